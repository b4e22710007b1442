"""Work against precision for the engineer's numbers: uniform, hand-graded and adaptive meshes.

    python benchmarks/work_precision_adaptive.py           # cylinder and sphere, to 1 %
    python benchmarks/work_precision_adaptive.py --quick   # the cylinder and the punch, coarse

The error of Hertz's peak pressure p0 (the peak recovered from the nodal pressures,
:mod:`admm_dolfinx.adapt.recovery`, the quantity ``solve_adaptive`` controls; the
largest nodal value beside it), of the contact half-width (radius) a and of the
total contact force against their analytic values, with the CPU seconds and the dofs
that bought them, for three ways to the same answer, each solved with the package's
default settings:

* **uniform**: a coarse uniform mesh, every edge split at each level (the contact
  boundary's new vertices placed on the true circle or sphere);
* **graded**: the gmsh mesh graded by hand around the contact point
  (:func:`~admm_dolfinx.scenes.hertz`, :func:`~admm_dolfinx.scenes.library.hertz_sphere`
  at their levels: element size a/4 (cylinder) or a/3 (sphere) halved per level);
* **adaptive**: :func:`~admm_dolfinx.solve_adaptive` from the same coarse uniform mesh
  with ``target=0.01`` on the peak pressure; its CPU is the sum over its levels (each
  solve, estimate, marking and refinement).

The bodies: the plane-strain cylinder of radius R = 8 with a = R/80, and the quarter
sphere of radius R = 8 with a = R/80, where Hertz's half-space model is close enough
to the elastic body for a 1 % target (the finest graded rows show how close). Every
row's CPU seconds are process time summed over the ranks, measured in this one run.
The summary table gives, at 1 % on p0, the CPU of the cheapest uniform mesh from
which on every uniform level is within 1 %, and of the adaptive run (all its levels:
it needs three, the last two resolved, to estimate its error), their ratio (where no
uniform level is within 1 %, a bound: "> x", the finest uniform level's CPU over the
adaptive run's, since a uniform mesh within 1 % is finer still), and the dofs and
CPU of the first graded mesh from which on every graded level is within 1 % (found
by comparing with Hertz's answer: a user without one needs the next levels to know).
The adaptive run is given both ways: where it stopped (its own estimate at most 1 %),
and judged like the uniform and graded meshes, its first level from which on every
level is within 1 % of Hertz's answer, with the CPU its levels had spent to there.

The flat punch (Boussinesq's: a rigid flat circular punch of radius a pressed δ into
a block 1000 a across, :func:`~admm_dolfinx.scenes.library.flat_punch`) has no peak
pressure (it is infinite at the rim); its tables give the error of the contact force
against F = 2 a E* δ and of the contact area, for the uniform mesh of boxes refined
uniformly, the gmsh mesh graded by hand towards the rim
(:func:`~admm_dolfinx.scenes.library.flat_punch_graded`: nodes on the rim, element
size a/4 there and its growth with the distance both halved per level), and
``solve_adaptive`` on the force from the coarse uniform mesh with ``target=0.01``
(the force's error estimated as the strain energy's on each level; its column
*estimate*). Its summary gives, for each way, the first mesh from which on every
mesh is within 5 %, 3 % and 1 % of Boussinesq's force, with its dofs and CPU seconds,
and whether the adaptive run claimed the target.

``--part punch-step1`` runs the punch's adaptive levels twice, one run after the
other: with the default step-1 plan and with ``step1="factorised"``, and gives, for
the levels past 10k dofs and for the whole run, what the default chose, the ADMM
iterations and the CPU seconds of each (the plan's crossover between a factorisation
and multigrid against a body whose iterations grow with its contact nodes).

Writes out_benchmarks/work_precision_adaptive_*.csv and work_precision_adaptive.png.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

import admm_dolfinx as ad
from admm_dolfinx.adapt.marking import all_local_edges
from admm_dolfinx.adapt.recovery import recovered_peak_pressure
from admm_dolfinx.adapt.refinement import refine_contact_mesh
from admm_dolfinx.scenes import library as lib
from admm_dolfinx.studies.hertz import hertz_errors

#: The error asked of the peak pressure.
TARGET = 0.01
#: R/a for both bodies.
SLENDERNESS = 80.0
RADIUS = 8.0


def _cpu(comm) -> float:
    return float(comm.allreduce(time.process_time(), op=MPI.SUM))


def _cylinder(comm, **mesh):
    a = RADIUS / SLENDERNESS
    return lib.hertz(comm, half_width=a, radius=RADIUS, **mesh), (
        lambda m, t: lib.hertz_on(m, t, half_width=a, radius=RADIUS)
    )


def _sphere(comm, **mesh):
    a = RADIUS / SLENDERNESS
    return lib.hertz_sphere(comm, half_width=a, radius=RADIUS, **mesh), (
        lambda m, t: lib.hertz_sphere_on(m, t, half_width=a, radius=RADIUS)
    )


#: body -> (scene maker, coarse uniform mesh arguments, uniform levels, graded levels)
BODIES = {
    "cylinder": (_cylinder, {"h_contact": 1.0, "h_far": 1.0}, 8, 6),
    "sphere": (_sphere, {"h_far": 0.1, "h_contact": 0.8}, 4, 4),
}


def _row(body, method, level, scene, problem, result, cpu):
    errors = hertz_errors(scene, problem, result.multiplier)
    a = scene.info["a"]
    return {
        "body": body,
        "method": method,
        "level": level,
        "dofs": problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
        "m": problem.num_contact_nodes,
        "p0 error": recovered_peak_pressure(problem, result.multiplier) / scene.info["p0"] - 1.0,
        "nodal max error": errors.p0_error,
        "a error": max(abs(errors.a_inside[0] - a), abs(errors.a_inside[1] - a)) / a,
        "force error": errors.force_error,
        "iterations": result.iterations,
        "cpu [s]": cpu,
    }


def _solve(problem):
    with ad.ADMMSolver(problem) as solver:
        return solver.solve()


def uniform(comm, body, levels):
    make, coarse, *_ = BODIES[body]
    scene, rebuild = make(comm, **coarse)
    msh, tags = scene.mesh, scene.facet_tags
    rows = []
    for level in range(levels):
        cpu0 = _cpu(comm)
        scene = rebuild(msh, tags)
        problem = scene.problem()
        result = _solve(problem)
        rows.append(_row(body, "uniform", level, scene, problem, result, _cpu(comm) - cpu0))
        problem.destroy()
        if level + 1 < levels:  # the refinement is not counted: it is cheap and done once
            msh, tags, _ = refine_contact_mesh(
                msh, tags, all_local_edges(msh), scene.contact_marker, scene.surface
            )
    return rows


def graded(comm, body, levels):
    make, *_ = BODIES[body]
    rows = []
    for level in range(levels):
        cpu0 = _cpu(comm)
        scene, _ = make(comm, level=level)
        problem = scene.problem()
        result = _solve(problem)
        rows.append(_row(body, "graded", level, scene, problem, result, _cpu(comm) - cpu0))
        problem.destroy()
    return rows


def adaptive(comm, body, max_levels):
    make, coarse, *_ = BODIES[body]
    scene, rebuild = make(comm, **coarse)
    try:
        run = ad.solve_adaptive(
            lambda m, t: rebuild(m, t).problem(),
            scene.mesh,
            scene.facet_tags,
            target=TARGET,
            surface=scene.surface,
            max_levels=max_levels,
        )
    except ad.AdaptiveLimitError as err:
        run = err.adaptive
    final = rebuild(run.mesh, run.facet_tags)
    row = _row(body, "adaptive", len(run.history) - 1, final, run.problem, run.result, 0.0)
    row["cpu [s]"] = sum(h.cpu_seconds for h in run.history)
    row["estimate"] = run.estimated_error
    levels = [
        {
            "body": body,
            "level": h.level,
            "dofs": h.dofs,
            "m": h.contact_nodes,
            "p0 error": h.quantity / scene.info["p0"] - 1.0,
            "estimate": "–" if h.estimate is None else f"{h.estimate:.2e}",
            "iterations": h.iterations,
            "cpu [s]": h.cpu_seconds,
            # the CPU of the levels up to this one (each one's solve, estimate, marking,
            # and the refinement that made the next mesh)
            "cpu to here [s]": sum(k.cpu_seconds for k in run.history[: h.level + 1]),
        }
        for h in run.history
    ]
    return row, levels


#: The flat punch: uniform levels, graded levels, adaptive refinements.
PUNCH_LEVELS = (4, 4, 24)
#: The errors of the punch's force its summary looks for.
PUNCH_TARGETS = (0.05, 0.03, 0.01)


def _punch_row(method, level, scene, problem, result, cpu):
    return {
        "method": method,
        "level": level,
        "dofs": problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
        "m": problem.num_contact_nodes,
        "active": result.num_active,
        "force error": float(np.linalg.norm(result.contact_force)) / scene.info["force"] - 1.0,
        "area error": result.contact_area / scene.info["area"] - 1.0,
        "iterations": result.iterations,
        "cpu [s]": cpu,
        "cpu to here [s]": cpu,
        "estimate": "–",
    }


def punch(comm, levels=PUNCH_LEVELS):
    """The flat punch's rows: uniform, graded by hand, and solve_adaptive's levels."""
    n_uniform, n_graded, n_adaptive = levels
    rows = []
    scene = lib.flat_punch(comm)
    msh, tags = scene.mesh, scene.facet_tags
    for level in range(n_uniform):
        cpu0 = _cpu(comm)
        scene = lib.flat_punch_on(msh, tags)
        problem = scene.problem()
        result = _solve(problem)
        rows.append(_punch_row("uniform", level, scene, problem, result, _cpu(comm) - cpu0))
        problem.destroy()
        if level + 1 < n_uniform:
            msh, tags, _ = refine_contact_mesh(
                msh, tags, all_local_edges(msh), scene.contact_marker
            )
    for level in range(n_graded):
        cpu0 = _cpu(comm)
        scene = lib.flat_punch_graded(comm, level=level)
        problem = scene.problem()
        result = _solve(problem)
        rows.append(_punch_row("graded", level, scene, problem, result, _cpu(comm) - cpu0))
        problem.destroy()
    scene = lib.flat_punch(comm)
    try:
        run = ad.solve_adaptive(
            lambda m, t: lib.flat_punch_on(m, t).problem(),
            scene.mesh,
            scene.facet_tags,
            target=TARGET,
            quantity="contact_force",
            max_levels=n_adaptive,
        )
    except ad.AdaptiveLimitError as err:
        run = err.adaptive
    force, area = scene.info["force"], scene.info["area"]
    spent = 0.0
    for h in run.history:
        spent += h.cpu_seconds
        rows.append(
            {
                "method": "adaptive",
                "level": h.level,
                "dofs": h.dofs,
                "m": h.contact_nodes,
                "active": h.active,
                "force error": h.quantity / force - 1.0,
                "area error": "–",
                "iterations": h.iterations,
                "cpu [s]": h.cpu_seconds,
                "cpu to here [s]": spent,
                "estimate": "–" if h.estimate is None else f"{h.estimate:.2e}",
            }
        )
    # the last level's area (the levels record the force, the quantity asked for)
    rows[-1]["area error"] = run.result.contact_area / area - 1.0
    run.problem.destroy()
    return rows, run.converged


def punch_summary(rows, claimed):
    """Per way: the first mesh from which on every mesh is within each target."""
    out = []
    for method in ("uniform", "graded", "adaptive"):
        sel = [r for r in rows if r["method"] == method]
        entry = {"method": method}
        for target in PUNCH_TARGETS:
            seen = next(
                (
                    r
                    for i, r in enumerate(sel)
                    if all(abs(q["force error"]) <= target for q in sel[i:])
                ),
                None,
            )
            entry[f"within {target:.0%}: dofs (level)"] = (
                "not reached" if seen is None else f"{seen['dofs']} ({seen['level']})"
            )
            entry[f"cpu [s] ({target:.0%})"] = (
                "–" if seen is None else f"{seen['cpu to here [s]']:.2f}"
            )
        last = sel[-1]
        entry["finest: dofs, force error"] = f"{last['dofs']}, {last['force error']:+.2e}"
        if method == "adaptive":
            entry["claimed"] = "yes" if claimed else "no (AdaptiveLimitError)"
        else:
            entry["claimed"] = "–"
        out.append(entry)
    return out


def _punch_fmt(row):
    out = dict(row)
    for key in ("force error", "area error"):
        if isinstance(out.get(key), float):
            out[key] = f"{out[key]:+.2e}"
    for key in ("cpu [s]", "cpu to here [s]"):
        out[key] = f"{out[key]:.2f}"
    return out


def _fmt(row):
    out = dict(row)
    for key in ("p0 error", "nodal max error", "a error", "force error"):
        if isinstance(out.get(key), float):
            out[key] = f"{out[key]:+.2e}"
    if isinstance(out.get("cpu [s]"), float):
        out["cpu [s]"] = f"{out['cpu [s]']:.2f}"
    if isinstance(out.get("estimate"), float):
        out["estimate"] = f"{out['estimate']:.2e}"
    return out


def _level_fmt(level):
    out = dict(level)
    out["p0 error"] = f"{level['p0 error']:+.2e}"
    for key in ("cpu [s]", "cpu to here [s]"):
        out[key] = f"{level[key]:.2f}"
    return out


def first_within(rows, target):
    """The first row from which on every finer row's p0 error is within target."""
    for i, row in enumerate(rows):
        if all(abs(r["p0 error"]) <= target for r in rows[i:]):
            return row
    return None


def summary(body, uniform_rows, graded_rows, adaptive_row, adaptive_levels):
    u, g = first_within(uniform_rows, TARGET), first_within(graded_rows, TARGET)
    a = adaptive_row if abs(adaptive_row["p0 error"]) <= TARGET else None
    # the adaptive levels judged as the graded and uniform ones are: by Hertz's answer
    seen = first_within(adaptive_levels, TARGET)
    last = uniform_rows[-1]
    if u is None:  # not reached on the meshes this machine holds
        u_text = (
            f"not reached ({last['p0 error']:+.0%} at {last['dofs']} dofs, {last['cpu [s]']:.2f} s)"
        )
    else:
        u_text = f"{u['cpu [s]']:.2f} ({u['dofs']} dofs)"
    if a is None:
        ratio = "–"
    elif u is not None:
        ratio = f"{u['cpu [s]'] / adaptive_row['cpu [s]']:.1f}"
    else:
        # a uniform mesh within the target is finer than the finest one run, and costs
        # more than it: the finest one's CPU bounds the ratio from below
        ratio = f"> {last['cpu [s]'] / adaptive_row['cpu [s]']:.1f}"
    return {
        "body": body,
        "uniform cpu [s]": u_text,
        "adaptive cpu [s]": f"{adaptive_row['cpu [s]']:.2f}",
        "uniform / adaptive cpu": ratio,
        "graded dofs": "not reached" if g is None else g["dofs"],
        "graded cpu [s]": "–" if g is None else f"{g['cpu [s]']:.2f}",
        "adaptive dofs": adaptive_row["dofs"],
        "adaptive p0 error": f"{adaptive_row['p0 error']:+.2e}",
        "adaptive first within: dofs (level)": "not reached"
        if seen is None
        else f"{seen['dofs']} ({seen['level']})",
        "cpu to there [s]": "–" if seen is None else f"{seen['cpu to here [s]']:.2f}",
        "estimate": f"{adaptive_row['estimate']:.2e}" if adaptive_row["estimate"] else "–",
    }


def plot(rows, path, full_run=False, punch_rows=()):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bodies = sorted({r["body"] for r in rows})
    panels = len(bodies) + (1 if punch_rows else 0)
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4.2), squeeze=False)
    if punch_rows:
        ax = axes[0][-1]
        for method, style in (("uniform", "o-"), ("graded", "s-"), ("adaptive", "*-")):
            sel = [r for r in punch_rows if r["method"] == method]
            ax.loglog(
                [r["cpu to here [s]"] for r in sel],
                [max(abs(r["force error"]), 1e-5) for r in sel],
                style,
                label=method,
            )
        ax.axhline(TARGET, color="grey", lw=0.8, ls="--")
        ax.set_xlabel("CPU seconds (adaptive: all levels to there)")
        ax.set_ylabel("relative error of the contact force")
        ax.set_title("Boussinesq flat punch")
        ax.legend()
    for ax, body in zip(axes[0], bodies, strict=False):
        for method, style in (("uniform", "o-"), ("graded", "s-"), ("adaptive", "*-")):
            sel = [r for r in rows if r["body"] == body and r["method"] == method]
            if sel:
                ax.loglog(
                    [r["cpu [s]"] for r in sel],
                    [max(abs(r["p0 error"]), 1e-5) for r in sel],
                    style,
                    label=method,
                )
        ax.axhline(TARGET, color="grey", lw=0.8, ls="--")
        ax.set_xlabel("CPU seconds")
        ax.set_ylabel("relative error of the peak pressure")
        ax.set_title(f"Hertz {body}, a = R/{SLENDERNESS:g}")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    if full_run:  # the book's figure
        fig.savefig(Path(__file__).resolve().parents[1] / "docs" / "figures" / path.name, dpi=120)


def punch_step1(comm, max_levels):
    """The punch's adaptive levels with the default step-1 plan and with factorisations.

    The two runs refine alike (the same marking on the same solutions to the
    tolerance); the rows pair their levels.
    """
    runs = {}
    for name, options in (("default", {}), ("factorised", {"step1": "factorised"})):
        scene = lib.flat_punch(comm)
        try:
            run = ad.solve_adaptive(
                lambda m, t: lib.flat_punch_on(m, t).problem(),
                scene.mesh,
                scene.facet_tags,
                target=TARGET,
                quantity="contact_force",
                max_levels=max_levels,
                **options,
            )
        except ad.AdaptiveLimitError as err:
            run = err.adaptive
        run.problem.destroy()
        runs[name] = run.history
    rows = []
    for d, f in zip(runs["default"], runs["factorised"], strict=False):
        if d.dofs < PUNCH_STEP1_FROM:
            continue
        rows.append(
            {
                "level": d.level,
                "dofs": d.dofs,
                "active": d.active,
                "default step 1": d.step1,
                "default its": d.iterations,
                "default cpu [s]": f"{d.cpu_seconds:.2f}",
                "factorised dofs": f.dofs,
                "factorised its": f.iterations,
                "factorised cpu [s]": f"{f.cpu_seconds:.2f}",
                "default / factorised cpu": f"{d.cpu_seconds / f.cpu_seconds:.2f}",
            }
        )
    total = {name: sum(h.cpu_seconds for h in history) for name, history in runs.items()}
    rows.append(
        {
            "level": "all",
            "dofs": runs["default"][-1].dofs,
            "active": runs["default"][-1].active,
            "default step 1": "–",
            "default its": sum(h.iterations for h in runs["default"]),
            "default cpu [s]": f"{total['default']:.2f}",
            "factorised dofs": runs["factorised"][-1].dofs,
            "factorised its": sum(h.iterations for h in runs["factorised"]),
            "factorised cpu [s]": f"{total['factorised']:.2f}",
            "default / factorised cpu": f"{total['default'] / total['factorised']:.2f}",
        }
    )
    return rows


#: The punch's step-1 table lists the levels from this size on.
PUNCH_STEP1_FROM = 10_000


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument(
        "--part",
        choices=("all", "punch-step1"),
        default="all",
        help="punch-step1: the punch's adaptive levels with the default step-1 plan "
        "and with step1='factorised', side by side (its own table)",
    )
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    if args.part == "punch-step1":
        rows = punch_step1(comm, 3 if args.quick else PUNCH_LEVELS[2])
        if comm.rank == 0:
            print_and_save(rows, out / "work_precision_adaptive_punch_step1.csv")
        return
    bodies = {"cylinder": BODIES["cylinder"]} if args.quick else BODIES
    rows, summaries, histories = [], [], []
    for body, (_, _, n_uniform, n_graded) in bodies.items():
        if args.quick:
            n_uniform, n_graded = 3, 2
        u = uniform(comm, body, n_uniform)
        g = graded(comm, body, n_graded)
        a, levels = adaptive(comm, body, 3 if args.quick else 12)
        rows += u + g + [a]
        histories += levels
        summaries.append(summary(body, u, g, a, levels))
    punch_rows, claimed = punch(comm, (2, 1, 4) if args.quick else PUNCH_LEVELS)
    if comm.rank == 0:
        print_and_save([_fmt(r) for r in rows], out / "work_precision_adaptive_methods.csv")
        print_and_save(
            [_level_fmt(h) for h in histories], out / "work_precision_adaptive_levels.csv"
        )
        print_and_save(summaries, out / "work_precision_adaptive_at_one_percent.csv")
        if punch_rows:
            print_and_save(
                [_punch_fmt(r) for r in punch_rows], out / "work_precision_adaptive_punch.csv"
            )
            print_and_save(
                punch_summary(punch_rows, claimed),
                out / "work_precision_adaptive_punch_within.csv",
            )
        full = not args.quick and os.environ.get("ADMM_BENCHMARK_PAGE", "1") != "0"
        plot(rows, out / "work_precision_adaptive.png", full_run=full, punch_rows=punch_rows)


if __name__ == "__main__":
    main()
