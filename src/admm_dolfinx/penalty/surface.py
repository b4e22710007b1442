"""β and r for the surface metric R = r (M + β L_Γ) (:mod:`admm_dolfinx.operators.surface_metric`).

The paper's rule r* = 1/sqrt(λ_min λ_max) applies to any metric: with μ_min, μ_max
the extreme eigenvalues of the pencil (Nᵀ(M + βL_Γ)N, A), the best r of the plain
ADMM is 1/sqrt(μ_min μ_max). The choice here starts from the paper's pencil (NᵀMN, A),
whose λ_min and λ_max :func:`~admm_dolfinx.penalty.estimate.estimate_penalty` computes
anyway:

* **β = b κ / k²_max**, κ = λ_max/λ_min, k²_max the largest eigenvalue of
  L_Γ x = k² M x (the roughest nodal pattern Γ_C carries), b = :data:`BETA_FRACTION`.
  With b = 1 the roughest contact mode, of compliance λ_min, would weigh
  λ_min (1 + κ) = λ_min + λ_max, while the smoothest, whose surface gradient is small,
  keeps λ_max: the two ends of the paper's spectrum brought together.
* **μ_min ≈ m λ_max**, m = :data:`MU_MIN_FRACTION`. The uniform and other smooth
  contact modes have almost no surface-gradient energy, so their μ is their λ: they
  cap μ_min at about λ_max; the minimum lies below, at a mode of intermediate
  wavelength, a global mode as dear to compute as λ_max.
* **μ_max** belongs to a short-wave mode at the edge of Γ_C, so it is computed like
  λ_min in :mod:`admm_dolfinx.penalty.lambda_min`, on a "layer" of zero rings of cells
  (:data:`LAYER_RINGS`): the contact nodes alone, every other node held fixed. That
  is stiffer than the body, so it gives a lower bound, which grows to μ_max with
  the layer; and it is a problem on the surface (3m unknowns), whose factorisation
  costs next to nothing beside the body's. SLEPc solves its generalised problem
  Nᵀ(M + βL_Γ)N x = μ A_L x with a factorisation of A_L.
  Since M + βL_Γ ⪰ M, μ_max ≥ λ_max too, and the larger of the two bounds is taken:
  at small β the top of the μ spectrum may be a smooth mode, which a layer sees only
  in part.
* **r = 1 / sqrt(m λ_max μ_max).**

b and m are calibrated on the iteration the solver runs (over-relaxed, with Anderson
acceleration), not on the plain ADMM's rate: with b = 1, m = ½ (the plain rate's
choice) the iteration counts grew on hexahedral and strongly graded meshes, where the
accelerated iteration's best r lay well above 1/sqrt(μ_min μ_max) and a smaller β
helped. ``python benchmarks/surface_metric.py --part calibrate`` counts the iterations
over a grid of (b, r) on Example 3, its variants, hexahedral and graded meshes (the
counts of b = 1, m = ½ included); ``--part rule`` compares r with the plain optimum
on the dense pencil.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from dolfinx.common import Timer
from slepc4py import SLEPc

from admm_dolfinx._logging import get_logger
from admm_dolfinx.linalg.petsc import (
    apply_options,
    factor_options,
    mean_diagonal,
    prepare_eigensolve,
    top_eigenpair,
)
from admm_dolfinx.operators.surface_metric import SurfaceMetric
from admm_dolfinx.penalty.estimate import PenaltyEstimate
from admm_dolfinx.problem.contact_layer import contact_layer, layer_index_set
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "LAMBDA_MIN_RINGS",
    "SURFACE_PENALTY_TOL",
    "SurfacePenalty",
    "estimate_surface_penalty",
]

logger = get_logger(__name__)

#: Rings of cells of the layer on which μ_max is computed: none, the contact nodes
#: alone with the rest of the body held fixed. The bound it gives falls short of the
#: body's μ_max, and b and m are calibrated with it: ``python
#: benchmarks/surface_metric.py --part rule`` prints the layer's μ_max over the whole
#: body's, ``--part calibrate`` the iteration counts. A
#: ring of cells costs a factorisation of a volume layer (on a mesh graded towards
#: Γ_C, the largest part of r*: ``python benchmarks/scale_3d.py``) for the same
#: counts.
LAYER_RINGS = 0
#: b of β = b κ / k²_max (see the module docstring).
BETA_FRACTION = 0.25
#: m of μ_min ≈ m λ_max, for r (see the module docstring); calibrated with the
#: zero-ring μ_max.
MU_MIN_FRACTION = 0.15
#: Residual tolerance of the layer's eigenvalue solve. r = 1/sqrt(m λ_max μ_max) needs
#: μ_max to a few digits, and a symmetric pencil's Ritz value is far more accurate than
#: its residual (of the order of the residual's square over the gap).
EIGEN_TOL = 1e-2
#: Rings of the one layer whose λ_min β uses (``lambda_min_rings`` of
#: :func:`~admm_dolfinx.penalty.estimate.estimate_penalty`, no growth check): the same
#: layer as μ_max's, a lower bound of λ_min. λ_min enters β = b κ/k²_max alone, not r,
#: and b was calibrated with this λ_min on a grid of factors of 2 (``python
#: benchmarks/surface_metric.py --part calibrate``).
LAMBDA_MIN_RINGS = LAYER_RINGS
#: Eigenvalue tolerance of λ_min and λ_max (``penalty_tol``) when the surface metric
#: uses them: they enter β = b κ/k²_max and r = 1/sqrt(m λ_max μ_max) through b and m,
#: calibrated on a grid of factors of 2, so digits beyond the first buy nothing; at
#: this tolerance λ_max's multigrid LOBPCG stops within a few iterations of its start.
#: ``python benchmarks/surface_metric.py --part calibrate`` counts the iterations
#: with it, ``python benchmarks/scale_3d.py`` times r* on the 3D ladder.
SURFACE_PENALTY_TOL = 0.1


@dataclass
class SurfacePenalty:
    """β, r and what they came from.

    Attributes:
        r: The penalty r = 1/sqrt(m λ_max μ_max) (m = :data:`MU_MIN_FRACTION`).
        beta: β = b κ/k²_max (b = :data:`BETA_FRACTION`).
        mu_max: Largest eigenvalue of (Nᵀ(M + βL_Γ)N, A).
        k_max_squared: Largest eigenvalue of L_Γ x = k² M x.
        estimate: The paper's pencil's estimate (λ_min, λ_max) that β and r use.
        time: Seconds for L_Γ, k²_max and μ_max (the paper's estimate excluded).
        details: ``layers`` (rings of the layer, "all", or None where L_Γ vanishes and
            no layer was solved), ``restarts`` (of
            Krylov–Schur).
    """

    r: float
    beta: float
    mu_max: float
    k_max_squared: float
    estimate: PenaltyEstimate
    time: float
    details: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Plain numbers for reports and JSON."""
        return {
            "r": self.r,
            "beta": self.beta,
            "mu_max": self.mu_max,
            "k_max_squared": self.k_max_squared,
            "lambda_min": self.estimate.lambda_min,
            "lambda_max": self.estimate.lambda_max,
            "time": self.time,
            **self.details,
        }


def estimate_surface_penalty(
    problem: ContactProblem,
    metric: SurfaceMetric,
    estimate: PenaltyEstimate,
    *,
    prefix: str,
    petsc_options: dict | None = None,
) -> SurfacePenalty:
    """β and r for the surface metric; collective.

    Args:
        problem: The contact problem.
        metric: Its surface metric (L_Γ).
        estimate: λ_min and λ_max of the paper's pencil
            (:func:`~admm_dolfinx.penalty.estimate.estimate_penalty`).
        prefix: Options prefix of the layer eigenvalue solves (``{prefix}eps_*``,
            ``{prefix}st_*``).
        petsc_options: Options of the layer factorisations (as for the step-1 solver).

    Returns:
        The surface penalty.

    Raises:
        RuntimeError: If a layer eigenvalue solve does not converge.
    """
    t0 = time.perf_counter()
    k2 = metric.k_max_squared
    if not (math.isfinite(k2) and k2 > 0.0):
        # no surface gradient on Γ_C (isolated contact nodes): the paper's metric, r*
        logger.warning("L_Γ vanishes on the contact nodes: β = 0, r = r* (the paper's metric)")
        return SurfacePenalty(
            r=estimate.r,
            beta=0.0,
            mu_max=estimate.lambda_max,
            k_max_squared=k2,
            estimate=estimate,
            time=time.perf_counter() - t0,
            details={"layers": None, "restarts": 0},  # no layer solved
        )
    with Timer("admm_dolfinx: surface penalty"):
        beta = BETA_FRACTION * estimate.condition_number / k2
        matrix = metric.penalty_matrix(beta)
        try:
            mu_layer, details = _largest_on_layer(problem, matrix, prefix, petsc_options)
        finally:
            matrix.destroy()
    # M + βL_Γ ⪰ M, so μ_max ≥ λ_max: the bound that a smooth top mode keeps (at small β
    # the top of the μ spectrum is a smooth mode that the layer sees only in part)
    mu_max = max(mu_layer, estimate.lambda_max)
    details["mu_max_layer"] = mu_layer
    r = 1.0 / math.sqrt(MU_MIN_FRACTION * estimate.lambda_max * mu_max)
    result = SurfacePenalty(
        r=r,
        beta=beta,
        mu_max=mu_max,
        k_max_squared=k2,
        estimate=estimate,
        time=time.perf_counter() - t0,
        details=details,
    )
    logger.info(
        "surface metric: β = %.4g (κ %.3g, k²_max %.4g), μ_max %.4e, r = %.6g in %.3f s",
        beta,
        estimate.condition_number,
        k2,
        mu_max,
        r,
        result.time,
    )
    return result


def _largest_on_layer(problem, matrix, prefix, petsc_options):
    """μ_max of (matrix, A) on a layer of LAYER_RINGS rings of cells along Γ_C."""
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    nodes, whole = contact_layer(problem, LAYER_RINGS)
    index_set = stiffness = penalty = start = None
    try:
        index_set = layer_index_set(problem, nodes)
        stiffness = problem.A.createSubMatrix(index_set, index_set)
        penalty = matrix.createSubMatrix(index_set, index_set)
        start = penalty.createVecRight()
        # unit diagonal scales: SLEPc's relative residual test is then unit-free
        a_scale = mean_diagonal(stiffness)
        diagonal = penalty.getDiagonal()
        b_scale = abs(diagonal.max()[1])
        diagonal.destroy()
        stiffness.scale(1.0 / a_scale)
        penalty.scale(1.0 / b_scale)
        start.set(0.0)  # N_Fᵀ of a partition-independent pseudo-random normal pattern
        position = np.searchsorted(nodes, c.nodes)
        gdim = problem.mesh.geometry.dim
        with start as arr:
            arr.reshape(-1, bs)[position, :gdim] = c.free_normals * c.probe[:, None]
        value, vec, its = _layer_eigenvalue(penalty, stiffness, start, prefix, petsc_options)
        vec.destroy()
    finally:
        for obj in (start, penalty, stiffness, index_set):
            if obj is not None:
                obj.destroy()
    mu = value * b_scale / a_scale
    return mu, {"layers": "all" if whole else LAYER_RINGS, "restarts": its}


def _layer_eigenvalue(penalty, stiffness, start, prefix, petsc_options):
    """Largest eigenvalue of penalty x = μ stiffness x (SLEPc, factorised stiffness)."""
    eps = SLEPc.EPS().create(comm=stiffness.getComm())
    try:
        eps.setOperators(penalty, stiffness)
        eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
        eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
        eps.setDimensions(nev=1, ncv=16)
        eps.setTolerances(tol=EIGEN_TOL, max_it=200)
        st = eps.getST()
        st.setType(SLEPc.ST.Type.SHIFT)
        apply_options(
            st.getKSP(),
            prefix + "st_",
            factor_options(petsc_options, 3),
            what="the layer solver of the surface metric's μ_max",
        )
        prepare_eigensolve(eps, prefix=prefix, start=[start])
        eps.solve()
        return top_eigenpair(
            eps,
            "SLEPc did not converge to the largest eigenvalue of the surface-metric pencil "
            "on a layer along the contact boundary. Pass expert={'penalty_metric': 'mass'}",
        )
    finally:
        eps.destroy()
