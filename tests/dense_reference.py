"""Dense reference for the contact pencil: the paper's Algorithm 5, literally, with scipy.

Serial only. Applies where every contact normal is axis-aligned, so that the contact
normal dofs are plain dofs: S = A_CC − A_CI A_II⁻¹ A_IC, X = S⁻¹ M_CC, all eigenvalues
of X with numpy. Shares nothing with the SLEPc code path but the assembled A and M.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def petsc_to_scipy(mat) -> sp.csr_matrix:
    indptr, indices, data = mat.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=mat.getSize())


def algorithm5_eigenvalues(problem) -> np.ndarray:
    """All eigenvalues of X = S⁻¹ M_CC (ascending)."""
    assert problem.comm.size == 1, "dense reference is serial"
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    axis = np.argmax(np.abs(c.normals), axis=1)
    assert np.allclose(np.abs(c.normals[np.arange(len(axis)), axis]), 1.0), "axis-aligned only"
    A = petsc_to_scipy(problem.A)
    n = A.shape[0]
    fixed = np.zeros(n, dtype=bool)
    for bc in problem.bcs:
        fixed[bc.dof_indices()[0]] = True
    C = c.nodes * bs + axis
    interior = np.setdiff1d(np.flatnonzero(~fixed), C)
    A_II = A[interior][:, interior].tocsc()
    A_IC = A[interior][:, C].toarray()
    A_CC = A[C][:, C].toarray()
    X = spla.splu(A_II).solve(A_IC)
    S = A_CC - A_IC.T @ X
    eig = np.linalg.eigvals(np.linalg.solve(S, np.diag(c.mass)))
    assert np.max(np.abs(eig.imag)) <= 1e-8 * np.max(np.abs(eig.real))
    return np.sort(eig.real)


def rotated_schur(problem) -> tuple[np.ndarray, np.ndarray]:
    """(S, M): the Schur complement of A onto the contact normal dofs, any normals; dense.

    At each contact node the free dofs are rotated (a Householder reflection within
    the free components) so that the first rotated dof is the normal one; then
    S = A_CC − A_CI A_II⁻¹ A_IC as in Algorithm 5. Where a Dirichlet condition fixes
    some components, only the free part ñ of the normal moves the node towards the
    obstacle, (N u)_j = |ñ_j| c_j, and S is scaled to D^{-½} S D^{-½} with D = |ñ|².
    Rows are the contact nodes in the problem's order; M is the lumped mass.
    """
    assert problem.comm.size == 1, "dense reference is serial"
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    A = petsc_to_scipy(problem.A).toarray()
    n = A.shape[0]
    fixed = np.zeros(n, dtype=bool)
    for bc in problem.bcs:
        fixed[bc.dof_indices()[0]] = True
    R = np.eye(n)
    C = np.empty(c.nodes.size, dtype=np.int64)
    D = np.empty(c.nodes.size)
    for j, (node, normal) in enumerate(zip(c.nodes, c.normals, strict=True)):
        dofs = node * bs + np.arange(bs)
        free = dofs[~fixed[dofs]]
        nt = normal[~fixed[dofs]]
        D[j] = nt @ nt
        t = nt / np.sqrt(D[j])
        e = np.zeros(free.size)
        e[0] = 1.0
        v = t - e
        H = np.eye(free.size)
        if np.linalg.norm(v) > 1e-14:
            H -= 2 * np.outer(v, v) / (v @ v)
        R[np.ix_(free, free)] = H  # H e_0 = t: rotated dof free[0] is the normal one
        C[j] = free[0]
    Ar = R.T @ A @ R
    interior = np.setdiff1d(np.flatnonzero(~fixed), C)
    A_II = Ar[np.ix_(interior, interior)]
    A_IC = Ar[np.ix_(interior, C)]
    S = Ar[np.ix_(C, C)] - A_IC.T @ np.linalg.solve(A_II, A_IC)
    S = S / np.sqrt(np.outer(D, D))
    return 0.5 * (S + S.T), c.mass.copy()


def rotated_pencil_eigenvalues(problem) -> np.ndarray:
    """Eigenvalues λ of M w = λ S w for any normals, floating bodies included.

    S from :func:`rotated_schur`. S may be singular (a floating body): the pencil is
    solved as S w = ν M w with scipy's symmetric solver, and λ = 1/ν, with ν = 0
    giving λ = ∞.
    """
    import scipy.linalg as sla

    S, mass = rotated_schur(problem)
    nu = sla.eigh(S, np.diag(mass), eigvals_only=True)
    scale = np.max(np.abs(nu))
    with np.errstate(divide="ignore"):
        lam = np.where(np.abs(nu) > 1e-10 * scale, 1.0 / nu, np.inf)
    return np.sort(lam)
