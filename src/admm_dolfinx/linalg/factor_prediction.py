"""What a 3D factorisation would cost, bracketed from the mesh alone, before any analysis.

MUMPS's analysis (:mod:`admm_dolfinx.linalg.factor_estimate`) orders the matrix to
tell what its factorisation would cost, and that ordering takes a few per cent of a
large solve. Where the answer to "factorise or not" is obvious, a model of nested
dissection on the body gives it for nothing:

* the body is taken as a box with the proportions of its bounding box and the volume
  of its cells, filled with ρ = n / V dofs per unit volume;
* nested dissection cuts the box's longest side in two, level after level: at level k
  the 2^k separators each hold s_k = ρ^{2/3} × (the area of the cut) dofs, and
  eliminating each costs about s_k³ operations and s_k² entries. The model's count
  is C Σ_k 2^k s_k³ operations and C_m Σ_k 2^k s_k² bytes, with C
  (:data:`FLOPS_CONSTANT`) and C_m (:data:`MEMORY_CONSTANT`) fitted to MUMPS's own
  figures for 3D vector fields (three dofs per node: the constants absorb the block
  size).

The model is a bracket, not an estimate to act on near a threshold: MUMPS's figures
lie within a factor :data:`PREDICTION_BAND` of it on the package's 3D scenes (blocks,
graded blocks, a slab, a quarter-ball, tetrahedra and hexahedra) and on boxes shaped as
cubes, bars, a slab and a plate, degree 1 and 2 (``python
benchmarks/factor_prediction.py`` measures the ratios, against MUMPS's sequential
analysis; ``tests/linalg/test_factor_prediction.py`` checks the bracket, under MPI
against the parallel analysis). The memory's upper end grows with the processes: the
parallel analysis's total does (1.5-1.7 times the sequential one's on two, the
``mpiexec -n 2`` table of ``python benchmarks/scale_3d.py --mpi``). The step-1 plan
(:mod:`admm_dolfinx.admm.plan`) runs MUMPS's analysis only where the two ends of the
bracket lead to different choices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from dolfinx import mesh

__all__ = [
    "FLOPS_CONSTANT",
    "MEMORY_CONSTANT",
    "PREDICTION_BAND",
    "FactorBracket",
    "mesh_volume",
    "nested_dissection",
    "predict_factorisation",
]

#: C of the model's operations C Σ_k 2^k s_k³ (the geometric mean of MUMPS's count
#: over Σ_k 2^k s_k³ on the meshes of ``python benchmarks/factor_prediction.py``).
FLOPS_CONSTANT = 14.0
#: C_m of the model's memory C_m Σ_k 2^k s_k² bytes (the geometric mean likewise).
MEMORY_CONSTANT = 58.0
#: MUMPS's figures lie within this factor of the model's, either way.
PREDICTION_BAND = 10.0


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

    A tetrahedron is measured by its vertices (exact for straight-sided cells), a
    hexahedron by its Jacobian at the centre (exact for parallelepipeds). None for
    other cell types.
    """
    # per cell type: the (from, to) vertex pairs whose mean is each edge vector of the
    # cell's map, and the volume of the reference cell (DOLFINx's vertex numbering)
    edges = {
        mesh.CellType.tetrahedron: ([[(0, 1)], [(0, 2)], [(0, 3)]], 1.0 / 6.0),
        mesh.CellType.hexahedron: (
            [
                [(0, 1), (2, 3), (4, 5), (6, 7)],
                [(0, 2), (1, 3), (4, 6), (5, 7)],
                [(0, 4), (1, 5), (2, 6), (3, 7)],
            ],
            1.0,
        ),
    }
    if msh.topology.cell_type not in edges:
        return None
    pairs, scale = edges[msh.topology.cell_type]
    owned = msh.topology.index_map(msh.topology.dim).size_local
    cells = msh.geometry.dofmaps[0][:owned]
    x = msh.geometry.x
    a, b, c = (
        sum(x[cells[:, j]] - x[cells[:, i]] for i, j in direction) / len(direction)
        for direction in pairs
    )
    # the triple product a · (b × c), component by component (np.cross and a gather of
    # the whole (cells, nodes, 3) array take several times as long)
    det = (
        a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
        - a[:, 1] * (b[:, 0] * c[:, 2] - b[:, 2] * c[:, 0])
        + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])
    )
    local = scale * float(np.abs(det).sum())
    return float(msh.comm.allreduce(local))


def nested_dissection(extents, num_dofs: float) -> tuple[float, float]:
    """(Σ_k 2^k s_k³, Σ_k 2^k s_k²) for a box of these sides holding ``num_dofs`` evenly.

    Raises:
        ValueError: For a side that is not positive and finite.
    """
    sides = np.sort(np.asarray(extents, dtype=float))
    if sides.shape != (3,) or not (np.all(np.isfinite(sides)) and sides[0] > 0.0):
        raise ValueError(f"nested_dissection needs three positive sides; got {extents}")
    density = float(num_dofs) / float(np.prod(sides))
    operations = entries = 0.0
    count = 1.0
    while density * float(np.prod(sides)) > 1.0:
        separator = sides[0] * sides[1] * density ** (2.0 / 3.0)
        operations += count * separator**3
        entries += count * separator**2
        sides = np.sort([sides[0], sides[1], sides[2] / 2.0])
        count *= 2.0
    return operations, entries


def predict_factorisation(
    extents, volume: float | None, num_dofs: int, processes: int = 1
) -> FactorBracket | None:
    """The bracket of a factorisation's cost for ``num_dofs`` dofs on a 3D body.

    Args:
        extents: The side lengths of the body's bounding box.
        volume: The body's volume (:func:`mesh_volume`); None takes the box's.
        num_dofs: The global size of the matrix to factorise.
        processes: The processes the factorisation is spread over.

    Returns:
        The bracket (operations and memory within :data:`PREDICTION_BAND` of the
        model's either way, the memory's upper end times ``processes``), or None where
        the model has nothing to say (a flat box, a count of zero).
    """
    box = np.asarray(extents, dtype=float)
    if box.shape != (3,) or not (np.all(np.isfinite(box)) and box.min() > 0.0):
        return None
    # a box of the bounding box's proportions and the cells' volume
    if volume is not None and math.isfinite(volume) and volume > 0.0:
        box = box * (volume / float(np.prod(box))) ** (1.0 / 3.0)
    operations, entries = nested_dissection(box, float(num_dofs))
    flops, memory = FLOPS_CONSTANT * operations, MEMORY_CONSTANT * entries
    if not (flops > 0.0 and math.isfinite(flops) and math.isfinite(memory)):
        return None
    band = PREDICTION_BAND
    return FactorBracket(
        flops=(flops / band, flops * band),
        memory=(memory / band, memory * band * max(1, processes)),
        model_flops=flops,
    )
