"""3D past one factorisation: multigrid step 1, factorised step 1, plain solve, SNES VI.

The block of Example 3 pressed onto the half-ball, on a ladder of meshes (refinements
of the level-0 mesh at smaller element sizes), and graded meshes (small elements on
Γ_C, large ones on the top face). For each size every configuration runs in a process
of its own (so that its peak memory is its own), one after the other:

* ``default``: ``ADMMSolver(problem)``: the plan chooses step 1 from the mesh's
  bracket of a factorisation's cost, or from MUMPS's analysis where the bracket
  straddles a threshold (the multigrid path above ``FACTOR_FLOPS_LIMIT``), r* by the
  local method, the surface metric;
* ``factorised``: the same with ``step1="factorised"`` (MUMPS), where MUMPS's analysis
  says it fits in half the memory;
* ``iterative``: the same with ``step1="iterative"`` (CG + GAMG, warm starts, the
  inexact rule), where the default factorises;
* ``plain CG+GAMG``: one elastic solve A u = f of the same matrix (no contact), CG
  preconditioned by GAMG with the rigid body modes, to ``ksp_rtol = 1e-8``;
* ``SNES VI``: PETSc's active-set Newton (``vinewtonrsls``) with MUMPS, on the sizes
  where it finishes within ``--snes-limit`` seconds (projected from the smaller sizes
  by the growth of the factorised solve).

The paper's contact model (along the body's normal, axis-aligned on this flat Γ_C)
is used throughout, because SNES VI's bounds need it; the contact solves all meet the
KKT tolerance 1e-6 (``kkt``), and ``vs ref`` is ‖u − u_ref‖/‖u_ref‖ against SNES
VI's answer at the same size (active-set Newton with direct solves, exact to round-off
once its active set is right) where it ran, else against the factorised ADMM's.

Columns: seconds per phase (``mesh s``; ``assembly``; ``plan`` (the choice of step 1,
with MUMPS's analysis where it is asked, and the rest of the set-up); ``r*`` (the
estimate and the surface metric's β, μ_max; of it ``λ_min s``, ``λ_max s`` with its
``λ_max V-cycles`` (the multigrid LOBPCG's start and iterations), and ``μ_max s``);
``step-1 setup`` (factorisation or multigrid set-up); ``step-1 solves`` and
``step 2+`` (the rest of the iterations: the surface QP on Γ_C, residuals)),
``total`` (all but the mesh), ADMM iterations, Krylov iterations of step 1, and the
peak resident memory of the process. ``r*/solve`` is the r* time over the whole
solve (assembly to answer).

With ``--mpi``, the default also runs under ``mpiexec -n 2`` at the sizes of
``--mpi-sizes``, its answer compared with the serial one, and so does the default at
``rtol`` = ``TIGHT_RTOL`` (config ``tight``): the two answers differ by the error each
solve is allowed, so the tighter pair shows how far that is from round-off.

    python benchmarks/scale_3d.py              # the ladder to 2M dofs (about an hour)
    python benchmarks/scale_3d.py --quick      # one small mesh (smoke test)
    python benchmarks/scale_3d.py --only 158k,"graded 350k"   # some sizes (no page)

Writes out_benchmarks/scale_3d.csv (and scale_3d_mpi.csv).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

MODEL = "body"
#: name: (level, h_bottom, h_top)
LADDER = {
    "158k": (3, 0.3, 0.28),
    "257k": (3, 0.24, 0.224),
    "530k": (3, 0.18, 0.168),
    "1.2M": (4, 0.3, 0.28),
    "2.2M": (4, 0.23, 0.215),
    "graded 350k": (3, 0.12, 0.6),
}
QUICK = {"20k": (2, 0.3, 0.28)}
CONFIGS = ("default", "factorised", "iterative", "plain CG+GAMG", "SNES VI")
#: The MPI table's second pair: the default at this tolerance, serial and on two
#: ranks, where the answers differ by the solves' error, not by round-off.
TIGHT_RTOL = 1e-9


def worker(case: str, config: str, out: str, quick: bool) -> None:
    """One configuration at one size; rank 0 prints one JSON line."""
    import numpy as np
    from mpi4py import MPI
    from petsc4py import PETSc

    import admm_dolfinx
    from admm_dolfinx.linalg.factor_estimate import mumps_estimate
    from admm_dolfinx.linalg.petsc import ITERATIVE_OPTIONS, apply_options
    from admm_dolfinx.scenes import example3
    from admm_dolfinx.studies.baselines import solve_snes_vi

    comm = MPI.COMM_WORLD
    level, h_bottom, h_top = (QUICK if quick else LADDER)[case]
    row: dict = {}
    t0 = time.perf_counter()
    scene = example3(level=level, h_bottom=h_bottom, h_top=h_top)
    row["mesh s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem = scene.problem(contact_normal=MODEL)
    row["assembly"] = time.perf_counter() - t0
    row["dofs"] = problem.V.dofmap.index_map.size_global * 3
    row["contact nodes"] = problem.contact.num_global
    u = None
    if config == "plain CG+GAMG":
        b = problem.create_vector()
        problem.assemble_rhs(0.0, b)
        x = b.duplicate()
        ksp = PETSc.KSP().create(comm)
        ksp.setOperators(problem.A)  # carries the rigid-body near null space
        t0 = time.perf_counter()
        apply_options(ksp, "plain_", {**ITERATIVE_OPTIONS, "ksp_rtol": 1e-8}, setup=True)
        row["step-1 setup"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        ksp.solve(b, x)
        row["step-1 solves"] = time.perf_counter() - t0
        row["Krylov its"] = ksp.getIterationNumber()
        row["total"] = row["assembly"] + row["step-1 setup"] + row["step-1 solves"]
        ksp.destroy()
    elif config == "SNES VI":
        t0 = time.perf_counter()
        reference = solve_snes_vi(problem, tol=1e-8)
        row["total"] = row["assembly"] + time.perf_counter() - t0
        row["iterations"] = f"{reference.iterations} Newton"
        u = reference.u
    else:
        settings = {"step1": config} if config in ("factorised", "iterative") else {}
        if config == "tight":
            settings = {"rtol": TIGHT_RTOL}
        if config == "default":  # what MUMPS's analysis says the factorisation needs
            estimate = mumps_estimate(problem.A)
            row["MUMPS GB"] = estimate.memory / 1e9 if estimate else float("nan")
        t0 = time.perf_counter()
        solver = admm_dolfinx.ADMMSolver(problem, **settings)
        setup = time.perf_counter() - t0
        result = solver.solve()
        t = result.timings
        surface = solver.surface_penalty.time if solver.surface_penalty else 0.0
        row["plan"] = setup - t.penalty - t.operator - t.factorization
        row["r*"] = t.penalty
        # what r* is made of: λ_min (its layer), λ_max (and its V-cycles), μ_max
        details = solver.penalty_estimate.details if solver.penalty_estimate else {}
        row["λ_min s"] = details.get("time_min", "–")
        row["λ_max s"] = details.get("time_max", "–")
        if details.get("lambda_max_method") == "multigrid":
            row["λ_max V-cycles"] = details["solves_max"]
        row["μ_max s"] = surface if surface else "–"
        row["step-1 setup"] = t.operator + t.factorization
        row["step-1 solves"] = solver.operator.solve_time
        row["step 2+"] = t.iterations - solver.operator.solve_time
        row["total"] = row["assembly"] + setup + t.iterations + t.kkt
        row["r*/solve"] = t.penalty / row["total"]
        row["iterations"] = result.iterations
        row["Krylov its"] = result.step1.krylov_iterations if result.step1 else "–"
        row["kkt"] = f"{result.kkt.max():.1e}"
        row["step 1"] = solver.plan.step1
        row["surface r"] = f"{result.penalty:.6g}" if surface else "–"
        u = result.u
        solver.destroy()
    row["peak RSS GB"] = comm.allreduce(
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, op=MPI.SUM
    )
    if u is not None:  # the answer, ordered by node coordinates, for the comparisons
        V = u.function_space
        n = V.dofmap.index_map.size_local
        coords = comm.gather(V.tabulate_dof_coordinates()[:n], root=0)
        values = comm.gather(u.x.array[: 3 * n].reshape(n, 3), root=0)
        if comm.rank == 0:
            coords, values = np.concatenate(coords), np.concatenate(values)
            order = np.lexsort(np.round(coords, 10).T[::-1])
            tag = f"{case}_{config}_{comm.size}".replace(" ", "_").replace("+", "")
            np.save(Path(out) / f"scale_3d_u_{tag}.npy", values[order])
    if comm.rank == 0:
        print("RESULT " + json.dumps(row), flush=True)


def _run(case, config, args, processes=1, timeout=None):
    """A worker in its own process; its row, or None if it failed or timed out."""
    command = [sys.executable, __file__, "--worker", case, config, "--out", args.out]
    if args.quick:
        command.append("--quick")
    if processes > 1:
        local = Path(sys.executable).parent / "mpiexec"
        mpiexec = os.environ.get("MPIEXEC") or (str(local) if local.exists() else "mpiexec")
        command = [mpiexec, "-n", str(processes), *command]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"note": f"stopped after {timeout:.0f} s"}
    lines = [x for x in done.stdout.splitlines() if x.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        return {"note": "failed: " + " / ".join(tail)[:300]}
    return json.loads(lines[-1][len("RESULT ") :])


def _error(args, case, config, reference, processes=1):
    import numpy as np

    def load(name, p):
        tag = f"{case}_{name}_{p}".replace(" ", "_").replace("+", "")
        path = Path(args.out) / f"scale_3d_u_{tag}.npy"
        return np.load(path) if path.exists() else None

    u, ref = load(config, processes), load(reference, 1)
    if u is None or ref is None:
        return "–"
    return f"{np.linalg.norm(u - ref) / np.linalg.norm(ref):.1e}"


def _fmt(row: dict) -> dict:
    return {k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in row.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one small mesh")
    parser.add_argument("--out", default="out_benchmarks")
    parser.add_argument("--snes-limit", type=float, default=1200.0, help="seconds")
    parser.add_argument(
        "--mpi", action="store_true", help="the default (and at TIGHT_RTOL) under mpiexec -n 2"
    )
    parser.add_argument("--mpi-sizes", default="257k,1.2M")
    parser.add_argument(
        "--only", default=None, help="comma-separated sizes of the ladder (a partial run)"
    )
    parser.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker, args.out, args.quick)
        return
    from tables import print_and_save, select

    from admm_dolfinx.admm.plan import MEMORY_FRACTION
    from admm_dolfinx.linalg.factor_estimate import available_memory

    Path(args.out).mkdir(parents=True, exist_ok=True)
    cases = select(parser, QUICK if args.quick else LADDER, args.only)
    memory = available_memory() or float("inf")
    rows = []
    snes_time: list[tuple[int, float]] = []
    for case in cases:
        results = {}
        for config in CONFIGS:
            if config == "factorised" and results.get("default", {}).get("step 1") == (
                "factorised"
            ):
                continue  # the default is the factorised solve here
            if config == "iterative" and results.get("default", {}).get("step 1") == ("iterative"):
                continue
            if config in ("factorised", "SNES VI"):
                estimate = results.get("default", {}).get("MUMPS GB", 0.0) * 1e9
                if estimate > MEMORY_FRACTION * memory:
                    results[config] = {"note": f"MUMPS needs {estimate / 1e9:.3g} GB"}
                    rows.append({"mesh": case, "config": config, **results[config]})
                    continue
            if config == "SNES VI" and snes_time:
                # projected from the last size by the growth of the factorised solve
                dofs = results.get("default", {}).get("dofs", 0)
                last_dofs, last_time = snes_time[-1]
                projected = last_time * (dofs / last_dofs) ** 2.2
                if projected > args.snes_limit:
                    results[config] = {"note": f"projected {projected:.0f} s > limit"}
                    rows.append({"mesh": case, "config": config, **results[config]})
                    continue
            timeout = args.snes_limit if config == "SNES VI" else None
            results[config] = _run(case, config, args, timeout=timeout)
            row = results[config]
            if config == "SNES VI" and "total" in row:
                snes_time.append((row["dofs"], row["total"]))
            out = _fmt({"mesh": case, "config": config, **row})
            rows.append(out)
            print(json.dumps(out), flush=True)
        _compare_with_reference(args, case, results, rows)
        _ratios(rows, case, results)
        print_and_save(rows, Path(args.out) / "scale_3d.csv")
    if args.mpi:
        mpi_rows = []
        for case in [c for c in args.mpi_sizes.split(",") if c in cases] or list(cases)[:1]:
            for config in ("default", "tight"):
                for processes in (1, 2):
                    row = _run(case, config, args, processes=processes)
                    row = {"mesh": case, "config": config, "processes": processes, **row}
                    if processes == 2:
                        row["vs serial"] = _error(args, case, config, config, processes=2)
                    mpi_rows.append(_fmt(row))
        print_and_save(mpi_rows, Path(args.out) / "scale_3d_mpi.csv")


def _compare_with_reference(args, case, results, rows) -> None:
    """``vs ref`` of this size's contact solves: the error against SNES VI's answer
    (active-set Newton with direct solves: exact once its active set is right) where it
    ran, else against the factorised ADMM's."""
    reference = next((c for c in ("SNES VI", "factorised") if "total" in results.get(c, {})), None)
    if reference is None and results.get("default", {}).get("step 1") == "factorised":
        reference = "default"
    for row in rows:
        if row["mesh"] != case or row["config"] in ("plain CG+GAMG", "ratios"):
            continue
        if row["config"] == reference:
            row["vs ref"] = "reference"
        elif reference is not None and "total" in row:
            row["vs ref"] = _error(args, case, row["config"], reference)


def _ratios(rows, case, results) -> None:
    """The targets' ratios at this size, as a row of its own."""
    default, plain = results.get("default", {}), results.get("plain CG+GAMG", {})
    snes = results.get("SNES VI", {})
    ratio: dict = {"mesh": case, "config": "ratios"}
    if "total" in default and "total" in plain:
        ratio["total"] = f"default/plain {default['total'] / plain['total']:.2f}"
        ratio["peak RSS GB"] = f"default/plain {default['peak RSS GB'] / plain['peak RSS GB']:.2f}"
    if "total" in default and "total" in snes:
        ratio["iterations"] = f"SNES VI/default {snes['total'] / default['total']:.2f}"
    if "r*/solve" in default:
        ratio["r*/solve"] = default["r*/solve"]
    rows.append(_fmt(ratio))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import dolfinx_solver  # noqa: F401  (before dolfinx, petsc4py)

    main()
