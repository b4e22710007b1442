"""PETSc helpers: prefixed options, factorised solvers, object lifetimes.

Every solver object of this package gets its own options prefix; options passed in
Python are pushed under that prefix, read once with ``setFromOptions`` and removed
again, so nothing leaks into the global options database (the pattern of
``dolfinx.fem.petsc.LinearProblem``).
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from petsc4py import PETSc

__all__ = [
    "CG_RESIDUAL_NORM",
    "DEFAULT_FACTOR_OPTIONS",
    "GAMG_KEEP_HIERARCHY",
    "ITERATIVE_OPTIONS",
    "PetscOwner",
    "apply_options",
    "create_factor_solver",
    "describe_factor_failure",
    "describe_petsc_error",
    "factor_options",
    "factorization_count",
    "is_factorisation",
    "iterative_options",
    "mean_diagonal",
    "prefixed_options",
    "prepare_eigensolve",
    "top_eigenpair",
    "unique_prefix",
]

#: Direct solve of a symmetric positive definite system: MUMPS Cholesky, one
#: factorisation reused by every ``KSPSolve``.
DEFAULT_FACTOR_OPTIONS: dict[str, Any] = {
    "ksp_type": "preonly",
    "pc_type": "cholesky",
    "pc_factor_mat_solver_type": "mumps",
}

#: An iterative step 1: conjugate gradients preconditioned by smoothed-aggregation
#: multigrid (the rigid body modes are A's near null space, set by the problem).
ITERATIVE_OPTIONS: dict[str, Any] = {"ksp_type": "cg", "pc_type": "gamg"}

#: Added to an iterative step 1's options when its preconditioner is GAMG: the
#: hierarchy (aggregates, smoothed interpolation) is built once and kept when the
#: values change (a new r); only the Galerkin coarse operators are recomputed.
GAMG_KEEP_HIERARCHY: dict[str, Any] = {"pc_gamg_reuse_interpolation": True}

#: Added to an iterative step 1's options when its Krylov method is CG: stop on the
#: unpreconditioned relative residual ‖b − Ax‖ / ‖b‖. PETSc's default test, on the
#: preconditioned residual ‖B(b − Ax)‖ / ‖Bb‖, spends a preconditioner application on
#: ‖Bb‖ in every solve that starts from a nonzero guess, and another on the residual
#: that stops it; a warm-started step-1 solve takes a few iterations, so those two
#: cycles are a large share of it. The inexact rule's tolerances
#: (:mod:`admm_dolfinx.admm.inexact`) are chosen in this norm.
CG_RESIDUAL_NORM: dict[str, Any] = {"ksp_norm_type": "unpreconditioned"}


def iterative_options(options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options of an iterative step 1: the defaults, then ``options``.

    :data:`GAMG_KEEP_HIERARCHY` joins them where the preconditioner is GAMG (PETSc
    refuses an option that no object reads, so not otherwise), and
    :data:`CG_RESIDUAL_NORM` where the Krylov method is CG (other methods support
    other norms), unless ``options`` decide it themselves.
    """
    merged = {**ITERATIVE_OPTIONS, **dict(options or {})}
    if merged.get("pc_type") == "gamg":
        merged = {**GAMG_KEEP_HIERARCHY, **merged}
    if merged.get("ksp_type") == "cg":
        merged = {**CG_RESIDUAL_NORM, **merged}
    return merged


#: MUMPS ordering in 2D: approximate minimum fill (AMF), faster to factorise than
#: MUMPS's own choice (METIS) on every 2D mesh of ``python benchmarks/orderings.py``,
#: at the same substitution time; in 3D METIS stays.
#: A factorisation with a Schur complement cannot use AMF: the condensed one
#: (:mod:`admm_dolfinx.operators.condensed`) asks for AMD, or METIS on large meshes.
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
    """The options of a step-1 solver: the defaults, the 2D ordering, then ``options``.

    The defaults (:data:`DEFAULT_FACTOR_OPTIONS`) are one choice, a factorisation, and
    apply only as a whole: options that choose another Krylov method (``ksp_type``
    other than ``preonly``) or another preconditioner (``pc_type`` other than
    ``cholesky``/``lu``) replace them entirely, so that e.g. ``{"ksp_type": "gmres",
    "pc_type": "ilu"}`` does not inherit MUMPS as the ILU's solver package.

    Args:
        options: The caller's options; they override everything.
        gdim: Geometric dimension of the problem (``None``: no dimension default).

    Returns:
        The merged options.
    """
    given = dict(options or {})
    iterative = given.get("ksp_type", "preonly") != "preonly"
    other_pc = given.get("pc_type", "cholesky") not in ("cholesky", "lu")
    if iterative or other_pc:
        return given
    merged = {**DEFAULT_FACTOR_OPTIONS, **given}
    if gdim == 2 and merged.get("pc_factor_mat_solver_type") == "mumps":
        merged = {**ORDERING_2D, **merged}
    return merged


def is_factorisation(options: Mapping[str, Any] | None) -> bool:
    """Whether ``options`` (merged with the defaults) describe a direct solve with MUMPS."""
    merged = factor_options(options)
    return (
        merged.get("ksp_type") == "preonly"
        and merged.get("pc_type") in ("cholesky", "lu")
        and merged.get("pc_factor_mat_solver_type") == "mumps"
    )


def unique_prefix(stem: str) -> str:
    """Return a fresh options prefix ``f"{stem}{k}_"``, unique in this process.

    Args:
        stem: Leading part, e.g. ``"admm_"``.

    Returns:
        The prefix.
    """
    return f"{stem}{next(_counter)}_"


#: No entry in PETSc's database.
_ABSENT = object()


@contextlib.contextmanager
def prefixed_options(prefix: str, options: Mapping[str, Any] | None) -> Iterator[None]:
    """Put ``options`` in PETSc's database under ``prefix`` for the ``with`` block only.

    An entry the database held before (the user's ``-prefix_key value``) is overridden
    inside the block and restored after it.

    Args:
        prefix: Options prefix.
        options: Option names without prefix (``{"pc_type": "lu"}``) and values;
            ``None`` values set a flag.
    """
    opts = PETSc.Options()
    options = dict(options or {})
    # the entries held under exactly these names ("" for a flag): not hasName, which
    # also finds -mg_levels_key for -mg_levels_3_key (PETSc's numbered prefixes)
    held = opts.getAll()
    before = {key: held.get(f"{prefix}{key}", _ABSENT) for key in options}
    for key, value in options.items():
        opts[f"{prefix}{key}"] = value
    try:
        yield
    finally:
        for key in options:
            del opts[f"{prefix}{key}"]
            if before[key] is not _ABSENT:  # None: a flag
                opts[f"{prefix}{key}"] = before[key]


def apply_options(
    obj: Any,
    prefix: str,
    options: Mapping[str, Any] | None,
    *,
    setup: bool = False,
    what: str = "",
) -> None:
    """Set ``obj``'s prefix, push ``options`` under it, call ``setFromOptions``, clean up.

    Some options are read only when the object is set up (MUMPS's ``mat_mumps_*``, a
    multigrid's level smoothers); pass ``setup=True`` to call ``setUp`` while they are
    still in the database, or they would be silently ignored (objects that set up
    inside their solve use :func:`prefixed_options` around it instead). With
    ``setup=True``, an option that PETSc did not read by then (misspelt, or meant for
    another object) is an error, and so is a PETSc failure, with a message naming the
    options and the prefix.

    Args:
        obj: A PETSc object with ``setOptionsPrefix`` and ``setFromOptions``.
        prefix: Options prefix for ``obj``.
        options: Option names without prefix (``{"pc_type": "lu"}``) and values;
            ``None`` values set a flag.
        setup: Call ``obj.setUp()`` before the options are removed.
        what: What ``obj`` is, for error messages ("the step-1 solver").

    Raises:
        ValueError: With ``setup=True``, if an option was not used.
        RuntimeError: If PETSc fails to apply the options or to set up ``obj``.
    """
    obj.setOptionsPrefix(prefix)
    options = dict(options or {})
    database = PETSc.Options()
    with prefixed_options(prefix, options):
        try:
            obj.setFromOptions()
            if setup:
                obj.setUp()
        except (PETSc.Error, SystemError) as error:  # slepc4py: a SystemError
            raise RuntimeError(
                f"PETSc could not set up {what or type(obj).__name__} (options prefix "
                f"{prefix!r}) with the options {options} and those of the options "
                f"database under -{prefix}: {describe_petsc_error(error)}."
            ) from error
        unused = [key for key in options if setup and not database.used(f"{prefix}{key}")]
    if unused:
        raise ValueError(
            f"PETSc did not use the option(s) {unused} given for "
            f"{what or type(obj).__name__} (prefix {prefix!r}): misspelt, or meant for "
            "another solver. Options that are only read while solving (monitors, views) "
            f"go into PETSc's options database as -{prefix}<name> instead."
        )


#: What PETSc's error codes mean for a user of this package (petscerror.h).
_PETSC_ERRORS = {
    55: "out of memory",
    56: "an operation this matrix type or solver package does not support",
    62: "a wrong argument value",
    71: "a zero pivot in the LU factorisation (a singular operator)",
    76: "an error in an external library (MUMPS, SuperLU_dist, ...)",
    81: "a zero pivot in the Cholesky factorisation (not positive definite)",
    86: "an unknown type name",
    91: "a solver that did not converge",
    92: "no solver package for this factorisation (e.g. MUMPS has no ILU; PETSc's own "
    "ILU and ICC are sequential: in parallel use pc_type bjacobi with sub_pc_type ilu)",
}


def describe_petsc_error(error: Exception) -> str:
    """PETSc's error code with what it means."""
    code = getattr(error, "ierr", None)
    if not code:  # slepc4py's SystemError carries no code: PETSc printed the reason
        return "an error PETSc reported above (an unknown type name, or a bad value)"
    meaning = _PETSC_ERRORS.get(code, "see the PETSc traceback above")
    return f"PETSc error {code}: {meaning}"


#: MUMPS's INFOG(1) values that mean "not enough memory" (MUMPS user's guide, §8).
_MUMPS_MEMORY = (-8, -9, -11, -13, -14, -15, -17, -19, -20)


def describe_factor_failure(ksp: PETSc.KSP) -> str | None:
    """Why the factorisation of ``ksp``'s preconditioner failed, if it did; else None."""
    pc = ksp.getPC()
    reason = int(pc.getFailedReason())
    infog = None
    if pc.getType() in ("cholesky", "lu"):
        try:
            factor = pc.getFactorMatrix()
            if factor.getType() == "mumps":
                infog = (factor.getMumpsInfog(1), factor.getMumpsInfog(2))
        except PETSc.Error:  # not set up
            infog = None
    if infog is not None and infog[0] < 0:
        code = infog[0]
        if code in _MUMPS_MEMORY:
            return (
                f"MUMPS ran out of memory (INFOG(1) = {code}, INFOG(2) = {infog[1]}): give "
                "it more workspace with the option mat_mumps_icntl_14 (percent, e.g. 100), "
                "and lift a cap mat_mumps_icntl_23 if one is set"
            )
        if code == -10:
            return (
                "MUMPS found the matrix numerically singular (INFOG(1) = -10): the body "
                "has a motion that neither the Dirichlet conditions nor the contact hold"
            )
        return f"MUMPS failed with INFOG(1) = {code}, INFOG(2) = {infog[1]} (see its manual)"
    names = {
        1: "a zero pivot in the symbolic factorisation",
        2: "a zero pivot: the operator is singular (a motion that the Dirichlet "
        "conditions and the contact do not hold) or not positive definite",
        3: "out of memory",
        4: "a failure of the factorisation package",
        5: "a failure in a sub-preconditioner",
    }
    if reason > 0:
        return f"PC failed reason {reason}: {names.get(reason, 'see PETSc PCFailedReason')}"
    return None


def create_factor_solver(
    A: PETSc.Mat,
    prefix: str,
    options: Mapping[str, Any] | None = None,
    gdim: int | None = None,
    what: str = "the step-1 solver",
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
        what: What the solver is for, in error messages.

    Returns:
        The KSP (the caller owns it and must ``destroy`` it).

    Raises:
        ValueError: For an option PETSc did not use.
        RuntimeError: If PETSc cannot set the solver up, or the factorisation fails
            (named: out of memory, singular, ...).
    """
    ksp = PETSc.KSP().create(A.getComm())
    try:
        ksp.setOperators(A)
        apply_options(ksp, prefix, factor_options(options, gdim), setup=True, what=what)
        failure = describe_factor_failure(ksp)
        if failure is not None:
            raise RuntimeError(
                f"The factorisation of {what} (prefix {prefix!r}) failed: {failure}."
            )
    except BaseException:
        ksp.destroy()
        raise
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
    if reason == PETSc.KSP.ConvergedReason.DIVERGED_INDEFINITE_PC:
        raise RuntimeError(
            f"The linear solve of {what} failed: its preconditioner is not positive "
            f"definite (KSP reason {reason}), although the system is. A multigrid's "
            "Chebyshev smoothers were given eigenvalue bounds below the spectrum, even "
            "when estimated carefully: widen them in the solver's options (options "
            f"prefix {ksp.getOptionsPrefix()!r}: mg_levels_ksp_chebyshev_esteig "
            "0,0.1,0,2), or use a factorisation (step1='factorised') where it fits."
        )
    if reason < 0:
        failure = describe_factor_failure(ksp)
        raise RuntimeError(
            f"The linear solve of {what} failed (KSP reason {reason}"
            + (f": {failure})." if failure else "). With an iterative solver, check its options.")
        )


def prepare_eigensolve(
    eps: Any,
    *,
    prefix: str,
    start: Sequence[PETSc.Vec] = (),
    deflation: Sequence[PETSc.Vec] = (),
) -> None:
    """Give a configured SLEPc EPS its start and deflation spaces and the user's options.

    The caller then runs ``eps.solve()`` itself (so that the Python callbacks of its
    shell operators are entered from the module that defines them) and reads the
    result with :func:`top_eigenpair`.

    Args:
        eps: The eigensolver, its operators, type and tolerances set.
        prefix: Options prefix; the user's ``-{prefix}eps_*`` options are applied last.
        start: Initial space (empty: SLEPc's random start).
        deflation: Vectors whose orthogonal complement is searched.
    """
    if deflation:
        eps.setDeflationSpace(list(deflation))
    if start:
        eps.setInitialSpace(list(start))
    apply_options(eps, prefix, {})


def top_eigenpair(eps: Any, failure: str) -> tuple[float, PETSc.Vec, int]:
    """The first eigenpair of a solved SLEPc EPS; collective.

    Args:
        eps: The eigensolver after ``eps.solve()``.
        failure: What to tell the user if nothing converged (the reason is appended).

    Returns:
        The eigenvalue, the eigenvector (the caller destroys it), the iteration count.

    Raises:
        RuntimeError: If no eigenpair converged.
    """
    if eps.getConverged() < 1:
        raise RuntimeError(f"{failure} (SLEPc reason {eps.getConvergedReason()}).")
    vec = eps.getOperators()[0].createVecRight()
    return eps.getEigenpair(0, vec).real, vec, eps.getIterationNumber()


def mean_diagonal(matrix: PETSc.Mat) -> float:
    """Mean of the diagonal (a scale of the matrix); collective."""
    diagonal = matrix.getDiagonal()
    value = diagonal.sum() / diagonal.getSize()
    diagonal.destroy()
    return value
