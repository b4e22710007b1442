"""Regenerate the paper's Tables 1–6 from scratch, with the paper's numbers beside ours.

Every table runs the paper's ADMM (``mode="paper"``: Algorithm 2, no acceleration, the
relative-change test at ``rtol = 1e-5``) in the paper's contact model (non-penetration
along the body's normal, ``contact_normal="body"``) on our gmsh meshes; r* comes from
:func:`~admm_dolfinx.estimate_penalty` and r̄ from
:func:`~admm_dolfinx.studies.sweep.sample_penalty` on the paper's grid of 200 points in
(0.1, 10)·E. Times are wall-clock seconds on this machine; the paper's are
MATLAB CPU seconds on its machine and are shown for reference only.
"""

from __future__ import annotations

import csv
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mpi4py import MPI

from admm_dolfinx.admm.solver import ADMMSolver
from admm_dolfinx.io.output import atomic_file, rank0_write
from admm_dolfinx.scenes.library import Scene, example1, example2, example3
from admm_dolfinx.studies.sweep import paper_penalty_grid, sample_penalty

__all__ = ["PAPER_MODEL", "TABLES", "Table", "run_table"]

#: The paper's contact model: non-penetration along the body's normal (Tables 1–6).
PAPER_MODEL = "body"

Progress = Callable[[str], None]


@dataclass
class Table:
    """A reproduced table: rows of ours and the paper's values side by side."""

    name: str
    title: str
    columns: list[str]
    rows: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: Iterations-vs-r curves ``(label, r, iterations)`` and marked points, if any.
    curves: list[tuple] = field(default_factory=list)
    marks: list[tuple] = field(default_factory=list)
    figure: str = ""

    def markdown(self) -> str:
        """The table as GitHub markdown, with its notes."""
        lines = [f"**{self.name}: {self.title}**", ""]
        lines.append("| " + " | ".join(self.columns) + " |")
        lines.append("|" + "|".join("---" for _ in self.columns) + "|")
        for row in self.rows:
            lines.append("| " + " | ".join(_fmt(row.get(c, "")) for c in self.columns) + " |")
        lines += [""] + [f"- {note}" for note in self.notes]
        return "\n".join(lines)

    def write_csv(self, path: Path) -> None:
        """Write the rows as CSV, whole or not at all (one process)."""
        with atomic_file(path, newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=self.columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(self.rows)


def _fmt(value) -> str:
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def _seconds(t: float) -> float:
    return float(f"{t:.3g}")


def _solve(problem, r, **kwargs):
    """ADMM at a fixed r (returns result and wall time, factorisation included)."""
    t0 = time.perf_counter()
    with ADMMSolver(problem, penalty=r, mode="paper", **kwargs) as solver:
        result = solver.solve()
    return result, time.perf_counter() - t0


def _sweep(problem, E, progress: Progress, label: str, samples: int):
    def report(k, n, r, its):
        if k == n or k % 20 == 0:
            progress(f"{label}: sampling r, {k}/{n} (r = {r:.4g}: {its} iterations)")

    return sample_penalty(problem, paper_penalty_grid(E, samples), progress=report)


def _r_star_row(problem, progress: Progress, label: str):
    progress(f"{label}: r* (Algorithm 5 with SLEPc) and ADMM at r*")
    t0 = time.perf_counter()
    with ADMMSolver(problem, mode="paper") as solver:
        result = solver.solve()
        estimate = solver.penalty_estimate
    return estimate, result, time.perf_counter() - t0


def _fixed_penalty_table(
    name: str,
    title: str,
    progress: Progress,
    meshes: Sequence[tuple[str, Callable[[], Scene], tuple]],
    r_star: float,
    r_bar: float,
) -> Table:
    """Iterations and times of Algorithm 2 at two fixed penalties over a mesh sequence.

    Args:
        name: Table name.
        title: Table title.
        progress: Progress callback.
        meshes: ``(label, build_scene, paper)`` with ``paper`` either
            ``(iter r*, iter r̄)`` (the mesh is named by h = label) or
            ``(nodes/m_c, iter r*, iter r̄)``.
        r_star: The paper's r*.
        r_bar: The paper's r̄.
    """
    by_h = len(meshes[0][2]) == 2
    head = ["h", "nodes"] if by_h else ["nodes/m_c (paper)", "nodes/m_c"]
    table = Table(
        name,
        title,
        [
            *head,
            "iter r* (paper)",
            "iter r*",
            "time r* [s]",
            "iter r̄ (paper)",
            "iter r̄",
            "time r̄ [s]",
        ],
    )
    for label, build, paper in meshes:
        progress(f"{name} {label}")
        scene = build()
        problem = scene.problem(contact_normal=PAPER_MODEL)
        res_star, t_star = _solve(problem, r_star)
        res_bar, t_bar = _solve(problem, r_bar)
        mesh = (
            {"h": label, "nodes": scene.num_nodes}
            if by_h
            else {
                "nodes/m_c (paper)": paper[0],
                "nodes/m_c": f"{scene.num_nodes}/{problem.num_contact_nodes}",
            }
        )
        table.rows.append(
            mesh
            | {
                "iter r* (paper)": paper[-2],
                "iter r*": res_star.iterations,
                "time r* [s]": _seconds(t_star),
                "iter r̄ (paper)": paper[-1],
                "iter r̄": res_bar.iterations,
                "time r̄ [s]": _seconds(t_bar),
            }
        )
        problem.destroy()
    return table


_SAMPLING_COLUMNS = [
    "m_c (paper)",
    "m_c",
    "r* (paper)",
    "r*",
    "iter r* (paper)",
    "iter r*",
    "time r* [s]",
    "r̄ (paper)",
    "r̄",
    "iter r̄ (paper)",
    "iter r̄",
    "time r̄ [s]",
    "iter r* / iter r̄",
]


def _sampling_row(
    table: Table, problem, E: float, progress: Progress, label: str, samples: int, paper: tuple
) -> dict:
    """One row of r* (with its ADMM solve) against the sampled r̄, plus its curve.

    ``paper`` is (m_c, r*, iter r*, time r*, r̄, iter r̄, time r̄) from the paper.
    """
    est, res, t_star = _r_star_row(problem, progress, label)
    sweep = _sweep(problem, E, progress, label, samples)
    name = label.split(" ", 1)[1]
    table.curves.append((name, sweep.r, sweep.iterations))
    table.marks.append((f"r* ({name}): {res.iterations} it.", est.r, res.iterations))
    return {
        "m_c (paper)": paper[0],
        "m_c": problem.num_contact_nodes,
        "r* (paper)": paper[1],
        "r*": est.r,
        "iter r* (paper)": paper[2],
        "iter r*": res.iterations,
        "time r* [s]": _seconds(t_star),
        "r̄ (paper)": paper[4],
        "r̄": sweep.r_best,
        "iter r̄ (paper)": paper[5],
        "iter r̄": sweep.iterations_best,
        "time r̄ [s]": _seconds(sweep.time),
        "iter r* / iter r̄": round(res.iterations / sweep.iterations_best, 2),
    }


# --------------------------------------------------------------------------- Example 1
def table1(progress: Progress, quick: bool = False) -> Table:
    """Table 1: r* against the sampled r̄ on Example 1, h = 1/8 ... 1/32 (and 1/64)."""
    nan = math.nan
    paper = {
        8: (17, 1591.4878, 35, 0.057, 3510, 19, 1.797),
        16: (33, 2220.5867, 27, 0.177, 2810, 18, 4.957),
        32: (65, 3134.1289, 27, 0.269, 3510, 19, 23.766),
        64: (nan, nan, nan, nan, nan, nan, nan),
    }
    table = Table(
        "Table 1",
        "r̄ obtained by sampling versus r* (Example 1)",
        ["h", *_SAMPLING_COLUMNS],
        figure="figure2",
    )
    samples = 40 if quick else 200
    for n in (8, 16) if quick else (8, 16, 32, 64):
        problem = example1(h=1 / n).problem(contact_normal=PAPER_MODEL)
        row = _sampling_row(table, problem, 2000.0, progress, f"table1 h=1/{n}", samples, paper[n])
        table.rows.append({"h": f"1/{n}"} | row)
        problem.destroy()
    table.notes += [
        "m_c: our contact nodes exclude the clamped corner (0, 0), whose normal "
        "displacement is fixed by the Dirichlet condition (the paper counts it).",
        f"r̄: fewest iterations over {samples} points uniformly in (0.1, 10)·E; ties go "
        "to the smallest r.",
        "h = 1/64 is beyond the paper's table (no paper values).",
    ]
    return table


def table2(progress: Progress, quick: bool = False) -> Table:
    """Table 2: Algorithm 2 at the paper's fixed r* = 3134.1289 and r̄ = 3510."""
    paper = {8: (24, 19), 16: (19, 20), 32: (27, 19), 64: (25, 20), 128: (19, 20), 256: (21, 20)}
    meshes = [
        (f"1/{n}", (lambda n=n: example1(h=1 / n)), paper[n])
        for n in ((8, 16, 32) if quick else (8, 16, 32, 64, 128, 256))
    ]
    table = _fixed_penalty_table(
        "Table 2",
        "Algorithm 2 with r* = 3134.1289 and r̄ = 3510 (Example 1)",
        progress,
        meshes,
        3134.1289,
        3510.0,
    )
    table.notes.append("The penalties are the paper's values (from its h = 1/32 mesh).")
    return table


# --------------------------------------------------------------------------- Example 2
def table3(progress: Progress, quick: bool = False) -> Table:
    """Table 3: r* against r̄ on the Hertz problem, m_c = 35 and 69."""
    paper = {
        0: (35, 137.1789, 59, 0.084, 200, 49, 46.357),
        1: (69, 201.7825, 43, 0.166, 200, 44, 215.029),
    }
    table = Table(
        "Table 3",
        "r̄ obtained by sampling versus r* (Hertz problem)",
        [*_SAMPLING_COLUMNS[:2], "nodes", *_SAMPLING_COLUMNS[2:]],
        figure="figure5",
    )
    samples = 40 if quick else 200
    for level in (0,) if quick else (0, 1):
        scene = example2(level=level)
        problem = scene.problem(contact_normal=PAPER_MODEL)
        row = _sampling_row(
            table,
            problem,
            2000.0,
            progress,
            f"table3 m_c={problem.num_contact_nodes}",
            samples,
            paper[level],
        )
        table.rows.append(row | {"nodes": scene.num_nodes})
        problem.destroy()
    # The paper makes A invertible with "a small positive constant on the vertical
    # components of Γ_D": measure how its r* then depends on that constant.
    springs = []
    for k in (2.0, 0.1):
        progress(f"table3: r* with a spring of stiffness {k} on the symmetry line")
        problem = example2(level=0, spring=k).problem(contact_normal=PAPER_MODEL)
        with ADMMSolver(problem, mode="paper", max_iter=5000) as solver:
            res = solver.solve()
        springs.append(f"k = {k}: r* = {res.penalty:.4g}, {res.iterations} iterations")
        problem.destroy()
    table.notes += [
        "Our r* deflates the free vertical translation (λ = ∞), so it needs no spring. "
        "The paper adds a spring of unstated stiffness k to the vertical motion of Γ_D "
        "instead; its r* then falls like √k. Measured on the m_c = 35 mesh: "
        + "; ".join(springs)
        + ". The paper's r* = 137 corresponds to k ≈ 2, and a smaller r* needs more "
        "iterations here: the gap to the paper's counts is this choice, not the ADMM.",
        "Geometry: R = 8 quarter cylinder as read in the book (Reproducing the paper, "
        "'What differs from the paper'; the paper's text is "
        "not self-consistent).",
    ]
    return table


def table4(progress: Progress, quick: bool = False) -> Table:
    """Table 4: Algorithm 2 at r* = 201.7825 and r̄ = 200 on five Hertz meshes."""
    paper = {
        0: ("442/35", 49, 49),
        1: ("1692/69", 43, 44),
        2: ("6619/125", 54, 56),
        3: ("26181/229", 51, 51),
        4: ("104137/457", 50, 51),
    }
    meshes = [
        (f"level {k}", (lambda k=k: example2(level=k)), paper[k])
        for k in ((0, 1) if quick else (0, 1, 2, 3, 4))
    ]
    return _fixed_penalty_table(
        "Table 4",
        "Algorithm 2 with r* = 201.7825 and r̄ = 200 (Hertz problem)",
        progress,
        meshes,
        201.7825,
        200.0,
    )


# --------------------------------------------------------------------------- Example 3
def table5(progress: Progress, quick: bool = False) -> Table:
    """Table 5: r* against r̄ on the coarse 3D mesh."""
    table = Table(
        "Table 5",
        "r̄ obtained by sampling versus r* (3D obstacle problem)",
        ["", "r (paper)", "r", "iter (paper)", "iter", "time (paper) [s]", "time [s]"],
    )
    scene = example3(level=0)
    problem = scene.problem(contact_normal=PAPER_MODEL)
    est, res, t_star = _r_star_row(problem, progress, "table5")
    sweep = _sweep(problem, 1e6, progress, "table5", 40 if quick else 200)
    table.rows += [
        {
            "": "r*",
            "r (paper)": 3.1026e6,
            "r": est.r,
            "iter (paper)": 28,
            "iter": res.iterations,
            "time (paper) [s]": 0.083,
            "time [s]": _seconds(t_star),
        },
        {
            "": "r̄",
            "r (paper)": 2.6e6,
            "r": sweep.r_best,
            "iter (paper)": 28,
            "iter": sweep.iterations_best,
            "time (paper) [s]": 8.035,
            "time [s]": _seconds(sweep.time),
        },
    ]
    table.notes.append(
        f"Mesh: {scene.num_nodes} nodes, {problem.num_contact_nodes} contact "
        "nodes (the paper's: 198/45)."
    )
    problem.destroy()
    return table


def table6(progress: Progress, quick: bool = False) -> Table:
    """Table 6: Algorithm 2 at r* = 3.1026e6 and r̄ = 2.6e6 on four 3D meshes."""
    paper = {
        0: ("198/45", 28, 26),
        1: ("1289/153", 30, 28),
        2: ("9245/603", 31, 33),
        3: ("69897/2341", 32, 30),
    }
    meshes = [
        (f"level {k}", (lambda k=k: example3(level=k)), paper[k])
        for k in ((0, 1) if quick else (0, 1, 2, 3))
    ]
    return _fixed_penalty_table(
        "Table 6",
        "Algorithm 2 with r* = 3.1026e6 and r̄ = 2.6e6 (3D problem)",
        progress,
        meshes,
        3.1026e6,
        2.6e6,
    )


TABLES: dict[str, Callable[..., Table]] = {
    "table1": table1,
    "table2": table2,
    "table3": table3,
    "table4": table4,
    "table5": table5,
    "table6": table6,
}


def stderr_progress(message: str) -> None:
    """Progress on rank 0's stderr: one updating line on a terminal, lines otherwise."""
    if MPI.COMM_WORLD.rank != 0:
        return
    if sys.stderr.isatty():
        sys.stderr.write("\r\033[K" + message)
    else:
        sys.stderr.write(message + "\n")
    sys.stderr.flush()


def run_table(
    name: str, out: Path, *, quick: bool = False, progress: Progress = stderr_progress
) -> Table:
    """Build one table, print it as markdown (rank 0) and write ``out/<name>.csv``."""
    t0 = time.perf_counter()
    table = TABLES[name](progress, quick=quick)
    table.notes.append(
        f"Regenerated in {time.perf_counter() - t0:.0f} s on {MPI.COMM_WORLD.size} process(es)."
    )

    def write() -> None:
        if sys.stderr.isatty():
            sys.stderr.write("\r\033[K")
        print(table.markdown() + "\n", flush=True)
        table.write_csv(Path(out) / f"{name}.csv")
        if table.curves:
            from admm_dolfinx.io.plotting import plot_iterations_vs_penalty

            plot_iterations_vs_penalty(
                table.curves,
                Path(out) / f"{table.figure}.png",
                marks=table.marks,
                title=f"Iterations against r ({table.title.split('(')[-1].rstrip(')')})",
                comm=MPI.COMM_SELF,
            )
            print(f"wrote {Path(out) / table.figure}.png\n", flush=True)

    rank0_write(MPI.COMM_WORLD, Path(out), write)  # a failure raises on every rank
    return table
