"""The adaptive steps agree across ranks: shared vertices, marked cells, counts, errors.

Each test compares a run on COMM_WORLD with one on COMM_SELF (under mpiexec) or checks
that every rank's copy of a shared vertex is the same; serially they check the same
statements on one rank.
"""

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx.adapt.estimator import EdgeIndicators
from admm_dolfinx.adapt.marking import (
    all_local_edges,
    contact_zone_edges,
    count_edges,
    doerfler_edges,
)
from admm_dolfinx.adapt.refinement import refine_contact_mesh
from admm_dolfinx.scenes import library as lib

pytestmark = [pytest.mark.mpi3]


def _scene(comm):
    return lib.hertz(comm, half_width=0.2, h_contact=1.0, h_far=1.0)


def _disagreeing_copies(msh):
    """Shared geometry nodes whose copies on different ranks are not at the same point."""
    index_map = msh.geometry.index_map()
    n = index_map.size_local + index_map.num_ghosts
    numbers = index_map.local_to_global(np.arange(n, dtype=np.int32))
    pieces = msh.comm.allgather((numbers, msh.geometry.x[:n].copy()))
    seen, bad = {}, 0
    for global_numbers, points in pieces:
        for g, x in zip(global_numbers.tolist(), points, strict=True):
            if g in seen and np.linalg.norm(seen[g] - x) > 1e-12:
                bad += 1
            seen.setdefault(g, x)
    return bad


def test_vertices_put_on_the_true_surface_are_put_there_by_every_rank():
    scene = _scene(MPI.COMM_WORLD)
    msh, tags = scene.mesh, scene.facet_tags
    for _ in range(3):
        msh, tags, _ = refine_contact_mesh(
            msh, tags, all_local_edges(msh), scene.contact_marker, scene.surface
        )
        assert _disagreeing_copies(msh) == 0


@pytest.mark.parametrize("window", [(2.0, 4.0), (5.0, 7.0)])
def test_the_contact_zone_marks_the_same_cells_on_every_partition(window):
    cells = []
    for comm in (MPI.COMM_SELF, MPI.COMM_WORLD):
        scene = _scene(comm)
        problem = scene.problem()
        x = problem.contact.coordinates[:, 0]
        active = ((x >= window[0]) & (x <= window[1])).astype(float)
        edges = contact_zone_edges(problem, active)
        fine, _, _ = refine_contact_mesh(
            problem.mesh, problem.facet_tags, edges, problem.contact_marker, scene.surface
        )
        cells.append((fine.topology.index_map(2).size_global, count_edges(problem.mesh, edges)))
        problem.destroy()
    assert cells[0] == cells[1]


@pytest.mark.parametrize(
    "values, theta, marked",
    [
        ([4.0, 3.0, 2.0, 1.0], 0.4, [0]),
        ([5.0] + [1.0] * 10, 0.3, [0]),
        ([1.0, 1.0, 0.5], 1.0, [0, 1, 2]),
    ],
)
def test_doerfler_marks_the_smallest_set(values, theta, marked):
    eta = np.array(values)
    indicators = EdgeIndicators(eta, np.ones(eta.size, bool), np.zeros((eta.size, 2)))
    assert doerfler_edges(indicators, theta, MPI.COMM_SELF).tolist() == marked


def test_a_surface_map_that_fails_on_one_rank_fails_on_every_rank():
    comm = MPI.COMM_WORLD
    scene = _scene(comm)
    # the first rank that holds Γ_C (a rank without it never calls the map)
    holds = comm.allgather(scene.facet_tags.find(scene.contact_marker).size > 0)
    failing = holds.index(True)

    def surface(x):
        if comm.rank == failing:
            raise RuntimeError("no surface here")
        return scene.surface(x)

    with pytest.raises(RuntimeError, match="surface"):
        refine_contact_mesh(
            scene.mesh, scene.facet_tags, all_local_edges(scene.mesh), scene.contact_marker, surface
        )


def test_a_surface_map_of_the_wrong_shape_is_named():
    scene = _scene(MPI.COMM_WORLD)
    with pytest.raises(ValueError, match="same shape"):
        refine_contact_mesh(
            scene.mesh,
            scene.facet_tags,
            all_local_edges(scene.mesh),
            scene.contact_marker,
            lambda x: x[:, :1],
        )


@pytest.mark.parametrize("gdim,cells", [(2, (6, 5)), (2, (1, 1)), (3, (4, 3, 3))])
@pytest.mark.parametrize("degree", [1, 2])
def test_the_transfer_through_parent_cells_equals_the_located_one(gdim, cells, degree):
    """A coarse function evaluated in each fine cell's parent equals the non-matching
    interpolation that locates the fine points (independent: a search in the coarse
    mesh), to round-off, for vector and scalar spaces and every partition (the square
    of two cells leaves ranks without cells under mpiexec -n 3)."""
    from dolfinx import fem, mesh

    from admm_dolfinx.adapt.refinement import (
        _interpolate_by_search,
        _interpolate_in_parents,
        refine_contact_mesh,
    )

    comm = MPI.COMM_WORLD
    if gdim == 2:
        msh = mesh.create_unit_square(comm, *cells)
    else:
        msh = mesh.create_unit_cube(comm, *cells)
    msh.topology.create_entities(1)
    msh.topology.create_connectivity(gdim - 1, gdim)
    tags = mesh.meshtags(msh, gdim - 1, np.zeros(0, np.int32), np.zeros(0, np.int32))
    edges = np.arange(0, msh.topology.index_map(1).size_local, 3, dtype=np.int32)
    fine, _, parents = refine_contact_mesh(msh, tags, edges, 1)
    for shape in ((gdim,), ()):
        coarse_space = fem.functionspace(msh, ("Lagrange", degree, shape))
        fine_space = fem.functionspace(fine, ("Lagrange", degree, shape))
        source = fem.Function(coarse_space)
        components = [lambda x, i=i: np.sin(3 * x[0] + i) * np.exp(x[1]) for i in range(gdim)]
        if shape:
            source.interpolate(lambda x, c=components: np.vstack([f(x) for f in c]))
        else:
            source.interpolate(components[0])
        by_parent, by_search = fem.Function(fine_space), fem.Function(fine_space)
        _interpolate_in_parents(by_parent, source, parents)
        _interpolate_by_search(by_search, source)
        difference = np.abs(by_parent.x.array - by_search.x.array).max(initial=0.0)
        assert comm.allreduce(difference, op=MPI.MAX) <= 1e-12
        size = np.abs(by_search.x.array).max(initial=0.0)
        assert comm.allreduce(size, op=MPI.MAX) > 0.1  # not two zero functions
