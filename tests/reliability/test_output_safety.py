"""No command deletes anything it did not write; each file is whole or absent.

``admm-dolfinx run ... --out DIR`` once replaced DIR entirely (``--out .`` deleted a
working tree). Now a command writes its own files into DIR and nothing else; a run
killed while writing leaves only a marked staging folder, which the next write into
DIR removes; files get the permissions the umask allows.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mpi4py import MPI

from admm_dolfinx.cli import main
from admm_dolfinx.io.output import STAGING_MARK, output_folder, write_json

pytestmark = pytest.mark.timeout(180)
COMM = MPI.COMM_WORLD


def _shared(tmp_path_factory, name: str) -> Path:
    path = str(tmp_path_factory.mktemp(name)) if COMM.rank == 0 else None
    return Path(COMM.bcast(path, root=0))


def _user_files(folder: Path) -> dict[str, bytes]:
    (folder / "notes.txt").write_text("the user's own notes")
    (folder / "solution.py").write_text("print('a user script')")
    (folder / "data").mkdir()
    (folder / "data" / "mesh.msh").write_bytes(b"\x00\x01 mesh")
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_run_out_keeps_the_users_files(tmp_path_factory):
    folder = _shared(tmp_path_factory, "users_folder")
    before = _user_files(folder) if COMM.rank == 0 else None
    argv = ["run", "example1", "--h", "0.25", "--mesher", "builtin", "--out", str(folder)]
    assert main(argv) == 0
    assert main(argv) == 0  # a second run replaces its own files only
    COMM.Barrier()
    if COMM.rank == 0:
        after = _snapshot(folder)
        for name, content in before.items():
            assert after[name] == content, f"{name} was changed"
        written = set(after) - set(before)
        assert {"solution.xdmf", "solution.h5", "summary.json"} <= written
        assert not any(name.startswith(".") for name in os.listdir(folder))


_KILLED_WRITER = """
import sys, time
from pathlib import Path
import admm_dolfinx
from mpi4py import MPI
from admm_dolfinx.io.output import output_folder
with output_folder(MPI.COMM_SELF, sys.argv[1]) as tmp:
    (tmp / "result.txt").write_text("half of it")
    print("writing", flush=True)
    time.sleep(120)
"""


@pytest.mark.skipif(COMM.size > 1, reason="one process kills another")
def test_kill_during_a_write_leaves_no_debris(tmp_path):
    before = _user_files(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(tmp_path)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline().strip() == "writing"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    # the killed run's staging folder is all it left; no final file appeared
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(STAGING_MARK)]
    assert len(leftovers) == 1 and not (tmp_path / "result.txt").exists()
    # the next write into the folder removes it, and touches nothing else
    with output_folder(MPI.COMM_SELF, tmp_path) as staging:
        (staging / "result.txt").write_text("whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["data", "notes.txt", "solution.py", "result.txt"]
    )
    assert {k: v for k, v in _snapshot(tmp_path).items() if k != "result.txt"} == before


@pytest.mark.skipif(COMM.size > 1, reason="one process kills another")
def test_a_live_runs_staging_folder_is_left_alone(tmp_path):
    """Another run writing into the same folder right now keeps its staging folder."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "writing"
        with output_folder(MPI.COMM_SELF, tmp_path) as staging:
            (staging / "mine.txt").write_text("whole")
        leftovers = [p for p in tmp_path.iterdir() if p.name.startswith(STAGING_MARK)]
        assert len(leftovers) == 1 and (leftovers[0] / "result.txt").exists()
    finally:
        proc.kill()
        proc.wait(timeout=30)


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_outputs_respect_the_umask(tmp_path_factory, mask):
    folder = _shared(tmp_path_factory, f"umask{mask:o}")
    old = os.umask(mask)
    try:
        with output_folder(COMM, folder / "new") as staging:
            if COMM.rank == 0:
                (staging / "a.txt").write_text("x")
        write_json(COMM, folder / "new" / "b.json", {"a": 1})
        COMM.Barrier()
        if COMM.rank == 0:
            assert (folder / "new").stat().st_mode & 0o777 == 0o777 & ~mask
            for name in ("a.txt", "b.json"):
                assert (folder / "new" / name).stat().st_mode & 0o777 == 0o666 & ~mask
    finally:
        os.umask(old)


def test_unwritable_out_fails_before_the_work(tmp_path_factory, capsys):
    folder = _shared(tmp_path_factory, "blocked")
    if COMM.rank == 0:
        (folder / "a_file").write_text("not a folder")
    COMM.Barrier()
    t0 = time.perf_counter()
    status = main(["run", "example3", "--level", "1", "--out", str(folder / "a_file" / "out")])
    assert status == 1
    assert time.perf_counter() - t0 < 20  # no solve happened first
    if COMM.rank == 0:
        assert "a_file" in capsys.readouterr().err
