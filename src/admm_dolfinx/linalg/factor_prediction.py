"""What a 3D factorisation would cost, bracketed from the mesh alone, before any analysis.

MUMPS's analysis (:mod:`admm_dolfinx.linalg.factor_estimate`) orders the matrix to
tell what its factorisation would cost, and that ordering is itself a few per cent of a
large solve, the largest share of the set-up under MPI. Where the answer to "factorise
or not" is obvious, a model of nested dissection on the body gives it for nothing:

* the body is taken as a box with the proportions of its bounding box and the volume
  of its cells, filled with ρ = n / V dofs per unit volume;
* nested dissection cuts the box's longest side in two, level after level: at level k
  the 2^k separators each hold s_k = ρ^{2/3} × (the area of the cut) dofs, and
  eliminating each costs about s_k³. The model's count is C Σ_k 2^k s_k³, with C
  (:data:`FLOPS_CONSTANT`) calibrated against MUMPS's own count.

The model is a bracket, not an estimate to act on near a threshold: MUMPS's count
lies within a factor :data:`PREDICTION_BAND` of it on cubes, blocks, slabs, plates,
bars and a half-ball, tetrahedra and hexahedra, degree 1 and 2
(``python benchmarks/factor_prediction.py`` measures the ratio;
``tests/linalg/test_factor_prediction.py`` checks the bracket). The memory of the
factors follows from the count: :data:`MEMORY_PER_FLOPS` bytes per flops^{2/3}
bracket MUMPS's figure on the same meshes. The step-1 plan
(:mod:`admm_dolfinx.admm.plan`) runs MUMPS's analysis only when the whole bracket
does not fall on one side of its thresholds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from dolfinx import mesh

__all__ = [
    "FLOPS_CONSTANT",
    "MEMORY_PER_FLOPS",
    "PREDICTION_BAND",
    "FactorBracket",
    "mesh_volume",
    "nested_dissection_flops",
    "predict_factorisation",
]

#: C of the model's count C Σ_k 2^k s_k³ (the geometric mean of MUMPS's count over
#: the model's on the meshes of ``python benchmarks/factor_prediction.py``).
FLOPS_CONSTANT = 14.0
#: MUMPS's count lies within this factor of the model's, either way.
PREDICTION_BAND = 10.0
#: Bytes of MUMPS's in-core memory per flops^{2/3} of its count: (low, high) bounds.
MEMORY_PER_FLOPS = (20.0, 100.0)


@dataclass(frozen=True)
class FactorBracket:
    """Bounds on what a Cholesky factorisation would cost, from the mesh.

    Attributes:
        flops: (low, high) operations of the elimination.
        memory: (low, high) bytes of the factorisation over all processes.
        model_flops: The model's count C Σ_k 2^k s_k³ (the bracket's geometric centre).
    """

    flops: tuple[float, float]
    memory: tuple[float, float]
    model_flops: float


def mesh_volume(msh: mesh.Mesh) -> float | None:
    """The volume of a 3D mesh's cells, summed over the ranks' owned cells; collective.

    Tetrahedra are measured exactly (by their vertices); a hexahedron is taken as the
    parallelepiped on its first vertex's three edges. None for other cell types.
    """
    corners = {
        mesh.CellType.tetrahedron: ([1, 2, 3], 1.0 / 6.0),
        mesh.CellType.hexahedron: ([1, 2, 4], 1.0),
    }
    if msh.topology.cell_type not in corners:
        return None
    others, scale = corners[msh.topology.cell_type]
    owned = msh.topology.index_map(msh.topology.dim).size_local
    cells = msh.geometry.dofmaps[0][:owned]
    x = msh.geometry.x
    origin = x[cells[:, 0]]
    a, b, c = (x[cells[:, k]] - origin for k in others)
    # the triple product a · (b × c), component by component (np.cross and a gather of
    # the whole (cells, nodes, 3) array take several times as long)
    det = (
        a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
        - a[:, 1] * (b[:, 0] * c[:, 2] - b[:, 2] * c[:, 0])
        + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])
    )
    local = scale * float(np.abs(det).sum())
    return float(msh.comm.allreduce(local))


def nested_dissection_flops(extents: np.ndarray, num_dofs: float) -> float:
    """Σ_k 2^k s_k³ for a box of these side lengths holding ``num_dofs`` dofs evenly."""
    sides = np.sort(np.asarray(extents, dtype=float))
    volume = float(np.prod(sides))
    if num_dofs <= 1.0 or volume <= 0.0:
        return 0.0
    density = num_dofs / volume
    total, count = 0.0, 1.0
    while density * float(np.prod(sides)) > 1.0:
        separator = sides[0] * sides[1] * density ** (2.0 / 3.0)
        total += count * separator**3
        sides = np.sort([sides[0], sides[1], sides[2] / 2.0])
        count *= 2.0
    return total


def predict_factorisation(
    extents: np.ndarray, volume: float | None, num_dofs: int
) -> FactorBracket:
    """The bracket of a factorisation's cost for ``num_dofs`` dofs on a 3D body.

    Args:
        extents: The side lengths of the body's bounding box.
        volume: The body's volume (:func:`mesh_volume`); None takes the box's.
        num_dofs: The global size of the matrix to factorise.

    Returns:
        The bracket: flops within :data:`PREDICTION_BAND` of the model's count either
        way, memory by :data:`MEMORY_PER_FLOPS` from those.
    """
    box = np.maximum(np.asarray(extents, dtype=float), 0.0)
    # a box of the bounding box's proportions and the cells' volume
    if volume is not None and volume > 0.0 and float(np.prod(box)) > 0.0:
        box = box * (volume / float(np.prod(box))) ** (1.0 / 3.0)
    model = FLOPS_CONSTANT * nested_dissection_flops(box, float(num_dofs))
    flops = (model / PREDICTION_BAND, model * PREDICTION_BAND)
    low, high = MEMORY_PER_FLOPS
    memory = (low * flops[0] ** (2.0 / 3.0), high * flops[1] ** (2.0 / 3.0))
    return FactorBracket(flops=flops, memory=memory, model_flops=model)
