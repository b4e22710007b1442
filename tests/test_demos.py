"""Every demo runs end to end at its smallest size, under ``mpiexec -n 2``.

``make test-demos`` runs these (``pytest -m demos``); the plain suite deselects them
(``addopts`` in pyproject.toml), because each starts an ``mpiexec`` of its own and must
not run inside ``mpiexec -n 2 pytest``. The book (``make docs``) executes every demo
serially at its book size, so together the demos run serially and in parallel.
``DEMO_RANKS=1,2`` runs them serially here too. A demo passes when it exits 0 within
its time limit and every solve it reports says "ADMM converged" (an unconverged solve
is reported, not raised, so the exit code alone would not show it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

DEMOS_FOLDER = Path(__file__).resolve().parents[1] / "demos"
# the Makefile's mpiexec, else the one installed next to this Python (the MPICH wheel)
MPIEXEC = os.environ.get("MPIEXEC") or str(Path(sys.executable).parent / "mpiexec")
#: seconds per demo run: below pytest's own limit, so a hang is reported as this demo's
TIMEOUT = 540
RANKS = [int(n) for n in os.environ.get("DEMO_RANKS", "2").split(",")]

#: (demo script, arguments for its smallest size)
DEMOS: list[tuple[str, list[str]]] = [
    ("example1.py", ["--h", "0.125", "--samples", "20"]),
    ("hertz.py", ["--level", "0", "--samples", "20"]),
    ("block_on_ball.py", ["--level", "0", "--samples", "10"]),
    ("block_on_ball.py", ["--level", "0", "--polish"]),
    ("load_steps.py", ["--n", "16", "--steps", "3"]),
    ("gmsh_part.py", ["--h", "0.15"]),
    ("adaptive_part.py", ["--target", "0.05"]),
]


def test_every_demo_is_run():
    """A demo added to demos/ without a line above would go untested."""
    scripts = {path.name for path in DEMOS_FOLDER.glob("*.py")}
    assert scripts == {script for script, _ in DEMOS}


@pytest.mark.demos
@pytest.mark.parametrize("nproc", RANKS)
@pytest.mark.parametrize(("script", "arguments"), DEMOS, ids=[" ".join([s, *a]) for s, a in DEMOS])
def test_demo_runs(script, arguments, nproc, tmp_path):
    """The demo exits 0 on ``nproc`` ranks, writing into a fresh folder."""
    # -m mpi4py: an exception on one rank aborts all instead of hanging
    command = [sys.executable, "-m", "mpi4py", str(DEMOS_FOLDER / script), *arguments]
    command += ["--out", str(tmp_path / "out")]
    if nproc > 1:
        command = [MPIEXEC, "-n", str(nproc), *command]
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{' '.join(command)} did not finish within {TIMEOUT} s")
    report = (
        f"--- stdout (end) ---\n{run.stdout[-4000:]}\n--- stderr (end) ---\n{run.stderr[-4000:]}"
    )
    assert run.returncode == 0, f"{' '.join(command)} exited {run.returncode}\n{report}"
    solves = [line.strip() for line in run.stdout.splitlines() if line.strip().startswith("ADMM ")]
    unconverged = [line for line in solves if not line.startswith("ADMM converged")]
    assert not unconverged, f"{script} reported unconverged solves: {unconverged}\n{report}"
