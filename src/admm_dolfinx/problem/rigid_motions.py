"""Rigid motions that cost no energy, and whether the contact can hold them.

A body whose Dirichlet conditions do not hold every rigid motion *floats*: A is
singular, and only the contact can keep it in place (the paper's Hertz cylinder, free
to move vertically). That is well posed along a motion that moves Γ_C towards or away
from the obstacle, N d ≠ 0: the contact pressure balances the load there. A motion
with N d = 0 (a flat body sliding along a flat obstacle, a disc spinning on its
centre) is held by nothing: the QP then has no unique minimiser, and the answer would
drift with the penalty. :func:`analyse_rigid_motions` finds the first kind (their
number is what the penalty estimate needs) and refuses the second.

Method: with the rigid motions R of the mesh (gdim translations and the rotations
about the body's centre, scaled by its size), the floating ones are the
eigenvectors of Rᵀ A R z = μ RᵀR z with μ at round-off of the stiffness scale
(a motion that moves a Dirichlet dof costs at least that scale over the number of
nodes); of those, the ones the contact normals do not see have ‖N d‖ at round-off
of ‖d‖ on Γ_C. A few products with A; collective.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from dolfinx import fem, la
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["RigidMotions", "analyse_rigid_motions", "near_nullspace"]

#: μ below this times the stiffness scale: the motion costs no energy (floats).
FLOATING_TOL = 1e-10
#: ‖N d‖²_M below this times ‖d‖²_M on Γ_C: the contact normals do not see the motion.
UNSEEN_TOL = 1e-10


@dataclass(frozen=True)
class RigidMotions:
    """The rigid motions A does not resist.

    Attributes:
        floating: How many independent rigid motions cost no energy (0: A is
            positive definite). Γ_C's normals see each of them.
        normal_motion: (N d_i)_j for a basis d_1 … d_floating of them, at the owned
            contact nodes, shape (floating, m_loc): the directions of the contact
            pencil that no penalty changes (its eigenvalue λ = ∞).
        coefficients: The d_i in the mesh's rigid motions (translations, then
            rotations about ``center`` scaled by 1/``length``), shape
            (rigid motions, floating): :meth:`vectors` makes them.
        center: The centre of the rotations.
        length: Their scale.
    """

    floating: int
    normal_motion: npt.NDArray[np.float64]
    coefficients: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    center: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    length: float = 1.0

    def vectors(self, V: fem.FunctionSpace) -> list[PETSc.Vec]:
        """The floating motions d_1 … d_floating as vectors of V; collective.

        A d_i = 0 to round-off (Dirichlet dofs included), and the d_i are orthonormal.

        Args:
            V: The displacement space the motions were analysed in.

        Returns:
            One vector per floating motion, ghosts updated (the caller destroys them).

        Raises:
            ValueError: If the motions' coefficients were not kept (a RigidMotions
                made by hand).
        """
        if self.coefficients.shape[1] != self.floating:
            raise ValueError(
                f"{self.floating} floating motion(s) but coefficients of "
                f"{self.coefficients.shape[1]}: make RigidMotions by analyse_rigid_motions."
            )
        basis = _basis(V, self.center, self.length)
        motions: list[PETSc.Vec] = []
        try:
            for column in self.coefficients.T:
                vec = basis[0].duplicate()
                motions.append(vec)
                vec.set(0.0)
                vec.maxpy(column, basis)
                vec.ghostUpdate(PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        except BaseException:
            for vec in motions:
                vec.destroy()
            raise
        finally:
            for vec in basis:
                vec.destroy()
        return motions


#: Rotations (i, j), the motions −x_j e_i + x_i e_j: about z in 2D; in 3D about x, y, z.
_ROTATIONS = {2: [(0, 1)], 3: [(1, 2), (2, 0), (0, 1)]}
#: The same in the order of DOLFINx's elasticity demos, for the multigrid (its
#: aggregates, and so its V-cycles, depend on the basis, not only on its span).
_NULLSPACE_ROTATIONS = {2: [(0, 1)], 3: [(0, 1), (0, 2), (1, 2)]}


def _motion_values(x: npt.NDArray, bs: int, k: int, rotations) -> npt.NDArray:
    """Nodal values (n, bs) of rigid motion k at the points x (n, gdim).

    The motions are the translations e_0 … e_{gdim−1}, then the rotations (i, j) of
    ``rotations``.
    """
    gdim = x.shape[1]
    values = np.zeros((x.shape[0], bs))
    if k < gdim:
        values[:, k] = 1.0
    else:
        i, j = rotations[k - gdim]
        values[:, i] = -x[:, j]
        values[:, j] = x[:, i]
    return values


def _basis(V: fem.FunctionSpace, center: npt.NDArray, length: float) -> list[PETSc.Vec]:
    """Translations e_i and rotations about ``center`` scaled by 1/length (owned dofs)."""
    gdim = V.mesh.geometry.dim
    bs = V.dofmap.index_map_bs
    n = V.dofmap.index_map.size_local
    x = (V.tabulate_dof_coordinates()[:n, :gdim] - center[:gdim]) / length
    vectors = []
    for k in range(gdim + len(_ROTATIONS[gdim])):
        vec = fem_petsc.create_vector(V)
        vec.array[: n * bs] = _motion_values(x, bs, k, _ROTATIONS[gdim]).reshape(-1)
        vectors.append(vec)
    return vectors


def near_nullspace(V: fem.FunctionSpace) -> PETSc.NullSpace:
    """The rigid body motions of V, orthonormalised; collective.

    They are the near null space of the elasticity operator that smoothed-aggregation
    multigrid (``PCGAMG``) needs.

    Args:
        V: Vector-valued Lagrange space (2D: 3 modes, 3D: 6 modes).

    Returns:
        A PETSc null space object (the caller destroys it).
    """
    gdim = V.mesh.geometry.dim
    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    n = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n, :gdim]
    basis = [la.vector(index_map, bs=bs) for _ in range(gdim + len(_ROTATIONS[gdim]))]
    for k, b in enumerate(basis):
        b.array.reshape(-1, bs)[:n] = _motion_values(x, bs, k, _NULLSPACE_ROTATIONS[gdim])
    la.orthonormalize(basis)
    vectors = [b.petsc_vec.copy() for b in basis]
    space = PETSc.NullSpace().create(vectors=vectors, comm=V.mesh.comm)
    for vec in vectors:
        vec.destroy()
    return space


def _gram(left: list[PETSc.Vec], right: list[PETSc.Vec]) -> np.ndarray:
    return np.array([[a.dot(b) for b in right] for a in left])


def _describe(z: npt.NDArray, gdim: int) -> str:
    z = z / z[np.argmax(np.abs(z))]  # the largest component +1
    z = np.where(np.abs(z) < 1e-8, 0.0, z) + 0.0  # no -0
    parts = []
    t = z[:gdim]
    if np.linalg.norm(t) > 1e-3:
        parts.append("translation along (" + ", ".join(f"{c:.2g}" for c in t) + ")")
    w = z[gdim:]
    if np.linalg.norm(w) > 1e-3:
        if gdim == 2:
            parts.append("rotation in the plane")
        else:
            parts.append("rotation about the axis (" + ", ".join(f"{c:.2g}" for c in w) + ")")
    return " with ".join(parts) or "rigid motion"


def analyse_rigid_motions(
    A: PETSc.Mat,
    V: fem.FunctionSpace,
    nodes: npt.NDArray[np.int32],
    normals: npt.NDArray[np.float64],
    mass: npt.NDArray[np.float64],
    stiffness_scale: float,
    bounds: npt.NDArray[np.float64],
) -> RigidMotions:
    """The floating rigid motions; raise if the contact does not hold one; collective.

    Args:
        A: Stiffness (Dirichlet rows and columns eliminated, their diagonal at the
            stiffness scale).
        V: Displacement space.
        nodes: Owned contact nodes (block indices of V).
        normals: Their contact normals (the rows of N).
        mass: Their lumped masses M_jj.
        stiffness_scale: Mean diagonal of A on the free dofs.
        bounds: (2, 3) lower and upper corners of the body.

    Returns:
        The number of floating motions.

    Raises:
        ValueError: On every rank, if a floating rigid motion has no normal component
            on Γ_C (nothing holds it), naming the motion and the fix.
    """
    comm = V.mesh.comm
    gdim = V.mesh.geometry.dim
    bs = V.dofmap.index_map_bs
    center = 0.5 * (bounds[0] + bounds[1])
    length = float(np.linalg.norm(bounds[1] - bounds[0])) or 1.0
    basis = _basis(V, center, length)
    products = [A.createVecLeft() for _ in basis]
    try:
        for vec, out in zip(basis, products, strict=True):
            A.mult(vec, out)
        G = _gram(basis, products)
        B = _gram(basis, basis)
        # the motions at the contact nodes, for N d and |d|
        local = np.array([vec.array_r.reshape(-1, bs)[nodes, :gdim] for vec in basis])
    finally:
        for vec in (*basis, *products):
            vec.destroy()
    G = 0.5 * (G + G.T)
    L = np.linalg.cholesky(0.5 * (B + B.T))
    Li = np.linalg.inv(L)
    mu, W = np.linalg.eigh(Li @ G @ Li.T)
    floating = W[:, mu <= FLOATING_TOL * stiffness_scale]
    if floating.shape[1] == 0:
        return RigidMotions(floating=0, normal_motion=np.zeros((0, nodes.size)))
    Z = Li.T @ floating  # coefficients of the floating motions in the basis
    motions = np.einsum("kjd,kf->fjd", local, Z) if local.size else np.zeros((Z.shape[1], 0, gdim))
    normal_part = np.einsum("fjd,jd->fj", motions, normals) if motions.size else motions[..., 0]
    C = comm.allreduce(np.einsum("fj,gj,j->fg", normal_part, normal_part, mass), op=MPI.SUM)
    D = comm.allreduce(np.einsum("fjd,gjd,j->fg", motions, motions, mass), op=MPI.SUM)
    D = 0.5 * (D + D.T) + 1e-12 * max(np.trace(D), np.finfo(float).tiny) * np.eye(D.shape[0])
    LD = np.linalg.cholesky(D)
    LDi = np.linalg.inv(LD)
    seen, U = np.linalg.eigh(LDi @ (0.5 * (C + C.T)) @ LDi.T)
    unseen = seen <= UNSEEN_TOL
    if np.any(unseen):
        z = Z @ (LDi.T @ U[:, np.flatnonzero(unseen)[0]])
        raise ValueError(
            f"The body can move rigidly ({_describe(z, gdim)}) without straining and "
            "without moving towards the obstacle: neither the Dirichlet conditions nor "
            "the contact hold that motion, so the contact problem has no unique solution. "
            "Add a Dirichlet condition that holds it, e.g. fix the tangential "
            "displacement on a symmetry line or plane (fem.dirichletbc(0.0, dofs, "
            "V.sub(i))) or at a point."
        )
    return RigidMotions(
        floating=int(floating.shape[1]),
        normal_motion=normal_part,
        coefficients=Z,
        center=center,
        length=length,
    )
