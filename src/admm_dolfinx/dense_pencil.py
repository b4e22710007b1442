"""The contact pencil read off the condensed stiffness S_C: compliance and r*, densely.

With the dense Schur complement S_C of A onto the contact dofs C
(:class:`~admm_dolfinx.condensed.CondensedOperator`) and W = Nᵀ M^{½} on C, the
m × m compliance of Γ_C at penalty r is

    T(r) = Wᵀ (S_C + r K_CC)⁻¹ W = M^{½} N (A + rK)⁻¹ Nᵀ M^{½},

whose eigenvalues are θ = λ / (1 + rλ) for the eigenvalues λ of the contact pencil
NᵀMN w = λ A w. Active-set polishing (:mod:`admm_dolfinx.polish`) uses T(r) itself;
r* = 1/sqrt(λ_min λ_max) needs the two ends of its spectrum, which SLEPc computes:

* m ≤ :data:`DENSE_ALL_EIGENVALUES`: every eigenvalue, with SLEPc's LAPACK solver;
* above: Krylov–Schur for the largest θ (one at a time, each found rigid motion
  deflated, so that a repeated θ = 1/r_a cannot hide behind its first copy) and
  Krylov–Schur with shift-and-invert at 0 (a dense Cholesky factorisation of T) for
  the smallest. SLEPc's LAPACK solver also returns all eigenvectors and their
  residuals, which dominates at thousands of contact nodes (r* on the 257k-dof mesh of
  Example 3, m = 3313: 73 s that way, 5.5 s with the compliance included this way;
  ``benchmarks/acceleration.py`` then, ``benchmarks/polish_3d.py`` now).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc
from slepc4py import SLEPc

__all__ = ["DENSE_ALL_EIGENVALUES", "RIGID_TOL", "compliance_matrix", "extremes_from_schur"]

#: Up to this m the dense pencil's eigenvalues all come from SLEPc's LAPACK solver
#: (under 0.1 s); above it Krylov–Schur computes the two ends.
DENSE_ALL_EIGENVALUES = 400
#: θ with 1 − r_a θ below this is a rigid motion (λ = ∞).
RIGID_TOL = 1e-6
#: Relative residual tolerance of the Krylov–Schur solves (T is formed to round-off).
_KRYLOV_TOL = 1e-12


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
    schur: np.ndarray, k_cc: np.ndarray, weights: np.ndarray, prefix: str = "pencil_dense_"
) -> tuple[float, float, int]:
    """λ_min, λ_max and the rigid motions seen by Γ_C, densely from S_C; exact.

    The pencil's eigenvalues are θ = λ / (1 + r_a λ) of T(r_a) (see the module
    docstring); rigid motions give θ = 1/r_a. The scale tr S_C / tr K_CC is about
    1/λ_min (the diagonal ratio of the shortest-wave modes), so
    r_a = 1e-3 tr S_C / tr K_CC puts r_a λ_max near κ/1000: then λ = θ/(1 − r_a θ)
    loses at most about κ²/1000 ulps at λ_max and λ_min keeps full relative accuracy,
    while the rigid motions, at 1 − r_a θ ≈ 1e-16, stay far below :data:`RIGID_TOL`
    for any κ = λ_max/λ_min below 1e8.

    Args:
        schur: S_C, symmetric c × c (singular for a floating body).
        k_cc: K = NᵀMN restricted to C × C.
        weights: W, c × m.
        prefix: Options prefix of the SLEPc solvers of the m × m problem.

    Returns:
        λ_min, λ_max (over the finite eigenvalues) and the number of rigid motions.

    Raises:
        RuntimeError: If S_C + r_a K_CC is not positive definite (A_II singular: a
            motion of the body that Γ_C does not see), every mode is rigid, or SLEPc
            fails.
    """
    r_a = 1e-3 * float(np.trace(schur) / np.trace(k_cc))
    compliance = compliance_matrix(schur, k_cc, weights, r_a)
    rigid_at = 1.0 / r_a
    try:  # a SLEPc failure gets a message that names the prefix and the alternative
        if compliance.shape[0] <= DENSE_ALL_EIGENVALUES:
            theta = _all_eigenvalues(compliance, prefix)
            finite = theta[1.0 - r_a * theta > RIGID_TOL]
            if finite.size == 0:
                raise RuntimeError("Every contact mode is a rigid motion of the body.")
            theta_min, theta_max, rigid = finite[0], finite[-1], theta.size - finite.size
        else:
            theta_max, rigid = _largest_finite(compliance, rigid_at, prefix)
            theta_min = _smallest(compliance, prefix)
    except (PETSc.Error, SystemError) as error:  # petsc4py reports some as SystemError
        raise RuntimeError(
            f"SLEPc failed on the dense contact pencil (m = {compliance.shape[0]}): {error}. "
            f"Check the options under the prefix {prefix!r}, or use "
            "estimate_penalty(..., method='iterative')."
        ) from error
    lam_min = theta_min / (1.0 - r_a * theta_min)
    lam_max = theta_max / (1.0 - r_a * theta_max)
    return float(lam_min), float(lam_max), int(rigid)


# ---------------------------------------------------------------------------------
def _dense_matrix(array: np.ndarray) -> PETSc.Mat:
    n = array.shape[0]
    return PETSc.Mat().createDense((n, n), array=np.asfortranarray(array), comm=PETSc.COMM_SELF)


def _all_eigenvalues(matrix: np.ndarray, prefix: str) -> np.ndarray:
    """All eigenvalues of a small dense symmetric matrix (SLEPc, LAPACK), ascending."""
    n = matrix.shape[0]
    mat = _dense_matrix(matrix)
    eps = SLEPc.EPS().create(comm=PETSc.COMM_SELF)
    try:
        eps.setOptionsPrefix(prefix)
        eps.setOperators(mat)
        eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
        eps.setType(SLEPc.EPS.Type.LAPACK)
        eps.setDimensions(nev=n)
        eps.solve()
        count = eps.getConverged()
        if count < n:  # pragma: no cover - LAPACK's dense solver returns all of them
            raise RuntimeError(f"SLEPc returned {count} of the {n} contact-pencil eigenvalues.")
        return np.sort([eps.getEigenvalue(i).real for i in range(n)])
    finally:
        eps.destroy()
        mat.destroy()


def _krylov_schur(mat: PETSc.Mat, prefix: str) -> SLEPc.EPS:
    eps = SLEPc.EPS().create(comm=PETSc.COMM_SELF)
    eps.setOptionsPrefix(prefix)
    eps.setOperators(mat)
    eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=1)
    eps.setTolerances(tol=_KRYLOV_TOL, max_it=1000)
    return eps


def _solve_one(eps: SLEPc.EPS, what: str) -> tuple[float, PETSc.Vec]:
    eps.setFromOptions()
    eps.solve()
    if eps.getConverged() < 1:
        raise RuntimeError(
            f"SLEPc's Krylov–Schur did not converge to the {what} eigenvalue of the dense "
            f"contact compliance ({eps.getIterationNumber()} iterations, reason "
            f"{eps.getConvergedReason()})."
        )
    vec = eps.getOperators()[0].createVecRight()
    value = eps.getEigenpair(0, vec).real
    return value, vec


def _largest_finite(matrix: np.ndarray, rigid_at: float, prefix: str) -> tuple[float, int]:
    """The largest θ below the rigid value 1/r_a, and how many rigid θ lie above it.

    One eigenvalue at a time: a found rigid mode joins SLEPc's deflation space, so that
    the next solve finds the next copy of θ = 1/r_a (a Krylov space grown from one
    vector holds one vector per distinct eigenvalue) or the largest finite θ.
    """
    mat = _dense_matrix(matrix)
    rigid: list[PETSc.Vec] = []
    try:
        while True:
            eps = _krylov_schur(mat, prefix + "max_")
            try:
                eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
                if rigid:
                    eps.setDeflationSpace(rigid)
                theta, vec = _solve_one(eps, "largest")
            finally:
                eps.destroy()
            if 1.0 - theta / rigid_at > RIGID_TOL:
                vec.destroy()
                return theta, len(rigid)
            rigid.append(vec)
            if len(rigid) == matrix.shape[0]:
                raise RuntimeError("Every contact mode is a rigid motion of the body.")
    finally:
        for vec in rigid:
            vec.destroy()
        mat.destroy()


def _smallest(matrix: np.ndarray, prefix: str) -> float:
    """The smallest θ: Krylov–Schur on T⁻¹ (shift-and-invert at 0, dense Cholesky)."""
    mat = _dense_matrix(matrix)
    eps = _krylov_schur(mat, prefix + "min_")
    try:
        eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
        eps.setTarget(0.0)
        st = eps.getST()
        st.setType(SLEPc.ST.Type.SINVERT)
        ksp = st.getKSP()
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.CHOLESKY)
        theta, vec = _solve_one(eps, "smallest")
        vec.destroy()
        return theta
    finally:
        eps.destroy()
        mat.destroy()
