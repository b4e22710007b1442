"""Strong scaling: the same problem on 1 and 2 processes, phase by phase.

The script runs itself under ``mpiexec -n p`` for each p, one after the other, so
each run has the machine to itself. Each worker builds the scene, assembles the
problem, and solves it with the defaults: ``ADMMSolver(problem).solve()``. The set-up
is split into r* (the estimate's own time, with β and μ_max of the surface metric in
3D) and the factorisation (the rest). In 2D
on one process one condensed factorisation serves both, so r* is its dense
eigenproblem only; under MPI the estimate factorises A condensed onto Γ_C for r* and
the ADMM factorises A + r*NᵀMN. It reports the slowest rank's time for each phase,
the best of ``--repeat`` rounds (the form compilation is warmed up first). It also
reports the iteration count and ‖u‖, so that the answers can be compared. The
speed-up of a phase is its time on 1 process over its time on p.

Each process runs ``--threads`` BLAS/OpenMP threads (default 1, as ``make`` sets):
with more, p processes on a p-core machine oversubscribe it (measure it with
``--threads 2``).

    python benchmarks/parallel_scaling.py            # Example 1 h=1/256, Example 3 level 3
    python benchmarks/parallel_scaling.py --quick    # small meshes (smoke test)
    python benchmarks/parallel_scaling.py --threads 2  # 2 threads per process

Writes out_benchmarks/parallel_scaling.csv (``_threads2.csv`` etc. with ``--threads``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"

CASES = {
    "example1 h=1/256": ("example1", {"h": 1 / 256}),
    "example3 level 3": ("example3", {"level": 3}),
}
QUICK_CASES = {
    "example1 h=1/32": ("example1", {"h": 1 / 32}),
    "example3 level 1": ("example3", {"level": 1}),
}
PHASES = ("mesh", "assembly", "r*", "factorisation", "iterations")  # timed phases


def worker(name: str, quick: bool, repeat: int) -> None:
    """One process group: time each phase; rank 0 prints one JSON line."""
    from mpi4py import MPI
    from timing import timed

    import admm_dolfinx
    from admm_dolfinx import scenes

    comm = MPI.COMM_WORLD
    builder, kwargs = (QUICK_CASES if quick else CASES)[name]
    build = getattr(scenes, builder)
    build(**kwargs).problem(
        contact_normal=MODEL
    ).destroy()  # compile the forms once, outside the timing
    best = dict.fromkeys(PHASES, float("inf"))
    for _ in range(repeat):
        t_mesh, scene = timed(lambda: build(**kwargs))
        t_assembly, problem = timed(scene.problem)
        t_setup, solver = timed(lambda: admm_dolfinx.ADMMSolver(problem))  # noqa: B023
        estimate, surface = solver.penalty_estimate, solver.surface_penalty
        own = estimate.time + (surface.time if surface is not None else 0.0)
        t_penalty = comm.allreduce(own, op=MPI.MAX)
        t_fact = t_setup - t_penalty
        t_iter, result = timed(solver.solve)
        measured = (t_mesh, t_assembly, t_penalty, t_fact, t_iter)
        for phase, seconds in zip(PHASES, measured, strict=True):
            best[phase] = min(best[phase], seconds)
        answer = {
            "dofs": problem.V.dofmap.index_map.size_global * problem.gdim,
            "r": estimate.r,
            "iterations": result.iterations,
            "norm_u": result.u.x.petsc_vec.norm(),
        }
        solver.destroy()
        problem.destroy()
    if comm.rank == 0:
        print("RESULT " + json.dumps({"answer": answer, "seconds": best}), flush=True)


def run(name: str, nprocs: int, quick: bool, repeat: int, threads: int) -> dict:
    # the Makefile's mpiexec, else the one installed next to this Python (the MPICH wheel)
    mpiexec = os.environ.get("MPIEXEC") or str(Path(sys.executable).parent / "mpiexec")
    cmd = [sys.executable, "-m", "mpi4py", __file__, "--worker", name, "--repeat", str(repeat)]
    if quick:
        cmd.append("--quick")
    cmd = [mpiexec, "-n", str(nprocs), *cmd]
    env = os.environ | {"OMP_NUM_THREADS": str(threads), "OPENBLAS_NUM_THREADS": str(threads)}
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        sys.stderr.write(proc.stdout + proc.stderr)
        raise SystemExit(f"the worker for {name!r} on {nprocs} process(es) failed")
    return json.loads(lines[-1].removeprefix("RESULT "))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small meshes (smoke test)")
    parser.add_argument("--nprocs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1, help="threads per process")
    parser.add_argument("--out", default="out_benchmarks")
    parser.add_argument("--worker", metavar="CASE", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.quick, args.repeat)
        return

    from mpi4py import MPI
    from tables import print_and_save

    if MPI.COMM_WORLD.size > 1:
        parser.error("starts its own MPI runs: call it without mpiexec")
    rows = []
    for name in QUICK_CASES if args.quick else CASES:
        base = None
        for nprocs in args.nprocs:
            data = run(name, nprocs, args.quick, args.repeat, args.threads)
            base = base or data
            answer, seconds = data["answer"], data["seconds"]
            total = sum(seconds[p] for p in PHASES[1:])  # what a user's solve costs
            base_total = sum(base["seconds"][p] for p in PHASES[1:])
            row = {"mesh": name, "dofs": answer["dofs"], "processes": nprocs}
            row["threads"] = args.threads
            row |= {"r*": f"{answer['r']:.6g}", "iterations": answer["iterations"]}
            ratio = answer["norm_u"] / base["answer"]["norm_u"]
            row["‖u‖ vs first"] = f"{abs(ratio - 1):.1e}"
            row |= {f"{p} [s]": f"{seconds[p]:.3g}" for p in PHASES}
            row["assembly to answer [s]"] = f"{total:.3g}"
            row |= {f"speed-up {p}": f"{base['seconds'][p] / seconds[p]:.2f}" for p in PHASES[1:]}
            row["speed-up assembly to answer"] = f"{base_total / total:.2f}"
            rows.append(row)
            print(f"{name}, {nprocs} process(es): done", flush=True)
    print()
    suffix = "" if args.threads == 1 else f"_threads{args.threads}"
    print_and_save(rows, Path(args.out) / f"parallel_scaling{suffix}.csv")


if __name__ == "__main__":
    main()
