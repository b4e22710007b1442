"""Ranks that share a node share its cores: BLAS threads per rank (`_threads`).

Run serially and under the suite's ``mpiexec -n 2`` and ``-n 3``: with one rank per node
nothing changes; with several, every BLAS pool of the process holds at most its share of
the cores, and a count the user chose is kept.
"""

from __future__ import annotations

import pytest
from mpi4py import MPI
from threadpoolctl import threadpool_info, threadpool_limits

import admm_dolfinx
from admm_dolfinx._threads import THREAD_VARIABLES, _cores, share_cores
from admm_dolfinx.scenes import example1

COMM = MPI.COMM_WORLD


def _ranks_on_node() -> int:
    node = COMM.Split_type(MPI.COMM_TYPE_SHARED)
    size = node.size
    node.Free()
    return size


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


@pytest.fixture
def no_user_count(monkeypatch):
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)


def test_each_rank_keeps_its_share_of_the_cores(no_user_count):
    ranks = _ranks_on_node()
    with threadpool_limits(limits=_cores(), user_api="blas"):  # as many as the node has
        before = _blas_threads()
        limit = share_cores(COMM)
        after = _blas_threads()
    if ranks == 1:
        assert limit is None and after == before
    else:
        assert limit == max(1, _cores() // ranks)
        assert all(n <= limit for n in after)
        # only ever lowered: a pool that had fewer threads keeps them
        assert all(a == min(b, limit) for a, b in zip(after, before, strict=True))


def test_a_count_the_user_chose_is_kept(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", str(_cores()))
    with threadpool_limits(limits=_cores(), user_api="blas"):
        before = _blas_threads()
        assert share_cores(COMM) is None
        assert _blas_threads() == before


def test_the_solver_applies_it(no_user_count):
    problem = example1(h=1 / 8).problem()
    with threadpool_limits(limits=_cores(), user_api="blas"):
        before = _blas_threads()
        solver = admm_dolfinx.ADMMSolver(problem)
        threads = _blas_threads()
        solver.destroy()
    ranks = _ranks_on_node()
    if ranks == 1:
        assert threads == before
    else:
        assert all(n <= max(1, _cores() // ranks) for n in threads)
        assert max(before) > max(1, _cores() // ranks)  # so that the test can fail
