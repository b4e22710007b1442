"""The one home of rank-0 gathers, scatters and errors raised on every rank (`_mpi`).

Every layout is tried, including ranks that own nothing (the first, a middle and the
last rank), against the same arrays assembled by hand; serially and under the test
suite's `mpiexec -n 2, 3, 4` runs.
"""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

import admm_dolfinx  # noqa: F401  (loads MPI/PETSc in the right order)
from admm_dolfinx._mpi import (
    OnRank0,
    RankLayout,
    collective_call,
    from_rank0,
    gather_concat,
    gather_csr,
    raise_collectively,
    run_on_rank0,
)

pytestmark = [pytest.mark.mpi3, pytest.mark.mpi4]

COMM = MPI.COMM_WORLD


def _sizes(pattern: str) -> list[int]:
    """Values per rank: 'all' every rank has some; 'first'/'last'/'middle' one has none."""
    sizes = [3 + rank for rank in range(COMM.size)]
    empty = {"first": 0, "last": COMM.size - 1, "middle": COMM.size // 2}.get(pattern)
    if empty is not None:
        sizes[empty] = 0
    if pattern == "one":  # only the last rank has values
        sizes = [0] * (COMM.size - 1) + [5]
    return sizes


PATTERNS = ["all", "first", "middle", "last", "one"]


def _local(sizes: list[int], k: int) -> tuple[np.ndarray, np.ndarray]:
    """This rank's (k, n_loc) block and the whole (k, n) array it belongs to."""
    n = sum(sizes)
    whole = np.arange(k * n, dtype=np.float64).reshape(k, n) + 0.5
    start = sum(sizes[: COMM.rank])
    return whole[:, start : start + sizes[COMM.rank]], whole


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("k", [None, 1, 3])
def test_gather_and_scatter_are_inverse_on_every_layout(pattern, k):
    sizes = _sizes(pattern)
    block, whole = _local(sizes, 1 if k is None else k)
    rows = block[0] if k is None else block
    layout = RankLayout(COMM, sizes[COMM.rank])
    assert layout.total == sum(sizes) and list(layout.counts) == sizes
    gathered = layout.gather(rows)
    if COMM.rank == 0:
        np.testing.assert_array_equal(gathered, whole[0] if k is None else whole)
    else:
        assert gathered is None
    back = layout.scatter(gathered, k)
    np.testing.assert_array_equal(back, rows)
    np.testing.assert_array_equal(layout.allgather(block[0]), whole[0])


@pytest.mark.parametrize("pattern", PATTERNS)
def test_gather_concat_and_csr_on_every_layout(pattern):
    sizes = _sizes(pattern)
    block, whole = _local(sizes, 1)
    ids = np.arange(sizes[COMM.rank], dtype=np.int64) + sum(sizes[: COMM.rank])
    concat = gather_concat(COMM, block[0], ids)
    # a CSR block per rank: row i of the whole matrix holds (i, i+1) with values i, -i
    n_rows = sizes[COMM.rank]
    indptr = np.arange(0, 2 * n_rows + 1, 2, dtype=np.int64)
    indices = np.column_stack([ids, ids + 1]).ravel()
    data = np.column_stack([ids, -ids]).ravel().astype(np.float64)
    csr = gather_csr(COMM, (indptr, indices, data))
    if COMM.rank == 0:
        np.testing.assert_array_equal(concat[0], whole[0])
        np.testing.assert_array_equal(concat[1], np.arange(sum(sizes)))
        all_ids = np.arange(sum(sizes))
        np.testing.assert_array_equal(csr[0], np.arange(0, 2 * sum(sizes) + 1, 2))
        np.testing.assert_array_equal(csr[1], np.column_stack([all_ids, all_ids + 1]).ravel())
        np.testing.assert_array_equal(csr[2], np.column_stack([all_ids, -all_ids]).ravel())
    else:
        assert concat is None and csr is None


@pytest.mark.parametrize("failing", ["first", "last", "all", "none"])
def test_an_error_on_some_ranks_is_raised_on_every_rank(failing):
    fails = {
        "first": COMM.rank == 0,
        "last": COMM.rank == COMM.size - 1,
        "all": True,
        "none": False,
    }[failing]

    def work():
        if fails:
            raise ValueError(f"bad value on {COMM.rank}")
        return COMM.rank

    if failing == "none":
        assert collective_call(COMM, work, "work") == COMM.rank
        raise_collectively(COMM, None, "nothing")
        return
    lowest = 0 if failing in ("first", "all") else COMM.size - 1
    with pytest.raises(ValueError, match=f"bad value on {lowest}"):
        collective_call(COMM, work, "work")
    # the communicator is still usable: nobody is left waiting
    assert COMM.allreduce(1) == COMM.size


def test_rank0_work_and_its_failure_reach_every_rank():
    assert from_rank0(COMM, COMM.rank * 10 + 7) == 7
    assert run_on_rank0(COMM, lambda: "done", lambda n, t, o: RuntimeError(t)) == "done"
    kept = run_on_rank0(COMM, lambda: [1, 2], lambda n, t, o: RuntimeError(t), broadcast=False)
    assert kept == ([1, 2] if COMM.rank == 0 else None)

    def failure(name, text, is_os_error):
        return OSError(text) if is_os_error else RuntimeError(f"{name}: {text}")

    def broken():
        raise PermissionError("read-only folder")

    with pytest.raises(OSError, match="read-only folder"):
        run_on_rank0(COMM, broken, failure)
    assert COMM.allreduce(1) == COMM.size


def test_on_rank0_block():
    """The inline form: the block's work runs on rank 0 only, its value reaches every
    rank (or stays on rank 0), and its failure is raised on every rank, not a hang."""
    ran = []
    with OnRank0(COMM, lambda n, t, o: RuntimeError(t)) as work:
        if work.here:
            ran.append(COMM.rank)
            work.value = {"answer": 42}
    assert work.value == {"answer": 42}
    assert COMM.allgather(ran) == [[0]] + [[]] * (COMM.size - 1)
    with OnRank0(COMM, lambda n, t, o: RuntimeError(t), broadcast=False) as kept:
        if kept.here:
            kept.value = [1, 2]
    assert kept.value == ([1, 2] if COMM.rank == 0 else None)
    with pytest.raises(RuntimeError, match="ValueError: bad pivot") as caught:
        with OnRank0(COMM, lambda n, t, o: RuntimeError(f"{n}: {t}")) as broken:
            if broken.here:
                raise ValueError("bad pivot")
    if COMM.rank == 0:  # chained to the original there
        assert isinstance(caught.value.__cause__, ValueError)
    assert COMM.allreduce(1) == COMM.size
