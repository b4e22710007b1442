"""The surface metric r(M + βL_Γ) (the 3D default) against the paper's r M, at matched error.

Two parts, each measured in one run:

``--part rule`` (serial): does the cheap choice of β and r pick a good point? On
Example 3 and three variants of its block (``slab``: 0.2 thick instead of 1;
``clamped``: the side faces held too, so Γ_C meets a Dirichlet boundary; ``punch``:
a flat obstacle, the whole face in contact), levels 0-2, the dense compliance
T = N A⁻¹ Nᵀ (m solves) gives every eigenvalue of the paper's pencil (λ) and of the
surface pencil (μ). Printed: κ = λ_max/λ_min, κ_R = μ_max/μ_min, μ_min/λ_max (the
rule assumes ≈ 1), μ_max from layers over the dense one, r over the best
r = 1/sqrt(μ_min μ_max), and the iterations to relative errors 1e-6 / 1e-8 in u of
the paper's metric (α = 1.6, Anderson 5 at r*), of the surface metric (the default)
and of the surface metric at the best r.

``--part calibrate`` (serial, 5 min): the constants b and m of the rule β = b κ/k²_max,
r = 1/sqrt(m λ_max μ_max) (``admm_dolfinx.penalty.surface``), over a grid of (b, m):
the ADMM iterations of the default solve (its stopping test, rtol 1e-6) on Example 3
levels 1-2, hexahedral meshes of its block (12 and 16 cells across), two strongly
graded tetrahedral meshes (element sizes 0.06 → 0.6 and 0.04 → 0.8 from Γ_C to the
top, level 1) and the three variants at level 1; sums and maxima per column.

``--part select`` (serial, 1 min): over-relaxation α and Anderson memory for the
surface metric, iterations to 1e-6 / 1e-8 summed over Example 3 levels 1-2 and the
slab and clamped variants at level 1 (the defaults α = 1.6, memory 5 were chosen for
the paper's metric by ``benchmarks/acceleration.py --select``).

``--part speed`` (MPI-capable): Example 3 levels 0-3 and the 257k-dof mesh. For each,
the default (surface metric), the paper's metric with the same acceleration
(``expert={"penalty_metric": "mass"}``) and the paper's ADMM at r* run until the error reaches
1e-6 and 1e-8; time = r* (+ β, μ_max) + factorisation + iterations to the error;
a plain linear-elastic solve of A + r*NᵀMN (factorisation + one solve) in the same
run gives *contact / plain*. Then the default's growth per halving of h.

The reference is ``benchmarks/acceleration.py``'s (SNES VI from a tight ADMM solve).

    python benchmarks/surface_metric.py                 # all but select (about 30 min)
    python benchmarks/surface_metric.py --part rule     # 3 min
    python benchmarks/surface_metric.py --part select
    python benchmarks/surface_metric.py --part calibrate
    python benchmarks/surface_metric.py --part speed --only "level 3"
    python benchmarks/surface_metric.py --quick         # levels 0-1, Example 3 only

Writes out_benchmarks/surface_metric_{rule,select,speed,growth}.csv.
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import numpy as np
from acceleration import TARGETS, ErrorTrace, plain_solve_times, reference, say
from mpi4py import MPI
from tables import print_and_save

from admm_dolfinx import ADMMSolver, Ball, Plane
from admm_dolfinx.admm.solver import ADMMConvergenceError
from admm_dolfinx.operators.penalised import PenalisedOperator
from admm_dolfinx.operators.surface_metric import SurfaceMetric
from admm_dolfinx.scenes.library import Scene, example3, example3_hexahedral, pressed_block

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"

COMM = MPI.COMM_WORLD
SPEED_MESHES = [
    ("level 0", {"level": 0}),
    ("level 1", {"level": 1}),
    ("level 2", {"level": 2}),
    ("level 3", {"level": 3}),
    ("level 3, h0=0.24", {"level": 3, "h_bottom": 0.24, "h_top": 0.24}),
]


def block_variant(kind: str, level: int) -> Scene:
    """Example 3's block with one thing changed (see the module docstring)."""
    half_depth, h, push = (0.1, 0.15, 0.05) if kind == "slab" else (0.5, 0.3, 0.2)
    obstacle = Ball(center=(-0.3, 0.0, -half_depth - 0.5), radius=0.5)
    if kind == "punch":
        obstacle = Plane(point=(0.0, 0.0, -0.55), normal=(0.0, 0.0, 1.0))
    return pressed_block(
        COMM,
        name=kind,
        level=level,
        half_depth=half_depth,
        h_bottom=h,
        h_top=h,
        displacement=push,
        obstacle=obstacle,
        clamp_sides=kind == "clamped",
    )


def traced_solve(problem, u_ref, max_iter=3000, r=None, **options):
    """(error trace, result, solver settings) of one solve stopped at the last target."""
    trace = ErrorTrace(u_ref)
    with ADMMSolver(problem, rtol=1e-300, max_iter=max_iter, **options) as solver:
        if r is not None:
            solver.set_penalty(r)
        try:
            result = solver.solve(callback=trace)
        except ADMMConvergenceError as err:
            result = err.result
        info = solver.surface_penalty
    trace.work.destroy()
    return trace, result, info


def counts(trace):
    return " / ".join(str(trace.iterations_to(t) or "–") for t in TARGETS)


def dense_compliance(problem):
    """T = N A⁻¹ Nᵀ (m × m, serial) with one factorisation of A and m solves."""
    m = problem.contact.gap.size
    operator = PenalisedOperator(problem, "compliance_")
    b, x = problem.create_vector(), problem.create_vector()
    T = np.empty((m, m))
    try:
        operator.set_penalty(0.0)
        for j in range(m):
            b.set(0.0)
            unit = np.zeros(m)
            unit[j] = 1.0 / problem.contact.mass[j]
            problem.add_normal_force(b, unit)  # Nᵀ e_j
            operator.solve(b, x)
            T[:, j] = problem.apply_normal(x)
    finally:
        for obj in (b, x, operator):
            obj.destroy()
    return 0.5 * (T + T.T)


def symmetric_eigenvalues(T, metric):
    """Eigenvalues of T·metric, through the Cholesky factor of the metric."""
    lower = np.linalg.cholesky(metric)
    return np.linalg.eigvalsh(lower.T @ T @ lower)


def rule_row(name, scene):
    problem = scene.problem(contact_normal=MODEL)
    c = problem.contact
    say(f"\n## {name}: m = {problem.num_contact_nodes}")
    u_ref, how, _ = reference(problem, True)
    trace_mass, *_ = traced_solve(problem, u_ref, expert={"penalty_metric": "mass"})
    trace_default, _, info = traced_solve(problem, u_ref)
    T = dense_compliance(problem)
    L = dense_laplacian(problem)
    lam = symmetric_eigenvalues(T, np.diag(c.mass))
    mu = symmetric_eigenvalues(T, np.diag(c.mass) + info.beta * L)
    r_best = 1.0 / math.sqrt(mu.min() * mu.max())
    trace_best, *_ = traced_solve(problem, u_ref, r=r_best)
    u_ref.destroy()
    row = {
        "mesh": name,
        "m": problem.num_contact_nodes,
        "κ": f"{lam.max() / lam.min():.3g}",
        "κ_R": f"{mu.max() / mu.min():.3g}",
        "μ_min/λ_max": f"{mu.min() / lam.max():.2f}",
        "μ_max layers/dense": f"{info.mu_max / mu.max():.3f}",
        "r / r_best": f"{info.r / r_best:.2f}",
        "paper metric": counts(trace_mass),
        "surface (default)": counts(trace_default),
        "surface at r_best": counts(trace_best),
    }
    say("   " + ", ".join(f"{k} {v}" for k, v in row.items()) + f" (reference: {how})")
    problem.destroy()
    return row


def dense_laplacian(problem):
    """L_Γ on the contact nodes (serial order), dense."""
    metric = SurfaceMetric(problem)
    try:
        return metric.dense_laplacian()
    finally:
        metric.destroy()


def speed_rows(name, options):
    scene = example3(level=options["level"], **{k: v for k, v in options.items() if k != "level"})
    problem = scene.problem(contact_normal=MODEL)
    dofs = problem.V.dofmap.index_map.size_global * problem.gdim
    say(f"\n## {name}: {dofs} dofs, m = {problem.num_contact_nodes}, {COMM.size} process(es)")
    u_ref, how, _ = reference(problem, True)
    say(f"   reference: {how}")
    runs = {
        "surface (default)": {},
        "paper metric, α 1.6 + Anderson 5": {"expert": {"penalty_metric": "mass"}},
    }
    results = {}
    for label, opts in runs.items():
        results[label] = traced_solve(problem, u_ref, **opts)
    r_star = results["paper metric, α 1.6 + Anderson 5"][1].penalty
    results["paper ADMM at r*"] = traced_solve(problem, u_ref, r=None, penalty=r_star, mode="paper")
    plain_fact, plain_solve = plain_solve_times(problem, r_star)
    t_plain = COMM.allreduce(plain_fact + plain_solve, op=MPI.MAX)
    rows = []
    for label, (trace, result, _) in results.items():
        t = result.timings
        per_it = max(t["iterations"] - trace.time, 0.0) / max(result.iterations, 1)
        setup = t["penalty"] + t["operator"] + t["factorization"]
        if label == "paper ADMM at r*":  # r* as the paper metric's run computed it
            setup += results["paper metric, α 1.6 + Anderson 5"][1].timings["penalty"]
        row = {"mesh": name, "dofs": dofs, "variant": label}
        for target in TARGETS:
            its = trace.iterations_to(target)
            row[f"iter {target:.0e}"] = its if its is not None else "–"
            if its is not None:
                seconds = COMM.allreduce(setup + its * per_it, op=MPI.MAX)
                row[f"time {target:.0e} [s]"] = f"{seconds:.3g}"
                row[f"contact/plain {target:.0e}"] = f"{seconds / t_plain:.2f}"
        row["r"] = f"{result.penalty:.4g}"
        row["r* (+β, μ_max) [s]"] = f"{COMM.allreduce(t['penalty'], op=MPI.MAX):.3g}"
        row["factorisation [s]"] = f"{COMM.allreduce(t['factorization'], op=MPI.MAX):.3g}"
        row["per iteration [s]"] = f"{per_it:.2g}"
        row["plain [s]"] = f"{t_plain:.3g}"
        rows.append(row)
        say("   " + ", ".join(f"{k} {v}" for k, v in row.items() if k != "mesh"))
    u_ref.destroy()
    problem.destroy()
    return rows


def select_grid():
    """Iterations to 1e-6 / 1e-8 per (α, memory), summed over four meshes."""
    meshes = [
        lambda: example3(level=1),
        lambda: example3(level=2),
        lambda: block_variant("slab", 1),
        lambda: block_variant("clamped", 1),
    ]
    alphas, memories = (1.0, 1.3, 1.6, 1.8), (0, 3, 5, 10)
    totals = {(a, k): [0, 0] for a in alphas for k in memories}
    for build in meshes:
        problem = build().problem(contact_normal=MODEL)
        u_ref, _, _ = reference(problem, True)
        for (alpha, memory), total in totals.items():
            trace, *_ = traced_solve(problem, u_ref, expert={"alpha": alpha, "anderson": memory})
            for i, target in enumerate(TARGETS):
                total[i] += trace.iterations_to(target) or 10**6
        u_ref.destroy()
        problem.destroy()
    return [
        {"α \\ memory": alpha}
        | {str(k): f"{totals[(alpha, k)][0]} / {totals[(alpha, k)][1]}" for k in memories}
        for alpha in alphas
    ]


def growth(rows):
    """Iterations of the default per level, and the factor per halving of h."""
    levels = [r for r in rows if r["variant"] == "surface (default)" and "h0" not in r["mesh"]]
    out = []
    for previous, row in itertools.pairwise(levels):
        factors = []
        for target in TARGETS:
            a, b = previous[f"iter {target:.0e}"], row[f"iter {target:.0e}"]
            factors.append(f"{b / a:.2f}" if isinstance(a, int) and isinstance(b, int) else "–")
        out.append(
            {
                "halving": f"{previous['mesh']} → {row['mesh']}",
                "iterations 1e-6 / 1e-8": f"{previous['iter 1e-06']} / {previous['iter 1e-08']}"
                f" → {row['iter 1e-06']} / {row['iter 1e-08']}",
                "factor 1e-6 / 1e-8": " / ".join(factors),
            }
        )
    return out


#: (b, m) of β = b κ/k²_max and μ_min ≈ m λ_max (admm_dolfinx.penalty.surface); the
#: first is the plain ADMM's choice, the default is among them.
CALIBRATION_GRID = [(1.0, 0.5), (0.5, 0.5), (0.5, 0.25), (0.5, 0.125), (0.25, 0.25)]
CALIBRATION_GRID += [(0.25, 0.15), (0.25, 0.125), (0.25, 0.0625), (0.125, 0.0625)]


def calibration_meshes(quick: bool):
    """Example 3, its variants, hexahedral and strongly graded meshes (name, builder)."""
    meshes = [
        ("example3 level 1", lambda: example3(level=1)),
        ("hexahedral 12", lambda: example3_hexahedral(cells=12)),
    ]
    if not quick:
        meshes += [
            ("graded 0.06/0.6 level 1", lambda: example3(level=1, h_bottom=0.06, h_top=0.6)),
            ("example3 level 2", lambda: example3(level=2)),
            ("hexahedral 16", lambda: example3_hexahedral(cells=16)),
            ("graded 0.04/0.8 level 1", lambda: example3(level=1, h_bottom=0.04, h_top=0.8)),
        ]
        meshes += [
            (f"{kind} level 1", lambda kind=kind: block_variant(kind, 1))
            for kind in ("slab", "clamped", "punch")
        ]
    return meshes


def calibration_rows(quick: bool) -> list[dict]:
    """ADMM iterations (the default solve: stopping test at rtol 1e-6) for each (b, m)."""
    import admm_dolfinx.penalty.surface as surface

    saved = surface.BETA_FRACTION, surface.MU_MIN_FRACTION
    grid = [*CALIBRATION_GRID[:2], saved] if quick else CALIBRATION_GRID
    rows = []
    try:
        for name, build in calibration_meshes(quick):
            problem = build().problem()
            row = {"mesh": name, "dofs": problem.V.dofmap.index_map.size_global * 3}
            for b, m in grid:
                surface.BETA_FRACTION, surface.MU_MIN_FRACTION = b, m
                mark = " (default)" if (b, m) == saved else ""
                try:
                    with ADMMSolver(problem) as solver:
                        row[f"b={b:g} m={m:g}{mark}"] = solver.solve().iterations
                except ADMMConvergenceError:  # a poor corner of the grid
                    row[f"b={b:g} m={m:g}{mark}"] = "–"
            rows.append(row)
            say(row)
    finally:
        surface.BETA_FRACTION, surface.MU_MIN_FRACTION = saved
    total = {"mesh": "sum"}
    for key in rows[0]:
        if key.startswith("b="):
            values = [row[key] for row in rows]
            total[key] = sum(values) if all(isinstance(v, int) for v in values) else "–"
    worst = {"mesh": "max"}
    for key in total:
        if key.startswith("b=") and total[key] != "–":
            worst[key] = max(row[key] for row in rows)
    return [*rows, total, worst]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--part", choices=["rule", "select", "calibrate", "speed", "both"], default="both"
    )
    parser.add_argument("--quick", action="store_true", help="levels 0-1 of Example 3 only")
    parser.add_argument("--only", default=None, help="speed meshes whose name contains this")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    out = Path(args.out)
    levels = (0, 1) if args.quick else (0, 1, 2)
    if args.part in ("rule", "both") and COMM.size == 1:
        meshes = [(f"example3 level {k}", lambda k=k: example3(level=k)) for k in levels]
        if not args.quick:
            meshes += [
                (f"{kind} level {k}", lambda kind=kind, k=k: block_variant(kind, k))
                for kind in ("slab", "clamped", "punch")
                for k in levels
            ]
        rows = [rule_row(name, build()) for name, build in meshes]
        if COMM.rank == 0:
            print("\nrule: iterations to 1e-6 / 1e-8 in u\n")
            print_and_save(rows, out / "surface_metric_rule.csv")
    if args.part in ("calibrate", "both") and COMM.size == 1:
        rows = calibration_rows(args.quick)
        if COMM.rank == 0:
            print("\ncalibrate: ADMM iterations of the default solve for each (b, m)\n")
            print_and_save(rows, out / "surface_metric_calibrate.csv")
    if args.part == "select" and COMM.size == 1:
        table = select_grid()
        if COMM.rank == 0:
            print("\nselect: iterations to 1e-6 / 1e-8 summed over four meshes\n")
            print_and_save(table, out / "surface_metric_select.csv")
    if args.part in ("speed", "both"):
        meshes = SPEED_MESHES[:2] if args.quick else SPEED_MESHES
        if args.only:
            meshes = [mesh for mesh in meshes if args.only in mesh[0]]
        rows = []
        for name, options in meshes:
            rows += speed_rows(name, options)
        if COMM.rank == 0:
            print("\nspeed: iterations and seconds to 1e-6 / 1e-8 in u\n")
            print_and_save(rows, out / "surface_metric_speed.csv")
            table = growth(rows)
            if table:
                print("\ngrowth of the default's iterations per halving of h\n")
                print_and_save(table, out / "surface_metric_growth.csv")


if __name__ == "__main__":
    main()
