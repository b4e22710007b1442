"""Run every demo at its smallest size under ``mpiexec -n 2`` (``--serial``: also serially).

Used by ``make test`` (and so by CI), where the book (``make docs``) executes every
demo serially, at its book size. Each demo writes into a temporary folder.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
# the Makefile's mpiexec, else the one installed next to this Python (the MPICH wheel)
MPIEXEC = os.environ.get("MPIEXEC") or str(Path(sys.executable).parent / "mpiexec")
TIMEOUT = 600  # seconds per demo run

# (demo script, arguments for its smallest size)
DEMOS: list[tuple[str, list[str]]] = [
    ("example1.py", ["--h", "0.125", "--samples", "20"]),
    ("hertz.py", ["--level", "0", "--samples", "20"]),
    ("block_on_ball.py", ["--level", "0", "--samples", "10"]),
    ("block_on_ball.py", ["--level", "0", "--polish"]),
    ("load_steps.py", ["--n", "16", "--steps", "3"]),
    ("gmsh_part.py", ["--h", "0.15"]),
    ("adaptive_part.py", ["--target", "0.05"]),
]


def main() -> int:
    failures = []
    counts = (1, 2) if "--serial" in sys.argv[1:] else (2,)
    for script, extra in DEMOS:
        for nproc in counts:
            with tempfile.TemporaryDirectory() as tmp:
                # -m mpi4py: an exception on one rank aborts all instead of hanging
                cmd = [
                    sys.executable,
                    "-m",
                    "mpi4py",
                    str(HERE / script),
                    *extra,
                    "--out",
                    f"{tmp}/out",
                ]
                if nproc > 1:
                    cmd = [MPIEXEC, "-n", str(nproc), *cmd]
                print(f"$ {' '.join(cmd)}", flush=True)
                try:
                    proc = subprocess.run(cmd, check=False, timeout=TIMEOUT)
                except subprocess.TimeoutExpired:
                    failures.append(f"{script} {extra} (np={nproc}, timed out after {TIMEOUT} s)")
                    continue
                if proc.returncode != 0:
                    failures.append(f"{script} {extra} (np={nproc})")
    if failures:
        print("demo failures: " + ", ".join(failures))
        return 1
    print(f"demos: {len(counts) * len(DEMOS)} passed, 0 failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
