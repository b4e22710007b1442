"""Â = PAP + cQ of a guessed active set, made afresh or into the matrix of an earlier guess."""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from admm_dolfinx.linalg.contact_space import NodalMap, ProjectedStiffness, projected_stiffness
from admm_dolfinx.scenes import example3, hertz_sphere

pytestmark = pytest.mark.timeout(300)


def _guess(problem, share: float) -> NodalMap:
    """The contact nodes with the smallest gaps, a share of each rank's (any partition)."""
    c = problem.contact
    keep = c.gap <= np.quantile(c.gap, share) if c.gap.size else np.zeros(0, bool)
    return NodalMap(
        c.nodes[keep], c.free_normals[keep], problem.V.dofmap.index_map_bs, problem.gdim
    )


@pytest.mark.parametrize("scene", ["block", "ball"])
def test_an_earlier_guess_matrix_takes_the_next_guess_values(scene):
    """Formed into the matrix of an earlier guess (its cQ added, other nodes active,
    the triple product's numeric phase only), Â of the next guess equals the one made
    afresh: every value is overwritten, none kept; on any partition."""
    problem = (example3(level=0) if scene == "block" else hertz_sphere(level=0)).problem()
    A = problem.A
    former = ProjectedStiffness(A)
    fresh = projected_stiffness(A, _guess(problem, 0.3))
    try:
        first = former.form(_guess(problem, 0.6))
        first_norm = first.norm(PETSc.NormType.FROBENIUS)
        reused = former.form(_guess(problem, 0.3))
        assert reused is first  # the same matrix, new values
        assert abs(reused.norm(PETSc.NormType.FROBENIUS) - first_norm) > 1e-8 * first_norm
        assert reused.getInfo()["nz_used"] == fresh.getInfo()["nz_used"]
        fresh.axpy(-1.0, reused, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        assert fresh.norm(PETSc.NormType.FROBENIUS) <= 1e-13 * first_norm
    finally:
        former.destroy()
        fresh.destroy()
