"""PETSc helpers: prefixed options, factorised solvers, object lifetimes.

Every solver object of this package gets its own options prefix; options passed in
Python are pushed under that prefix, read once with ``setFromOptions`` and removed
again, so nothing leaks into the global options database (the pattern of
``dolfinx.fem.petsc.LinearProblem``).
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

from petsc4py import PETSc

__all__ = [
    "DEFAULT_FACTOR_OPTIONS",
    "PetscOwner",
    "apply_options",
    "create_factor_solver",
    "factor_options",
    "factorization_count",
    "prefixed_options",
    "solve_top_eigenpair",
    "unique_prefix",
]

#: Direct solve of a symmetric positive definite system: MUMPS Cholesky, one
#: factorisation reused by every ``KSPSolve``.
DEFAULT_FACTOR_OPTIONS: dict[str, Any] = {
    "ksp_type": "preonly",
    "pc_type": "cholesky",
    "pc_factor_mat_solver_type": "mumps",
}

#: MUMPS ordering in 2D: approximate minimum fill (AMF). Measured by
#: ``benchmarks/orderings.py``: 0.5-0.75× the factorisation time of MUMPS's own
#: choice (METIS) on every 2D mesh, the same substitution time; in 3D METIS stays.
#: With a Schur complement (:mod:`admm_dolfinx.condensed`) MUMPS runs AMD instead.
ORDERING_2D: dict[str, Any] = {"mat_mumps_icntl_7": 2}

_counter = itertools.count()


class PetscOwner:
    """Frees the PETSc objects named in ``_petsc_objects`` on :meth:`destroy`.

    There is deliberately no ``__del__``: destroying a parallel PETSc object is
    collective, and the garbage collector runs at different times on different ranks,
    so a destructor that destroys would deadlock. An object that is never destroyed
    explicitly is left to petsc4py, which defers parallel objects to
    ``PETSc.garbage_cleanup``.
    """

    _petsc_objects: tuple[str, ...] = ()

    def destroy(self) -> None:
        """Free the PETSc objects this object owns; collective."""
        for name in self._petsc_objects:
            obj = getattr(self, name, None)
            if obj is not None:
                obj.destroy()
                setattr(self, name, None)


def factor_options(options: Mapping[str, Any] | None, gdim: int | None = None) -> dict[str, Any]:
    """The options of a factorisation: the defaults, the 2D ordering, then ``options``.

    Args:
        options: The caller's options; they override everything.
        gdim: Geometric dimension of the problem (``None``: no dimension default).

    Returns:
        The merged options.
    """
    merged = {**DEFAULT_FACTOR_OPTIONS, **dict(options or {})}
    if gdim == 2 and merged.get("pc_factor_mat_solver_type") == "mumps":
        merged = {**ORDERING_2D, **merged}
    return merged


def unique_prefix(stem: str) -> str:
    """Return a fresh options prefix ``f"{stem}{k}_"``, unique in this process.

    Args:
        stem: Leading part, e.g. ``"admm_"``.

    Returns:
        The prefix.
    """
    return f"{stem}{next(_counter)}_"


@contextlib.contextmanager
def prefixed_options(prefix: str, options: Mapping[str, Any] | None) -> Iterator[None]:
    """Put ``options`` in PETSc's database under ``prefix`` for the ``with`` block only.

    Args:
        prefix: Options prefix.
        options: Option names without prefix (``{"pc_type": "lu"}``) and values;
            ``None`` values set a flag.
    """
    opts = PETSc.Options()
    options = dict(options or {})
    for key, value in options.items():
        opts[f"{prefix}{key}"] = value
    try:
        yield
    finally:
        for key in options:
            del opts[f"{prefix}{key}"]


def apply_options(
    obj: Any, prefix: str, options: Mapping[str, Any] | None, *, setup: bool = False
) -> None:
    """Set ``obj``'s prefix, push ``options`` under it, call ``setFromOptions``, clean up.

    Some options are read only when the object is set up (MUMPS's ``mat_mumps_*``, a
    multigrid's level smoothers); pass ``setup=True`` to call ``setUp`` while they are
    still in the database, or they would be silently ignored (objects that set up
    inside their solve use :func:`prefixed_options` around it instead).

    Args:
        obj: A PETSc object with ``setOptionsPrefix`` and ``setFromOptions``.
        prefix: Options prefix for ``obj``.
        options: Option names without prefix (``{"pc_type": "lu"}``) and values;
            ``None`` values set a flag.
        setup: Call ``obj.setUp()`` before the options are removed.
    """
    obj.setOptionsPrefix(prefix)
    with prefixed_options(prefix, options):
        obj.setFromOptions()
        if setup:
            obj.setUp()


def create_factor_solver(
    A: PETSc.Mat, prefix: str, options: Mapping[str, Any] | None = None, gdim: int | None = None
) -> PETSc.KSP:
    """Create a KSP that factorises ``A`` (MUMPS Cholesky unless overridden), now.

    ``A`` must hold its values: it is factorised here, while the options (including
    the solver package's, e.g. ``mat_mumps_icntl_14``) are in the database. The
    factorisation is reused until the values of ``A`` change.

    Args:
        A: Symmetric positive definite operator.
        prefix: Options prefix of the KSP.
        options: Options overriding :data:`DEFAULT_FACTOR_OPTIONS`.
        gdim: Geometric dimension, for the default ordering (see :func:`factor_options`).

    Returns:
        The KSP (the caller owns it and must ``destroy`` it).
    """
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A)
    apply_options(ksp, prefix, factor_options(options, gdim), setup=True)
    return ksp


def factorization_count() -> int:
    """Numeric factorisations recorded by PETSc's log in this process (LU + Cholesky).

    Requires ``PETSc.Log.begin()`` to have been called; counts are cumulative.

    Returns:
        The number of ``MatLUFactorNum`` and ``MatCholFctrNum`` events so far.
    """
    return sum(
        int(PETSc.Log.Event(name).getPerfInfo()["count"])
        for name in ("MatLUFactorNum", "MatCholFctrNum")
    )


def check_solve(ksp: PETSc.KSP, what: str) -> None:
    """Raise if the last ``ksp.solve`` did not converge.

    Args:
        ksp: The solver.
        what: Short description of the system for the error message.

    Raises:
        RuntimeError: With PETSc's reason, if the solve diverged.
    """
    reason = ksp.getConvergedReason()
    if reason < 0:
        pc_reason = ksp.getPC().getFailedReason()
        raise RuntimeError(
            f"The linear solve of {what} failed (KSP reason {reason}, PC reason {pc_reason}). "
            "If the factorisation hit a zero pivot, the operator is singular: the body "
            "has a rigid motion that neither the Dirichlet conditions nor the contact "
            "normals restrain."
        )


def solve_top_eigenpair(
    eps: Any,
    create_vec: Callable[[], PETSc.Vec],
    failure: str,
    *,
    prefix: str,
    start: Sequence[PETSc.Vec] = (),
    deflation: Sequence[PETSc.Vec] = (),
) -> tuple[float, PETSc.Vec, int]:
    """Run a configured SLEPc EPS and return its first eigenpair; collective.

    Args:
        eps: The eigensolver, its operators, type and tolerances set.
        create_vec: Makes the vector that receives the eigenvector (only on success).
        failure: What to tell the user if nothing converged (the reason is appended).
        prefix: Options prefix; the user's ``-{prefix}eps_*`` options are applied last.
        start: Initial space (empty: SLEPc's random start).
        deflation: Vectors whose orthogonal complement is searched.

    Returns:
        The eigenvalue, the eigenvector (the caller destroys it), the iteration count.

    Raises:
        RuntimeError: If no eigenpair converged.
    """
    if deflation:
        eps.setDeflationSpace(list(deflation))
    if start:
        eps.setInitialSpace(list(start))
    apply_options(eps, prefix, {})
    eps.solve()
    if eps.getConverged() < 1:
        raise RuntimeError(f"{failure} (SLEPc reason {eps.getConvergedReason()}).")
    vec = create_vec()
    return eps.getEigenpair(0, vec).real, vec, eps.getIterationNumber()
