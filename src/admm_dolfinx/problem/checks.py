"""Input checks of the contact problem, run once, up front, on every rank alike.

Everything here is collective and raises the same error on every rank: a bad input
must never reach the iteration, where it would run NaN iterations, give a wrong
answer, or fail deep inside PETSc with a message that does not name it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._mpi import probe_vector

__all__ = [
    "STIFFNESS_RANGE",
    "check_dirichlet_conditions",
    "check_finite",
    "check_stiffness",
]

#: The scale of the stiffness (the mean diagonal of A) must lie in this range: the
#: ADMM's residuals multiply forces by forces, which leaves double precision beyond it.
STIFFNESS_RANGE = (1e-100, 1e100)
#: Relative asymmetry yᵀAx − xᵀAy of two probe vectors above which A is not symmetric.
_SYMMETRY_TOL = 1e-8


def check_finite(comm: MPI.Comm, values: npt.ArrayLike | PETSc.Vec, what: str, fix: str) -> None:
    """Raise a ValueError on every rank if ``values`` hold a NaN or ±inf on any rank.

    Args:
        comm: Communicator.
        values: Local values (an array, or a PETSc vector: its local part).
        what: The input, for the message ("the load vector assembled from L").
        fix: What to do about it.
    """
    local = values.array_r if isinstance(values, PETSc.Vec) else np.asarray(values)
    n_bad = comm.allreduce(int(np.count_nonzero(~np.isfinite(local))), op=MPI.SUM)
    if n_bad:
        raise ValueError(f"{what} holds {n_bad} NaN or infinite value(s). {fix}")


def check_dirichlet_conditions(V: fem.FunctionSpace, bcs: Sequence[fem.DirichletBC]) -> None:
    """Each condition must live on V or one of its sub-spaces, with finite values.

    DOLFINx's assembly silently skips a condition on any other space (even an
    identical copy of V), so it would not be applied at all.

    Raises:
        ValueError: On every rank, naming the condition.
    """
    space = V._cpp_object
    for i, bc in enumerate(bcs):
        bc_space = getattr(bc.function_space, "_cpp_object", bc.function_space)
        if not space.contains(bc_space):
            raise ValueError(
                f"Dirichlet condition bcs[{i}] is defined on a function space that is not "
                "the displacement space of `a` (or one of its sub-spaces, V.sub(i)); "
                "DOLFINx would silently not apply it. Build it on that space: "
                "fem.dirichletbc(value, dofs, V) or fem.dirichletbc(value, dofs, V.sub(i)), "
                "with V = the space of the forms' arguments."
            )
    comm = V.mesh.comm
    for i, bc in enumerate(bcs):
        g = bc.g
        values = g.value if hasattr(g, "value") else g.x.array
        check_finite(
            comm,
            np.asarray(values),
            f"The value of Dirichlet condition bcs[{i}]",
            "Give finite prescribed displacements.",
        )


def _fixed_rows(A: PETSc.Mat, fixed_local: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    n_owned = A.getLocalSize()[0]
    return np.asarray(fixed_local[:n_owned], dtype=bool)


def check_stiffness(
    A: PETSc.Mat,
    fixed: npt.NDArray[np.bool_],
    coordinates: npt.NDArray[np.float64],
) -> float:
    """Check that A is finite, symmetric, has a positive diagonal and a usable scale.

    Args:
        A: The assembled stiffness (Dirichlet rows and columns eliminated).
        fixed: Per owned (and ghost) dof, whether a Dirichlet condition fixes it.
        coordinates: Coordinates of the owned dofs' nodes, one row per dof (for the
            partition-independent symmetry probes).

    Returns:
        The stiffness scale: the mean diagonal entry of A over the free dofs.

    Raises:
        ValueError: On every rank, naming the problem and the fix.
    """
    comm = A.getComm().tompi4py()
    diagonal = A.getDiagonal()
    try:
        free = ~_fixed_rows(A, fixed)
        d = diagonal.array_r[free]
        n_free = comm.allreduce(int(d.size), op=MPI.SUM)
        n_bad = comm.allreduce(int(np.count_nonzero(~np.isfinite(d))), op=MPI.SUM)
        if n_bad:
            raise ValueError(
                f"The stiffness A assembled from `a` holds NaN or infinite values ({n_bad} "
                "diagonal entries). Check the material constants and the other "
                "coefficients of `a` (e.g. E, ν)."
            )
        norm = A.norm(PETSc.NormType.INFINITY)  # max row sum: no squares to overflow
        if not math.isfinite(norm):
            raise ValueError(
                "The stiffness A assembled from `a` holds NaN or infinite values. Check "
                "the material constants and the other coefficients of `a` (e.g. E, ν)."
            )
        n_nonpositive = comm.allreduce(int(np.count_nonzero(d <= 0.0)), op=MPI.SUM)
        if n_nonpositive:
            raise ValueError(
                f"The stiffness A has {n_nonpositive} non-positive diagonal entries on free "
                "dofs, so it is not positive definite and `a` is not an elastic energy. "
                "Check the material constants: E > 0 and −1 < ν < ½."
            )
        if n_free == 0:
            raise ValueError("Every dof is fixed by the Dirichlet conditions: nothing to solve.")
        scale = comm.allreduce(float(d.sum()), op=MPI.SUM) / n_free
    finally:
        diagonal.destroy()
    low, high = STIFFNESS_RANGE
    if not low <= scale <= high:
        raise ValueError(
            f"The stiffness scale (mean diagonal of A) is {scale:.3g}, outside [{low:g}, "
            f"{high:g}], where the ADMM's products of forces stay within double "
            "precision. Rescale the units (e.g. E in MPa or GPa instead of Pa, or lengths "
            "in mm), which changes nothing in the solution but its units."
        )
    _check_symmetric(A, coordinates)
    return scale


def _check_symmetric(A: PETSc.Mat, coordinates: npt.NDArray[np.float64]) -> None:
    """yᵀ(Ax) = xᵀ(Ay) for two partition-independent probe vectors, or raise."""
    x, ax = A.createVecs()
    y, ay = A.createVecs()
    try:
        x.array[:] = probe_vector(coordinates, 0.5)
        y.array[:] = probe_vector(coordinates, 1.7)
        A.mult(x, ax)
        A.mult(y, ay)
        asymmetry = abs(y.dot(ax) - x.dot(ay))
        scale = y.norm() * ax.norm() + x.norm() * ay.norm()
    finally:
        for vec in (x, ax, y, ay):
            vec.destroy()
    if asymmetry > _SYMMETRY_TOL * scale:
        raise ValueError(
            f"The stiffness A assembled from `a` is not symmetric (relative asymmetry "
            f"{asymmetry / scale:.2e}). Frictionless contact minimises an elastic energy, "
            "whose bilinear form is symmetric: a(u, v) = a(v, u), e.g. "
            "inner(sigma(u), sym(grad(v))) * dx with a symmetric stress sigma(u)."
        )
