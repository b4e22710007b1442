"""Ranks that share a node share its cores: BLAS threads per rank (`_threads`).

Run serially and under the suite's ``mpiexec -n 2`` and ``-n 3``: with one rank per node
nothing changes; with several, every BLAS pool of the process holds at most its share of
the cores, a pool below it keeps its count, and a count the user chose is kept.
"""

from __future__ import annotations

import pytest
from mpi4py import MPI
from threadpoolctl import threadpool_info, threadpool_limits

import admm_dolfinx
from admm_dolfinx import _threads
from admm_dolfinx._threads import THREAD_VARIABLES, cores_per_rank, pools_above, share_cores
from admm_dolfinx.scenes import example1

pytestmark = [pytest.mark.mpi3]

COMM = MPI.COMM_WORLD


@pytest.fixture
def node():
    node = COMM.Split_type(MPI.COMM_TYPE_SHARED)
    yield node
    node.Free()


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def _all_cores() -> int:
    return len(_threads._affinity())


@pytest.fixture
def no_user_count(monkeypatch):
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)


def test_pinned_ranks_keep_their_cores_and_others_share(node, monkeypatch):
    """Disjoint affinity masks (a launcher that pins ranks): each rank keeps its own
    cores; one mask for all: the cores are divided among the ranks."""
    rank = node.rank
    monkeypatch.setattr(_threads, "_affinity", lambda: frozenset({2 * rank, 2 * rank + 1}))
    assert cores_per_rank(node) == 2
    monkeypatch.setattr(_threads, "_affinity", lambda: frozenset(range(4 * node.size)))
    assert cores_per_rank(node) == 4
    monkeypatch.setattr(_threads, "_affinity", lambda: frozenset({0}))
    assert cores_per_rank(node) == 1


def test_only_the_pools_above_the_limit_are_lowered():
    info = [
        {"user_api": "blas", "filepath": "/a.so", "num_threads": 8},
        {"user_api": "blas", "filepath": "/b.so", "num_threads": 1},
        {"user_api": "openmp", "filepath": "/c.so", "num_threads": 8},
        {"user_api": "blas", "filepath": "/d.so", "num_threads": 4},
    ]
    assert pools_above(info, 4) == {"/a.so": 4}
    assert pools_above(info, 1) == {"/a.so": 1, "/d.so": 1}
    assert pools_above(info, 8) == {}


def test_each_rank_keeps_its_share_of_the_cores(no_user_count, node):
    with threadpool_limits(limits=_all_cores(), user_api="blas"):  # as many as the node has
        before = _blas_threads()
        limit = share_cores(COMM)
        after = _blas_threads()
    if node.size == 1:
        assert limit is None and after == before
    else:
        assert limit == cores_per_rank(node)
        assert all(a == min(b, limit) for a, b in zip(after, before, strict=True))


def test_a_count_the_user_chose_is_kept(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", str(_all_cores()))
    with threadpool_limits(limits=_all_cores(), user_api="blas"):
        before = _blas_threads()
        assert share_cores(COMM) is None
        assert _blas_threads() == before


def test_the_solver_applies_it(no_user_count, node):
    problem = example1(h=1 / 8).problem()
    limit = cores_per_rank(node)
    with threadpool_limits(limits=_all_cores(), user_api="blas"):
        before = _blas_threads()
        solver = admm_dolfinx.ADMMSolver(problem)
        threads = _blas_threads()
        solver.destroy()
    if node.size == 1:
        assert threads == before
    else:
        assert all(n == min(b, limit) for n, b in zip(threads, before, strict=True))
        if max(before) <= limit:
            pytest.skip("every pool is within this rank's share already")
        assert max(threads) < max(before)
