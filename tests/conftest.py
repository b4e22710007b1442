"""Shared fixtures. Collective destructors: collect garbage and synchronise after each test."""

from __future__ import annotations

import gc

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

import admm_dolfinx  # noqa: F401  (imports dolfinx_solver first when present)

PETSc.Log.begin()


@pytest.fixture(autouse=True)
def _collective_cleanup():
    yield
    gc.collect()
    MPI.COMM_WORLD.Barrier()


def gather_nodal(V_function, decimals: int = 10):
    """Gather (coordinates, values) of a P1 Function to all ranks, sorted by coordinate.

    Used to compare solutions computed on different communicators / partitions.
    """
    V = V_function.function_space
    comm = V.mesh.comm
    n_owned = V.dofmap.index_map.size_local
    bs = V.dofmap.index_map_bs
    coords = V.tabulate_dof_coordinates()[:n_owned]
    values = V_function.x.array[: n_owned * bs].reshape(n_owned, bs)
    coords = np.concatenate(comm.allgather(coords))
    values = np.concatenate(comm.allgather(values))
    order = np.lexsort(np.round(coords, decimals).T[::-1])
    return coords[order], values[order]


def rel_diff(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    scale = max(np.linalg.norm(a), np.linalg.norm(b))
    return float(np.linalg.norm(a - b) / scale) if scale > 0 else 0.0


def problem_from(scene, **changes):
    """The scene's ContactProblem with any constructor argument replaced (by name)."""
    from admm_dolfinx import ContactProblem

    args = {
        "a": scene.a,
        "L": scene.L,
        "bcs": scene.bcs,
        "facet_tags": scene.facet_tags,
        "contact_marker": scene.contact_marker,
        "obstacle": scene.obstacle,
    }
    args.update(changes)
    return ContactProblem(**args)
