"""The contact pencil read off the condensed stiffness S_C: compliance and r*, densely.

With the dense Schur complement S_C of A onto the contact dofs C
(:class:`~admm_dolfinx.operators.condensed.CondensedOperator`) and W = Nᵀ M^{½} on C, the
m × m compliance of Γ_C at penalty r is

    T(r) = Wᵀ (S_C + r K_CC)⁻¹ W = M^{½} N (A + rK)⁻¹ Nᵀ M^{½},

whose eigenvalues are θ = λ / (1 + rλ) for the eigenvalues λ of the contact pencil
NᵀMN w = λ A w. Active-set polishing (:mod:`admm_dolfinx.admm.polish_dense`) uses T(r) itself;
r* = 1/sqrt(λ_min λ_max) needs the two ends of its spectrum, which a SLEPc ``EPS`` on
the dense T finds (:func:`compliance_spectrum`, options prefix ``<penalty prefix>dense_``):

* up to :data:`LAPACK_LIMIT` contact nodes, ``EPSLAPACK``: LAPACK's symmetric
  eigensolver, all of T's eigenvalues at once, to an absolute accuracy of ε‖T‖, so
  λ_min to a relative ε κ: enough for any κ = λ_max/λ_min that double precision holds
  (a thin strip has κ ≈ 1e10);
* beyond, Krylov–Schur for each end: the largest θ directly, the smallest by
  shift-and-invert at 0 (a dense Cholesky factorisation of T); the same accuracy,
  at a fraction of LAPACK's cost (which grows as m³ with its eigenvectors). Where the
  small end is a tight cluster of short-wave modes and shift-and-invert does not
  converge within its restarts, LAPACK is used after all.

The rigid motions that the contact holds (a floating body: θ = 1/r_a) are known from
the problem (:mod:`admm_dolfinx.problem.rigid_motions`) and deflated, so that no eigenvalue
is classified by its size: that would confuse them with the smoothest modes of a very
compliant body.
"""

from __future__ import annotations

import time

import numpy as np
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx._logging import get_logger
from admm_dolfinx._mpi import OnRank0, RankLayout
from admm_dolfinx.linalg.petsc import apply_options
from admm_dolfinx.operators.condensed import CondensedOperator

__all__ = [
    "LAPACK_LIMIT",
    "RIGID_TOL",
    "compliance_matrix",
    "compliance_spectrum",
    "dense_extremes",
    "extremes_from_schur",
]

logger = get_logger(__name__)

#: Up to this many contact nodes, LAPACK (SLEPc's ``EPSLAPACK``) gives the whole
#: spectrum of T; beyond, Krylov–Schur its two ends. ``EPSLAPACK`` computes the
#: eigenvectors too: on this machine 0.07 s at m = 500, 0.5 s at m = 1000, where
#: Krylov–Schur takes 0.03 s (``python benchmarks/penalty_cost.py`` measures r*'s cost).
LAPACK_LIMIT = 500
#: Relative tolerance of the Krylov–Schur ends (r* inherits half of λ's error).
KRYLOV_TOL = 1e-13
#: Krylov–Schur restarts before LAPACK is used after all.
KRYLOV_MAX_IT = 300

#: θ with 1 − r_a θ below this is a rigid motion (λ = ∞).
RIGID_TOL = 1e-6
#: r_a λ_max above this: λ = θ/(1 − r_a θ) amplifies θ's error too much; T is formed
#: again at r_a = 1/λ_max.
_MAX_RA_LAMBDA = 4.0


def _scaled_auxiliary_penalty(schur, k_cc, weights, r_a, smooth, rigid) -> float:
    """1/λ̃ with λ̃ ≤ λ_max the Ritz value of T(r_a) on the smooth pressures."""
    V = np.asarray(smooth, dtype=float)
    if rigid is not None and rigid.size:  # the rigid directions are not a λ
        q = np.linalg.qr(np.asarray(rigid, dtype=float))[0]
        V = V - q @ (q.T @ V)
    V = np.linalg.qr(V)[0]
    try:
        lower = np.linalg.cholesky(schur + r_a * k_cc)
    except np.linalg.LinAlgError:
        return r_a  # compliance_matrix explains the failure
    half = np.linalg.solve(lower, weights @ V)
    theta = float(np.linalg.eigvalsh(half.T @ half)[-1])
    x = r_a * theta
    if not 0.0 < x < 1.0:
        return r_a
    lam = theta / (1.0 - x)
    return min(r_a, 1.0 / lam) if r_a * lam > _MAX_RA_LAMBDA else r_a


def compliance_matrix(
    schur: np.ndarray, k_cc: np.ndarray, weights: np.ndarray, r: float
) -> np.ndarray:
    """T = Wᵀ (S_C + r K_CC)⁻¹ W, the m × m compliance of Γ_C at penalty r; dense.

    (M^{½} N (A + rK)⁻¹ Nᵀ M^{½}, read off the condensed stiffness.) Its eigenvalues
    are θ = λ / (1 + rλ) for the eigenvalues λ of the contact pencil.

    Args:
        schur: S_C, symmetric c × c.
        k_cc: K = NᵀMN restricted to C × C.
        weights: W = Nᵀ M^{½} on C, c × m.
        r: Penalty (> 0).

    Raises:
        RuntimeError: If S_C + r K_CC is not positive definite.
    """
    try:
        lower = np.linalg.cholesky(schur + r * k_cc)
    except np.linalg.LinAlgError as error:
        raise RuntimeError(
            "The Schur complement of A onto the contact dofs plus r NᵀMN is not "
            "positive definite: the body has a motion that neither the Dirichlet "
            "conditions nor Γ_C restrain."
        ) from error
    half = np.linalg.solve(lower, weights)  # L⁻¹ W, so that T = (L⁻¹W)ᵀ(L⁻¹W)
    return half.T @ half


def extremes_from_schur(
    schur: np.ndarray,
    k_cc: np.ndarray,
    weights: np.ndarray,
    rigid: np.ndarray | None = None,
    smooth: np.ndarray | None = None,
    prefix: str = "penalty_dense_",
) -> tuple[float, float, int]:
    """λ_min, λ_max and the rigid motions seen by Γ_C, densely from S_C; exact.

    The pencil's eigenvalues are θ = λ / (1 + r_a λ) of T(r_a) (see the module
    docstring); rigid motions give θ = 1/r_a. λ = θ/(1 − r_a θ) loses about r_a λ ulps
    at λ_max, so r_a is chosen with r_a λ_max ≤ 4, and T is formed again at
    r_a = 1/λ_max if that did not hold. λ_min keeps its accuracy relative to λ_max,
    which is what r* needs.

    Args:
        schur: S_C, symmetric c × c (singular for a floating body).
        k_cc: K = NᵀMN restricted to C × C.
        weights: W, c × m.
        rigid: The rigid directions M^{½} N d of the floating motions d (m × k), known
            from the problem (:mod:`admm_dolfinx.problem.rigid_motions`): deflated, so that
            nothing is classified by the size of θ. None: found as θ within
            :data:`RIGID_TOL` of 1/r_a (a test that needs κ ≪ 1/RIGID_TOL).
        smooth: Smooth normal pressures on Γ_C in compliance coordinates (m × k, e.g.
            M^{½} times 1, x, y): their Ritz value bounds λ_max from below and sets
            the first r_a. None: r_a starts at about 1e-3/λ_min.
        prefix: Options prefix of the eigensolvers (:func:`compliance_spectrum`).

    Returns:
        λ_min, λ_max (over the finite eigenvalues) and the number of rigid motions.

    Raises:
        RuntimeError: If S_C + r_a K_CC is not positive definite (A_II singular: a
            motion of the body that Γ_C does not see), every mode is rigid, or SLEPc
            fails.
    """
    r_a = 1e-3 * float(np.trace(schur) / np.trace(k_cc))
    if smooth is not None:
        r_a = _scaled_auxiliary_penalty(schur, k_cc, weights, r_a, smooth, rigid)
    known = rigid is not None
    complement = None
    if rigid is not None and rigid.size:
        m = weights.shape[1]
        q = np.linalg.qr(np.asarray(rigid, dtype=float).reshape(m, -1), mode="complete")[0]
        complement = q[:, rigid.shape[1] :]
    for _attempt in range(8):
        compliance = compliance_matrix(schur, k_cc, weights, r_a)
        finite, n_rigid = _finite_spectrum(compliance, r_a, complement, known, prefix)
        lam_max = finite[-1] / (1.0 - r_a * finite[-1])
        if r_a * lam_max <= _MAX_RA_LAMBDA:
            break
        r_a = 1.0 / lam_max  # the map θ → λ amplified errors: again, better scaled
    else:  # pragma: no cover - a pathological spectrum
        raise RuntimeError("could not separate λ_max from the rigid motions")
    lam_min = finite[0] / (1.0 - r_a * finite[0])
    return float(lam_min), float(lam_max), int(n_rigid)


def _eps(matrix: PETSc.Mat, prefix: str, kind: str, which: str, nev: int = 1) -> SLEPc.EPS:
    """A SLEPc eigensolver of the symmetric dense ``matrix``, configured, not solved."""
    eps = SLEPc.EPS().create(comm=MPI.COMM_SELF)
    eps.setOperators(matrix)
    eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
    eps.setType(kind)
    eps.setDimensions(nev=nev)
    if which == "smallest" and kind == SLEPc.EPS.Type.KRYLOVSCHUR:
        eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
        eps.setTarget(0.0)
        st = eps.getST()
        st.setType(SLEPc.ST.Type.SINVERT)
        st.getKSP().setType(PETSc.KSP.Type.PREONLY)
        st.getKSP().getPC().setType(PETSc.PC.Type.CHOLESKY)
    else:
        eps.setWhichEigenpairs(
            SLEPc.EPS.Which.SMALLEST_REAL if which == "smallest" else SLEPc.EPS.Which.LARGEST_REAL
        )
    eps.setTolerances(KRYLOV_TOL, KRYLOV_MAX_IT)
    apply_options(eps, prefix, {}, what="the dense r*'s eigensolver")  # the user's last
    return eps


def _solved(eps: SLEPc.EPS, count: int) -> list[float] | None:
    """The first ``count`` eigenvalues of a solved EPS, or None if fewer converged."""
    if eps.getConverged() < count:
        return None
    return [eps.getEigenvalue(i).real for i in range(count)]


def compliance_spectrum(compliance: np.ndarray, prefix: str, *, whole: bool) -> np.ndarray:
    """Eigenvalues of the symmetric compliance T by SLEPc, ascending; one process.

    Args:
        compliance: T, symmetric m × m.
        prefix: Options prefix of the eigensolvers (``<prefix>eps_type`` and the like);
            the Krylov–Schur ends take ``<prefix>max_`` and ``<prefix>min_``.
        whole: Every eigenvalue (to classify rigid motions by their size); otherwise
            only the two ends are needed.

    Returns:
        All eigenvalues, or (where m > :data:`LAPACK_LIMIT` and not ``whole``) the
        smallest and the largest.

    Raises:
        RuntimeError: If SLEPc computes no spectrum.
    """
    m = compliance.shape[0]
    matrix = PETSc.Mat().createDense(
        [m, m], array=np.asfortranarray(compliance, dtype=PETSc.ScalarType), comm=MPI.COMM_SELF
    )
    matrix.assemble()
    try:
        if not whole and m > LAPACK_LIMIT:
            ends = []
            for which in ("smallest", "largest"):
                eps = _eps(matrix, f"{prefix}{which[:3]}_", SLEPc.EPS.Type.KRYLOVSCHUR, which)
                try:
                    eps.solve()
                    ends.append(_solved(eps, 1))
                finally:
                    eps.destroy()
            if all(end is not None for end in ends):
                return np.array([ends[0][0], ends[1][0]])  # type: ignore[index]
            logger.info("r*: Krylov–Schur did not converge on T (m = %d): LAPACK instead", m)
        eps = _eps(matrix, prefix, SLEPc.EPS.Type.LAPACK, "smallest", nev=m)
        try:
            eps.solve()
            values = _solved(eps, m)
        finally:
            eps.destroy()
    finally:
        matrix.destroy()
    if values is None:  # pragma: no cover - LAPACK's QR iteration
        raise RuntimeError("SLEPc's LAPACK eigensolver failed on the dense contact pencil.")
    return np.sort(np.asarray(values))


def _finite_spectrum(
    compliance: np.ndarray, r_a: float, complement: np.ndarray | None, known: bool, prefix: str
) -> tuple[np.ndarray, int]:
    """The finite θ of T (ascending; its ends only if ``known``) and the number of rigid ones."""
    if complement is not None:
        compliance = complement.T @ compliance @ complement
    theta = compliance_spectrum(compliance, prefix, whole=not known)
    if known:  # the deflated directions are the rigid ones
        return theta, 0 if complement is None else complement.shape[0] - complement.shape[1]
    finite = theta[1.0 - r_a * theta > RIGID_TOL]
    if finite.size == 0:
        raise RuntimeError("Every contact mode is a rigid motion of the body.")
    return finite, theta.size - finite.size


def dense_extremes(problem, condensed, prefix, petsc_options):
    """λ_min, λ_max from the condensed factorisation (a private one if None); collective."""
    own = condensed is None
    t0 = time.perf_counter()
    if own:
        condensed = CondensedOperator(problem, prefix + "schur_", petsc_options)
    try:
        t1 = time.perf_counter()

        # the rigid directions M^½ N d of the floating motions, in the weights' node order
        c = problem.contact
        layout = RankLayout(problem.comm, c.dofs.size)
        rigid = layout.gather(problem.rigid_motions.normal_motion * np.sqrt(c.mass))
        # the affine pressures 1, x, y (, z) on Γ_C, to estimate λ_max
        smooth = layout.gather(np.vstack([np.ones(c.dofs.size), c.coordinates.T]) * np.sqrt(c.mass))

        def failure(name: str, text: str, _: bool) -> Exception:
            if name == "RuntimeError":  # the explained failures of extremes_from_schur
                return RuntimeError(text)
            return RuntimeError(f"The dense r* failed on rank 0: {name}: {text}")

        with OnRank0(problem.comm, failure) as work:
            if work.here:
                with Timer("admm_dolfinx: r* dense pencil"):
                    work.value = extremes_from_schur(
                        condensed.schur,
                        condensed.k_cc,
                        condensed.support.weights,
                        rigid=rigid.T,
                        smooth=smooth.T,
                        prefix=prefix + "dense_",
                    )
        lambda_min, lambda_max, rigid = work.value
        details = {
            "method": "dense",
            "m": problem.contact.num_global,
            "c": condensed.support.size,
            "rigid_modes": rigid,
            "solves_min": 0,
            "solves_max": 0,
            "time_factorization": t1 - t0 if own else 0.0,
            "time_dense": time.perf_counter() - t1,
        }
    finally:
        if own:
            condensed.destroy()
    return lambda_min, lambda_max, details
