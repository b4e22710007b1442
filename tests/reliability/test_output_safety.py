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
from pathlib import Path

import pytest
from mpi4py import MPI

from admm_dolfinx.cli import main
from admm_dolfinx.io.output import STAGING_MARK, output_folder, write_json

pytestmark = [pytest.mark.timeout(180), pytest.mark.mpi3]
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


def test_unwritable_out_fails_before_the_work(tmp_path_factory, capsys, monkeypatch):
    import admm_dolfinx.cli as cli

    folder = _shared(tmp_path_factory, "blocked")
    if COMM.rank == 0:
        (folder / "a_file").write_text("not a folder")
    COMM.Barrier()
    built = []
    monkeypatch.setattr(cli, "_build_scene", lambda args: built.append(args))
    status = main(["run", "example3", "--level", "1", "--out", str(folder / "a_file" / "out")])
    assert status == 1
    assert built == []  # refused before any scene was built, let alone solved
    if COMM.rank == 0:
        assert "a_file" in capsys.readouterr().err


def test_a_set_that_cannot_be_published_whole_is_not_published(tmp_path_factory, capsys):
    """A folder named summary.json in --out: the run writes none of its files (it used to
    publish the others, a mixed set), says what is in the way, and exits with 1."""
    folder = _shared(tmp_path_factory, "in_the_way")
    if COMM.rank == 0:
        before = _user_files(folder)
        (folder / "solution.h5").write_text("an older run's file")
        (folder / "summary.json").mkdir()
        (folder / "summary.json" / "keep.txt").write_text("the user's")
    COMM.Barrier()
    argv = ["run", "example1", "--h", "0.25", "--mesher", "builtin", "--out", str(folder)]
    assert main(argv) == 1
    COMM.Barrier()
    if COMM.rank == 0:
        assert "summary.json" in capsys.readouterr().err
        after = _snapshot(folder)
        assert after == {
            **before,
            "solution.h5": b"an older run's file",
            "summary.json/keep.txt": b"the user's",
        }
        assert not any(name.startswith(".") for name in os.listdir(folder))


@pytest.mark.skipif(COMM.size > 1, reason="a failure injected into rank 0's renames")
def test_a_publication_that_fails_halfway_is_undone(tmp_path, monkeypatch):
    """The last rename fails (after the others succeeded): every file goes back, the
    older files of the same names included."""
    from admm_dolfinx.io import output

    (tmp_path / "a.txt").write_text("old a")
    (tmp_path / "c.txt").write_text("old c")
    real = os.replace
    moves = []

    def failing(src, dst):
        src, dst = Path(src), Path(dst)
        if src.name == "c.txt" and dst.parent == tmp_path and STAGING_MARK in src.parent.name:
            raise PermissionError("injected")
        moves.append((src, dst))
        return real(src, dst)

    monkeypatch.setattr(output.os, "replace", failing)
    with pytest.raises(OSError, match="injected"):
        with output_folder(COMM, tmp_path) as staging:
            for name in ("a.txt", "b.txt", "c.txt"):
                (staging / name).write_text(f"new {name}")
    assert len(moves) >= 4  # a and b were published before the failure, then undone
    assert _snapshot(tmp_path) == {"a.txt": b"old a", "c.txt": b"old c"}


def test_a_refused_option_creates_no_folder(tmp_path_factory, capsys):
    folder = _shared(tmp_path_factory, "refused")
    for bad in (["--rtol", "-1"], ["--h", "1e-9"], ["--penalty", "-3"]):
        out = folder / "new" / "out"
        argv = ["run", "example1", "--mesher", "builtin", *bad, "--out", str(out)]
        assert main(argv) == 1, bad
        COMM.Barrier()
        assert not (folder / "new").exists(), bad
    if COMM.rank == 0:
        err = capsys.readouterr().err
        assert "rtol must be a positive" in err and "h must lie in [1/2048, 1]" in err


def _writer_problem():
    from admm_dolfinx.scenes.library import example1

    return example1(COMM, h=0.25, mesher="builtin").problem()


def test_contact_writer_refuses_a_missing_folder_up_front(tmp_path_factory):
    from admm_dolfinx.io.paraview import ContactWriter

    folder = _shared(tmp_path_factory, "vtx_missing")
    problem = _writer_problem()
    with pytest.raises(OSError, match=r"no_such_dir.*does not exist.*Create it first"):
        ContactWriter(problem, folder / "no_such_dir" / "out.bp")
    if COMM.rank == 0:
        (folder / "a_file").write_text("x")
    COMM.Barrier()
    with pytest.raises(OSError, match="a_file"):
        ContactWriter(problem, folder / "a_file" / "out.bp")
    assert sorted(p.name for p in folder.iterdir()) == ["a_file"]


_VTX_INTO_A_FILE = """
import sys
import admm_dolfinx
from mpi4py import MPI
from admm_dolfinx.io.paraview import ContactWriter
from admm_dolfinx.scenes.library import example1
problem = example1(MPI.COMM_SELF, h=0.5, mesher="builtin").problem()
try:
    writer = ContactWriter(problem, sys.argv[1])
except OSError as error:
    print("refused:", error)
"""


@pytest.mark.skipif(COMM.size > 1, reason="one process runs another")
def test_contact_writer_never_aborts_the_interpreter(tmp_path):
    """ADIOS2 used to accept the path, fail in write() and abort the interpreter at
    exit (status 134). The path is refused up front, and the process ends normally."""
    (tmp_path / "a_file").write_text("x")
    done = subprocess.run(
        [sys.executable, "-c", _VTX_INTO_A_FILE, str(tmp_path / "a_file" / "out.bp")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "refused:" in done.stdout and "a_file" in done.stdout


def test_contact_writer_keeps_the_users_files(tmp_path_factory):
    """An existing out.bp/ that this package did not write is left alone (ADIOS2 would
    empty it); one it wrote is written over."""
    from admm_dolfinx import ADMMSolver
    from admm_dolfinx.io.paraview import MARKER, ContactWriter

    folder = _shared(tmp_path_factory, "vtx_users")
    target = folder / "out.bp"
    if COMM.rank == 0:
        target.mkdir()
        (target / "notes.txt").write_text("the user's notes")
        (target / "data.0").write_bytes(b"someone else's")
    COMM.Barrier()
    problem = _writer_problem()
    with pytest.raises(FileExistsError, match=r"out\.bp.*did not write.*notes\.txt"):
        ContactWriter(problem, target)
    COMM.Barrier()
    assert _snapshot(target) == {"notes.txt": b"the user's notes", "data.0": b"someone else's"}
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    mine = folder / "mine.bp"
    for _ in range(2):  # the second time over its own earlier output
        with ContactWriter(problem, mine) as writer:
            writer.write(result)
        COMM.Barrier()
        assert (mine / MARKER).exists() and (mine / "md.idx").exists()
    if COMM.rank == 0:
        (mine / "notes.txt").write_text("added by the user")
    COMM.Barrier()
    with pytest.raises(FileExistsError, match=r"notes\.txt"):
        ContactWriter(problem, mine)
