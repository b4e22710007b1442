"""The numbers that the book's prose quotes are the numbers of the pages they come from.

The benchmark scripts write their tables to ``docs/benchmarks/<script>.md``
(``benchmarks/tables.py``); the chapters include those tables (MyST ``{include}``) or
quote numbers from them. Each quoted number is checked here against its page: the
value is read off the page's table (or computed from it: a range, a ratio), and the
words that quote it must be in the chapter as written. Rerunning a script that
changes a quoted number, or editing the number in the prose, fails this test; update
both sides. Numbers that the prose quotes from the code (a default, a limit) are read
off the source the same way, and so are the prose numbers that quote the tables of
"Reproducing the paper" (the output of ``admm-dolfinx reproduce all``, pasted there).
Reads files only: no solve, no import of the package.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = DOCS / "benchmarks"

_CELL_SPLIT = re.compile(r"(?<!\\)\|")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


# ----------------------------------------------------------------------------- reading
def _flat(text: str) -> str:
    return " ".join(text.split())


@functools.cache
def _doc(name: str) -> str:
    path = ROOT / name if name == "README.md" else DOCS / name
    return _flat(path.read_text())


@functools.cache
def _section(path: Path, heading: str) -> str:
    """The text under the heading line ``heading`` (``## name``), up to the next heading."""
    text = path.read_text()
    start = text.find(f"\n{heading}\n")
    assert start >= 0, f"{path.name} has no section {heading!r}"
    body = text[start + len(heading) + 2 :]
    following = re.search(r"\n#{1,3} ", body)
    return body[: following.start()] if following else body


def _parse_table(text: str) -> list[dict[str, str]]:
    lines = [line.strip() for line in text.splitlines() if line.strip().startswith("|")]
    assert len(lines) >= 3, "no markdown table"

    def cells(line: str) -> list[str]:
        return [c.strip().replace("\\|", "|") for c in _CELL_SPLIT.split(line)[1:-1]]

    keys = cells(lines[0])
    return [dict(zip(keys, cells(line), strict=True)) for line in lines[2:]]


def page_rows(page: str, section: str, **where: str) -> list[dict[str, str]]:
    """Rows of the table in section ``## section`` of ``docs/benchmarks/<page>.md``."""
    rows = _parse_table(_section(PAGES / f"{page}.md", f"## {section}"))
    return _select(rows, where, f"{page}.md / {section}")


def doc_rows(doc: str, heading: str, **where: str) -> list[dict[str, str]]:
    """Rows of the table under ``heading`` (a whole heading line) in ``docs/<doc>``."""
    rows = _parse_table(_section(DOCS / doc, heading))
    return _select(rows, where, f"{doc} / {heading}")


def _select(rows, where, name):
    chosen = [row for row in rows if all(row[k] == v for k, v in where.items())]
    assert chosen, f"no row of {name} has {where}"
    return chosen


def cell(rows: list[dict[str, str]], column: str) -> str:
    assert len(rows) == 1, f"{len(rows)} rows where one was meant"
    return rows[0][column]


def num(text: str) -> float:
    """The first number in a cell: '-6.9e-01 gap' → -0.69, '+0.10%' → 0.10."""
    match = _NUMBER.search(text)
    assert match, f"no number in {text!r}"
    return float(match.group())


def nums(rows: list[dict[str, str]], column: str) -> list[float]:
    return [num(row[column]) for row in rows]


def span(values, fmt: Callable[[float], str]) -> str:
    low, high = fmt(min(values)), fmt(max(values))
    return low if low == high else f"{low}–{high}"


def f2(x: float) -> str:
    return f"{x:.2f}"


def e1(x: float) -> str:
    return f"{x:.1e}"


def source_constant(path: str, pattern: str) -> str:
    """The group of ``pattern`` in a source file (a default, a limit)."""
    match = re.search(pattern, (ROOT / path).read_text(), re.M)
    assert match, f"{path} no longer matches {pattern!r}"
    return match.group(1)


def rate(h, errors) -> float:
    """Least-squares slope of log(error) against log(h) (studies.hertz.observed_rate)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


def at_most(value: float, bound: str) -> str:
    assert value <= float(bound), f"{value} exceeds the quoted bound {bound}"
    return bound


def ceil1(x: float) -> str:
    """x rounded up to one significant digit, as in '≤ 7e-11' for 6.4e-11."""
    exponent = math.floor(math.log10(x))
    return f"{math.ceil(x / 10**exponent)}e{exponent:03d}".replace("e-0", "e-")


def provenance(page: str, section: str) -> tuple[str, str]:
    """(command, date and time) of the run that wrote a page's section."""
    match = re.search(
        r"Written by `([^`]+)` on (\S+ \S+ UTC)", _section(PAGES / f"{page}.md", f"## {section}")
    )
    assert match, f"{page}.md / {section} names no run"
    return match[1], match[2]


#: The tables of "Reproducing the paper" (the output of ``admm-dolfinx reproduce all``).
TABLE1 = "### Table 1: r̄ obtained by sampling versus r* (Example 1)"
TABLE3 = "### Table 3: r̄ obtained by sampling versus r* (Hertz problem)"
TABLE4 = "### Table 4: Algorithm 2 with r* = 201.7825 and r̄ = 200 (Hertz problem)"
TABLE5 = "### Table 5: r̄ obtained by sampling versus r* (3D obstacle problem)"
TABLE6 = "### Table 6: Algorithm 2 with r* = 3.1026e6 and r̄ = 2.6e6 (3D problem)"


# ------------------------------------------------------------------- the quoted numbers
def _contact_model():
    rows = lambda scene: page_rows("contact_model", "contact model", scene=scene)  # noqa: E731
    disc, ball = rows("half-disc pressed 7.5 gaps"), rows("half-ball pressed 7.5 gaps")
    sink = [f"{-100 * num(cell(r, 'lowest node (body)')):.0f} %" for r in (disc, ball)]
    low = [f"{100 * (1 - num(cell(r, '|F| body / obstacle'))):.2g} %" for r in (disc, ball)]
    return sink, low


def _contact_model_method():
    sink, low = _contact_model()
    hertz = page_rows("contact_model", "contact model", scene="Hertz cylinder (a = R/80)")
    distance = cell(hertz, "|u_body − u_obstacle| / |u|").replace("e-0", "e-")
    return [*sink, *low, distance]


def _contact_model_deep_indenter():
    block = page_rows("contact_model", "contact model", scene="Example 3 (block on ball, level 0)")
    return [f"{100 * (num(cell(block, '|F| body / obstacle')) - 1):.1f} %"]


def _hertz(body: str, model: str) -> list[dict[str, str]]:
    return page_rows("hertz_validation", "hertz validation", body=body, **{"contact normal": model})


def _cylinder_rates():
    out = []
    for model in ("obstacle", "body"):
        rows = _hertz("cylinder", model)[:4]
        assert [row["level"] for row in rows] == ["0", "1", "2", "3"]
        out.append(f2(rate(nums(rows, "h/a"), nums(rows, "L2 error"))))
    return out


def _hertz_prose():
    obstacle, body = _hertz("cylinder", "obstacle"), _hertz("cylinder", "body")
    for rows in (obstacle, body):
        assert [row["level"] for row in rows] == ["0", "1", "2", "3", "4", "5"]
        at_most(max(abs(x) for x in nums(rows[1:], "p0 error")), "0.5")
        assert all(row["a error / h"] == "0.00" for row in rows)
        assert all(row["iterations"] == "2" for row in rows)
    at_most(max(abs(x) for x in nums(obstacle, "force error")), "1e-12")
    p0_body = nums(body[2:], "p0 error")
    return [
        *_cylinder_rates(),
        "0.5 %",
        "a error / h = 0.00",
        f"to {obstacle[5]['p0 error'].replace('%', ' %')} at level 5",
        f"over levels 0–5: {obstacle[5]['fitted L2 rate']}",
        f"stays at {min(p0_body):+.2f} % to {max(p0_body):+.2f} % from level 2 on",
        f"falls to {body[5]['L2 rate']} (fitted over levels 0–5: {body[5]['fitted L2 rate']})",
        f"off by {body[5]['force error'].lstrip('+')}",
        f"element size a/{1 / num(obstacle[0]['h/a']):.0f} … a/{1 / num(obstacle[5]['h/a']):.0f}",
    ]


def _factor_prediction():
    rows = page_rows("factor_prediction", "factor prediction")
    meshes = [row for row in rows if row["dofs"] != "–"]
    assert all(row["flops in bracket"] == row["memory in bracket"] == "True" for row in meshes)

    def summary(label, column):
        text = cell(_select(rows, {"case": f"geometric mean (range): {label}"}, ""), column)
        return re.match(r"(\S+) \((\S+) to (\S+)\)", text).groups()

    mean, low, high = summary("all", "MUMPS / Σ s³")
    _, memory_low, memory_high = summary("all", "MUMPS bytes / Σ s²")
    scenes, boxes = summary("scene", "MUMPS / Σ s³")[0], summary("box", "MUMPS / Σ s³")[0]
    ladder = ["158k", "257k", "530k", "1.2M"]
    basis = [cell(_select(rows, {"case": c}, ""), "plan").split("(")[1] for c in ladder]
    first = basis.index("mesh)")
    assert all(b == "mesh)" for b in basis[first:])
    case = lambda name, column: cell(_select(rows, {"case": name}, ""), column)  # noqa: E731
    return [
        f"the bracket decides from {ladder[first]} dofs up",
        f"{low} to {high} times the model's sum",
        f"their geometric mean is {mean}; {scenes} on the scenes alone, {boxes} on",
        f"its memory {memory_low} to {memory_high} bytes per entry",
        f"takes {case('257k', 'plan s')} s at 257k and {case('1.2M', 'plan s')} s at 1.2M",
        f"against {case('257k', 'analysis s')} s and {case('1.2M', 'analysis s')} s",
    ]


def _step1_crossover():
    rows = page_rows("step1_crossover", "step1 crossover")
    ratio = {row["mesh"]: row["multigrid / factorised"] for row in rows}
    flops = {row["mesh"]: num(row["MUMPS flops"]) for row in rows}
    limit = float(source_constant("src/admm_dolfinx/admm/plan.py", r"^FACTOR_FLOPS_LIMIT = (\S+)$"))
    assert limit == 1e10  # the chapter writes it 10¹⁰
    below = [m for m in ratio if flops[m] <= limit]
    above = [m for m in ratio if flops[m] > limit]
    return [
        f"{span([num(ratio[m]) for m in below], f2)} the factorised time below 10¹⁰",
        f"{span([num(ratio[m]) for m in above], f2)} above it",
        f"{ratio['158k']} at 158k dofs",
        f"took at most {max(nums(rows, 'default plan s')):.2g} s",
    ]


def _strips():
    rows = page_rows("strips", "strips")
    kappa, m = nums(rows, "κ (pencil)"), nums(rows, "m")
    assert all(row["iterations"] == "2" for row in rows)
    return [f"{min(kappa):.1e} to {max(kappa):.1e} (m = {min(m):.0f} to {max(m):.0f})"]


def _hard_cases():
    rows = page_rows("hard_cases", "hard cases")
    two_d = [row for row in rows if not row["case"].startswith("3D")]
    three_d = [row for row in rows if row["case"].startswith("3D")]
    assert all(row["status (default)"] == "converged" for row in rows)
    stopped_short = [row["case"] for row in rows if row["status (paper)"] != "converged"]
    assert stopped_short == ["negative gap"]
    assert [row["case"] for row in two_d if row["iterations (default)"] != "2"] == ["nu=0.499"]
    assert cell(_select(rows, {"case": "nu=0.499"}, ""), "iterations (default)") == "3"
    e1_, e9 = (_select(rows, {"case": c}, "")[0] for c in ("E=1", "E=1e9"))
    assert e1_["iterations (default)"] == e9["iterations (default)"]
    assert e1_["iterations (paper)"] == e9["iterations (paper)"]
    case = lambda name, column: cell(_select(rows, {"case": name}, ""), column)  # noqa: E731
    kkt = max(nums(two_d, "KKT (default)"))
    return [
        f"(≤ {ceil1(kkt)})",
        f"needs {span(nums(three_d, 'iterations (default)'), lambda x: f'{x:.0f}')} iterations",
        f"the paper's ADMM needs {case('3D nu=0.499', 'iterations (paper)')}",
        f"stops after {case('3D all of Γ_C active', 'iterations (paper)')} iterations at a KKT "
        f"residual of {num(case('3D all of Γ_C active', 'KKT (paper)')):.0e}".replace("e-0", "e-"),
        f"KKT residual of {case('negative gap', 'KKT (paper)')}".replace("e-0", "e-"),
        f"it needed {case('nothing touches', 'iterations (paper)')} iterations",
    ]


def _penalty_cost(problem: str) -> dict[str, str]:
    return page_rows("penalty_cost", "penalty cost", problem=problem)[0]


def _breakdown(row: dict[str, str]) -> tuple[float, float]:
    """(condensed factorisation, dense) seconds of a 2D estimate breakdown."""
    match = re.fullmatch(r"condensed factorisation (\S+) \+ dense (\S+)", row["estimate breakdown"])
    assert match, row["estimate breakdown"]
    return float(match.group(1)), float(match.group(2))


def _penalty_cost_2d():
    h64, h128, h256 = (_penalty_cost(f"example1 h=1/{n}") for n in (64, 128, 256))
    ratios = [_breakdown(r)[0] / num(r["t_factorization"]) for r in (h64, h128, h256)]
    return [
        f"dense part took {1e3 * _breakdown(h64)[1]:.2g} ms at m = {h64['m']} and "
        f"{1e3 * _breakdown(h128)[1]:.2g} ms at m = {h128['m']}",
        f"costs {span(ratios, f2)}× as much",
        f"({_breakdown(h64)[0]} s against {h64['t_factorization']} s at h = 1/64, "
        f"{_breakdown(h256)[0]} s against {h256['t_factorization']} s at h = 1/256)",
    ]


def _penalty_cost_bullets():
    h64, h128, h256 = (_penalty_cost(f"example1 h=1/{n}") for n in (64, 128, 256))
    block = _penalty_cost("example3 level 3")
    over = "(auto-admm)/admm"
    over_acc = "(auto-admm)/admm accelerated"
    dense64 = _breakdown(h64)[1]
    overheads = [num(r[c]) for r in (h64, h128, h256, block) for c in (over, over_acc)]
    premium = _breakdown(h256)[0] / num(h256["t_factorization"])
    standalone = [num(r["estimate/admm"]) for r in (h64, h128, h256)]
    return [
        f"r* adds {h64[over]} to the paper-mode solve and {h64[over_acc]} to the accelerated",
        f"takes {1e3 * dense64:.2g} ms, {dense64 / num(h64['t_admm']):.2f} of the solve",
        f"{_breakdown(h64)[0]:.2g} s against {h64['t_factorization']} s for A + r*K",
        f"overhead is {h128[over]} / {h128[over_acc]} at h = 1/128 and "
        f"{h256[over]} / {h256[over_acc]} at h = 1/256",
        f"premium is {premium:.2f}× at h = 1/256 ({_breakdown(h256)[0]} s against "
        f"{num(h256['t_factorization']):.3g} s)",
        f"exceeds the fixed-r one by {num(h128['t_auto']) - num(h128['t_admm']):.2f} s, of "
        f"which the factorisations explain "
        f"{_breakdown(h128)[0] - num(h128['t_factorization']):.2f} s and r* "
        f"{h128['r* in auto']} s",
        f"took {_breakdown(h256)[1]} s at m = {h256['m']}",
        f"({num(block['nodes']) * 3 / 1e3:.0f}k dofs",
        f"takes {block['estimate/admm']} of the paper's solve and "
        f"{num(block['t_estimate']) / num(block['t_admm accelerated']):.2f} of the accelerated "
        f"one ({block['accelerated iterations']} iterations instead of {block['iterations']})",
        f"overhead inside the solvers is {block[over]} / {block[over_acc]}",
        f"≤ {max(overheads):.2f} holds at every size",
        f"({span(standalone, f2)} of a solve)",
    ]


def _penalty_accuracy():
    rows = page_rows("penalty_accuracy", "penalty accuracy")
    dense = [row for row in rows if row["method"] == "dense"]
    local = [row for row in rows if row["method"] == "local"]
    tight = [row for row in rows if row["tol"] == "1e-08"]
    multigrid = [row for row in local if row["λ_max by"] == "multigrid"]
    assert {row["mesh"] for row in tight} == {row["mesh"] for row in rows}
    return [
        f"≤ {max(nums(dense, 'err λ_min')):.1e} in λ_min, ≤ {max(nums(dense, 'err λ_max')):.1e} "
        f"in λ_max and ≤ {max(nums(dense, 'err r*')):.1e} in r*",
        f"within {max(nums(local, 'err r*')):.1e} in r*".replace("e-0", "e-"),
        f"within {max(nums(local, 'err λ_min')):.1e}".replace("e-0", "e-"),
        f"within {max(nums(multigrid, 'err λ_max')):.1e}".replace("e-0", "e-"),
        f"agrees to ≤ {at_most(max(nums(tight, 'err r*')), '1e-12')}",
    ]


def _rule():
    rows = page_rows("surface_metric", "surface metric rule")
    mesh = {row["mesh"]: row for row in rows}

    def its(row, column, k):  # iterations to 1e-6 (k = 0) or 1e-8 (k = 1)
        return int(row[column].split("/")[k])

    default, best, paper = "surface (default)", "surface at r_best", "paper metric"
    excess = [[its(r, default, k) - its(r, best, k) for r in rows] for k in (0, 1)]
    worst = [r["mesh"] for r in rows if its(r, default, 0) - its(r, best, 0) == max(excess[0])]
    assert worst == ["slab level 0", "slab level 1"]
    fewer = [r["mesh"] for r in rows if its(r, default, 0) - its(r, best, 0) == -1]
    assert fewer == ["punch level 0", "punch level 1"] and min(excess[0]) == -1
    small = ["slab level 0", "clamped level 0", "slab level 1", "clamped level 1"]
    for name in small[2:]:
        assert its(mesh[name], default, 0) == its(mesh[name], paper, 0)
    others = [r for r in rows if r["mesh"] not in small]
    share = {r["mesh"]: its(r, default, 0) / its(r, paper, 0) for r in others}
    ex3 = [f2(share[f"example3 level {k}"]) for k in range(3)]
    kappa = [mesh[f"example3 level {k}"]["κ"] for k in range(3)]
    return [
        f"({' → '.join(kappa)} on Example 3); κ_R stays at {span(nums(rows, 'κ_R'), f2)}",
        f"(r / r_best {span(nums(rows, 'r / r_best'), f2)})",
        f"μ_min/λ_max is {span(nums(rows, 'μ_min/λ_max'), f2)}",
        f"{span(nums(rows, 'μ_max layers/dense'), f2)} of the whole body's",
        f"at most {max(excess[0])} iterations more than at r_best to 1e-6 (the slab at levels 0 "
        f"and 1) and {max(excess[1])} more to 1e-8",
        f"κ {mesh['slab level 0']['κ']} and {mesh['clamped level 0']['κ']}",
        f"({its(mesh['slab level 0'], default, 0)} against {its(mesh['slab level 0'], paper, 0)}"
        f" and {its(mesh['clamped level 0'], default, 0)} against "
        f"{its(mesh['clamped level 0'], paper, 0)} to 1e-6)",
        f"(κ {mesh['slab level 1']['κ']} and {mesh['clamped level 1']['κ']}) as many "
        f"({its(mesh['slab level 1'], default, 0)} and {its(mesh['clamped level 1'], default, 0)})",
        f"needs {span(share.values(), f2)} of the paper metric's count",
        f"(Example 3, levels 0–2: {', '.join(ex3)})",
    ]


def _condition_numbers():
    rows = page_rows("surface_metric", "surface metric rule")
    return [
        f"condition number of {span(nums(rows, 'κ_R'), f2)} where the paper's has "
        f"{min(nums(rows, 'κ')):.3g}–{max(nums(rows, 'κ')):.3g}"
    ]


def _calibration():
    rows = page_rows("surface_metric", "surface metric calibrate")
    total, worst = (_select(rows, {"mesh": name}, "")[0] for name in ("sum", "max"))
    default, plain = "b=0.25 m=0.15 (default)", "b=1 m=0.5"
    slab = page_rows("surface_metric", "surface metric rule", mesh="slab level 1")[0]
    return [
        f"{total[default]} iterations over the nine meshes and at most {worst[default]}, "
        f"against {total[plain]} and {worst[plain]}",
        f"r / r_best {slab['r / r_best']} at level 1, where the default needs "
        f"{slab['surface (default)']} iterations against {slab['surface at r_best']} at r_best",
    ]


def _floating_3d():
    rows = page_rows("floating_3d", "floating 3d")
    by = {(row["mesh"], row["config"]): row for row in rows}

    def config(name, scene=""):
        return [r for r in rows if r["config"] == name and r["mesh"].startswith(scene)]

    def whole(x: float) -> str:
        return f"{x:.0f}"

    polished, plain_steps = config("multigrid"), config("plain steps")
    assert all(row["its"] == "2" for row in polished + plain_steps)
    assert all(num(row["KKT"]) <= 1e-6 for row in polished + plain_steps + config("no polish"))
    level4 = [by[(f"{scene} level 4", "plain")] for scene in ("hertz", "wide")]
    hertz, wide = (
        [
            num(by[(f"{scene} level {k}", "multigrid")]["wall [s]"])
            / num(by[(f"{scene} level {k}", "no polish")]["wall [s]"])
            for k in (2, 3, 4)
        ]
        for scene in ("hertz", "wide")
    )
    per_round = [
        num(row["walk Krylov its"]) / num(row["rounds"]) / num(by[(row["mesh"], "plain")]["its"])
        for row in polished
    ]
    versus_plain_steps = [
        num(row["wall [s]"]) / num(by[(row["mesh"], "plain steps")]["wall [s]"]) for row in polished
    ]
    versus_factorised = [
        num(by[(f"{scene} level 3", "multigrid")]["wall [s]"])
        / num(by[(f"{scene} level 3", "factorised")]["wall [s]"])
        for scene in ("hertz", "wide")
    ]
    assert all(
        by[(f"{scene} level 3", "default")]["plan"] == "iterative, polish sparse"
        for scene in ("hertz", "wide")
    )
    return [
        f"levels 2–4 (level 4: {int(level4[0]['dofs']):,} and {int(level4[1]['dofs']):,} "
        f"dofs, {level4[0]['m']} and {level4[1]['m']} contact nodes; there the plan takes the "
        "path by itself), one solve after the other in one run: * polished, every solve "
        "takes 2 iterations, against "
        f"{span(nums(config('no polish', 'hertz'), 'its'), whole)} unpolished "
        f"on the Hertz ball and {span(nums(config('no polish', 'wide'), 'its'), whole)} "
        "on the wide one, all within the KKT tolerance; * on the Hertz ball the polished "
        f"solve takes {span(hertz, f2)} of the unpolished time, but on the wide ball, whose "
        f"ADMM alone is quick, {span(wide, f2)} of it; * either way it costs "
        f"{span(nums(polished, 'wall / plain'), lambda x: f'{x:.1f}')}× a plain CG + GAMG "
        "solve of the same size: the walk takes "
        f"{span(nums(polished, 'rounds'), lambda x: f'{x:.0f}')} rounds, each "
        f"{span(per_round, lambda x: f'{x:.1f}')} times a plain solve's Krylov iterations"
        "; * against the walk's plain primal-dual steps (the row *plain steps*), which "
        f"took {span(nums(plain_steps, 'rounds'), lambda x: f'{x:.0f}')} rounds, it takes "
        f"{span(versus_plain_steps, f2)} of their time"
        "; * where the time goes, in plain solves (r* / set-up / walk / rest of the "
        "iterations): on the Hertz ball "
        + ", ".join(
            f"{by[(f'hertz level {k}', 'multigrid')]['r* / set-up / walk / rest ÷ plain']} "
            f"on level {k}"
            for k in (2, 3, 4)
        )
        + "; "
        f"* on level 3 it took {versus_factorised[0]:.2f} (Hertz) and "
        f"{versus_factorised[1]:.2f} (wide) of the time of the factorised path "
        '(`step1="factorised"`, polished from its factors) of the same run',
    ]


def _wide_sphere_polish():
    rows = page_rows("polish_3d", "polish 3d wide sphere")
    l3 = _select(rows, {"mesh": "level 3"}, "")[0]
    assert all(row["default: its"] == "2" for row in rows)
    return [
        f"at the second iteration on levels 1–3 (up to {l3['m']} contact nodes, "
        f"{int(l3['dofs']):,} dofs), at {l3['default: / plain']}× a plain solve",
        f"only {span(nums(rows, 'no polish: its'), lambda x: f'{x:.0f}')} iterations",
        f"made it {l3['default / no polish']}× the unpolished time",
    ]


def _hertz_sphere_polish():
    rows = page_rows("polish_3d", "polish 3d hertz sphere")
    level = {row["mesh"]: row for row in rows}
    up_to_2 = [level[f"level {k}"] for k in range(3)]
    l2, l3 = level["level 2"], level["level 3"]
    return [
        f"{span(nums(rows, 'no polish: its'), lambda x: f'{x:.0f}')} iterations to 1e-6",
        f"contact set in {span(nums(rows, 'polish: its'), lambda x: f'{x:.0f}')}",
        f"takes {span(nums(up_to_2, 'polish / no polish'), f2)} of the unpolished time up to "
        f"level 2 ({l2['m']} contact nodes, {int(l2['dofs']):,} dofs)",
        f"{l3['polish / no polish']}× it on level 3 ({l3['m']} contact nodes, "
        f"{int(l3['dofs']):,} dofs)",
        f"costs {num(l3['condensed − plain factorisation [s]']):.0f} s beyond",
        f"({num(l3['C × C of (A + r*K)⁻¹ by inverse entries [s]']):.2g} s on level 3)",
        f"the default of that run (factorised, as a floating body then was up to 10¹² "
        f"operations) took {l3['default: its']} iterations, exact to round-off, in "
        f"{l3['default / no polish']} of the unpolished time, where the walk from ADMM's own "
        f"guess (`walk alone` on the page) took {l3['walk alone: its']}",
        f"default was {l3['default: / plain']}× a plain solve",
    ]


def _scale_3d():
    rows = page_rows("scale_3d", "scale 3d")
    ratios = [r for r in rows if r["config"] == "ratios"]
    default = [r for r in rows if r["config"] == "default"]
    uniform = [r for r in ratios if not r["mesh"].startswith("graded")]
    graded = _select(ratios, {"mesh": "graded 350k"}, "")[0]
    total = "total"
    time_ratio = [num(r[total]) for r in uniform]
    memory = [num(r["peak RSS GB"]) for r in ratios]
    snes = [num(r["iterations"].split("/default")[1]) for r in ratios if "SNES" in r["iterations"]]
    with_snes = [r for r in default if r["mesh"] in {"158k", "257k", "graded 350k"}]
    largest = _select(default, {"mesh": "2.2M"}, "")[0]
    r_share = [num(r["r*/solve"]) for r in default if r["mesh"] != "graded 350k"]
    return [
        f"{span(time_ratio, lambda x: f'{x:.1f}')}× the plain CG + GAMG solve",
        f"({num(_select(ratios, {'mesh': '1.2M'}, '')[0][total]):.2f}× at 1.2M)",
        f"and {num(graded[total]):.2f}× on the graded mesh",
        f"at {span(memory, lambda x: f'{x:.1f}')}× its peak memory "
        f"({num(largest['peak RSS GB']):.1f} GB at {num(largest['dofs']) / 1e6:.2f}M dofs)",
        f"in {span(nums(default, 'iterations'), lambda x: f'{x:.0f}')} iterations",
        f"{span(snes, lambda x: f'{x:.1f}')}× faster than SNES VI",
        f"within {span(nums(with_snes, 'vs ref'), lambda x: f'{x * 1e7:.0f}')}e-7 of SNES VI's",
        f"r* was {span(r_share, lambda x: f'{x:.3f}')} of the solve, "
        f"{num(graded['r*/solve']):.3f} on the graded mesh",
        f"from 158k to {num(largest['dofs']) / 1e6:.2f}M dofs",
    ]


def _scale_3d_mpi():
    rows = page_rows("scale_3d", "scale 3d mpi")

    def run(mesh, config, processes):
        return _select(rows, {"mesh": mesh, "config": config, "processes": processes}, "")[0]

    out = []
    for mesh in ("257k", "1.2M"):
        one, two = run(mesh, "default", "1"), run(mesh, "default", "2")
        out.append(f"{num(two['total']) / num(one['total']):.2f}×")
    s1, s2 = run("1.2M", "default", "1"), run("1.2M", "default", "2")
    t1, t2 = run("257k", "default", "1"), run("257k", "default", "2")
    tight = [r for r in rows if r["config"] == "tight"]
    gaps = [run(m, "tight", "2")["vs serial"] for m in ("257k", "1.2M")]
    return [
        f"took {out[0]} the serial time at 257k dofs and {out[1]} at 1.2M",
        f"from {num(s1['step 2+']):.2f} to {num(s2['step 2+']):.2f} s at 1.2M",
        f"from {num(t1['step 2+']):.2g} to {num(t2['step 2+']):.2g} s at 257k",
        f"({num(t1['λ_min s']):.3f} → {num(t2['λ_min s']):.3f} s and "
        f"{num(s1['λ_min s']):.2f} → {num(s2['λ_min s']):.2f} s)",
        f"within {run('257k', 'default', '2')['vs serial'].replace('e-0', 'e-')} (257k) and "
        f"{run('1.2M', 'default', '2')['vs serial'].replace('e-0', 'e-')} (1.2M)",
        f"{span(nums(tight, 'iterations'), lambda x: f'{x:.0f}')} iterations) the gap fell to "
        f"{gaps[0]} and {gaps[1]}",
    ]


def _inner_tolerance():
    rows = page_rows("inner_tolerance", "inner tolerance")

    def run(case, label):
        return next(r for r in _select(rows, {"case": case}, "") if r["σ"].endswith(label))

    held = ("158k", "graded 350k", "hex 212k")
    floating = ("hertz sphere level 2", "hertz sphere level 3")
    now = [run(c, "(rule)") for c in held]
    before = [run(c, "(rule before)") for c in held]
    return [
        ", ".join(r["/plain"] + "×" for r in now[:-1]) + f" and {now[-1]['/plain']}×",
        ", ".join(r["/plain"] + "×" for r in before[:-1]) + f" and {before[-1]['/plain']}×",
        f"in {span(nums(now, 'iterations'), lambda x: f'{x:.0f}')} iterations "
        f"({span(nums(before, 'iterations'), lambda x: f'{x:.0f}')} before)",
        *(
            f"{run(c, '(rule)')['iterations']} iterations in {run(c, '(rule)')['solve s']} s "
            f"against {run(c, '(rule before)')['iterations']} in "
            f"{run(c, '(rule before)')['solve s']} s"
            for c in floating
        ),
    ]


def _scale_2d():
    rows = page_rows("scale_2d", "scale 2d")
    finest = _select(rows, {"h": "1/512"}, "")[0]
    coarser = [r for r in rows if r["h"] != "1/512"]
    assert all(r["ADMM its"] == "2" for r in coarser)
    premium = num(finest["factorisation"]) - num(finest["plain factorisation"])
    return [
        f"h = 1/512 ({num(finest['dofs']) / 1e6:.1f}M dofs, {finest['contact nodes']} contact "
        f"nodes) took {finest['ADMM its']} iterations and {finest['default/plain']}× the plain",
        f"took 2 iterations and {span(nums(coarser, 'default/plain'), f2)}×",
        f"at h = 1/512, {premium:.1f} s and {num(finest['iterations s']):.1f} s of the "
        f"{finest['default total']} s",
    ]


def _reproduction_example3():
    t5 = doc_rows("reproduction.md", TABLE5)
    star = _select(t5, {"": "r*"}, "")[0]
    ours, paper = num(star["r"]), num(star["r (paper)"])
    t6 = doc_rows("reproduction.md", TABLE6)
    t1 = doc_rows("reproduction.md", TABLE1)
    below = [100 * (1 - num(r["r*"]) / num(r["r* (paper)"])) for r in t1 if r["r* (paper)"] != "–"]
    dense = page_rows("penalty_accuracy", "penalty accuracy", mesh="example3 level 0")[0]
    return [
        f"Table 5's r* is {100 * (ours / paper - 1):.0f} % above the paper's "
        f"({ours / 1e6:.2f}e6 against {paper / 1e6:.2f}e6)",
        f"gives r* = {dense['r* (dense)']}",
        f"ours is {span(below, lambda x: f'{x:.1f}')} % below",
        f"{t6[0]['iter r*']} (Table 6, level 0) against {star['iter']} (Table 5)",
    ]


def _reproduction_fine_mesh():
    block = _penalty_cost("example3 level 3")
    t6 = doc_rows("reproduction.md", TABLE6)
    ladder = page_rows("scale_3d", "scale 3d", mesh="158k", config="default")[0]
    return [
        f"r* = {num(block['r*']):.1e} needs {block['iterations']} paper-mode iterations where "
        f"the paper's coarse r* = 3.1e6 needs {t6[-1]['iter r*']}".replace("e+0", "e"),
        f"it needs {block['accelerated iterations']} iterations",
        f"in the surface metric, {ladder['iterations']} (the `158k` default row",
        f"{ladder['dofs']} dofs and {ladder['contact nodes']} contact nodes",
    ]


def _reproduction_tables():
    t1 = doc_rows("reproduction.md", TABLE1)
    h8 = _select(t1, {"h": "1/8"}, "")[0]
    t3 = doc_rows("reproduction.md", TABLE3)
    m69 = _select(t3, {"m_c": "69"}, "")[0]
    t4 = doc_rows("reproduction.md", TABLE4)
    ratio = max(
        num(r[ours]) / num(r[paper])
        for r in t4
        for ours, paper in (("iter r*", "iter r* (paper)"), ("iter r̄", "iter r̄ (paper)"))
    )
    notes = _flat(_section(DOCS / "reproduction.md", TABLE3))
    spring = re.search(
        r"k = 2\.0: r\* = (\S+), (\d+) iterations; k = 0\.1: r\* = (\S+), (\d+) iterations", notes
    )
    assert spring, "Table 3's notes lost the spring measurements"
    return [
        f"needs {h8['iter r̄']} iterations at r̄ and {h8['iter r*']} at r* for h = 1/8 (paper: "
        f"{h8['iter r̄ (paper)']} and {h8['iter r* (paper)']})",
        f"m_c = 69: {m69['iter r*']} against {m69['iter r* (paper)']}",
        f"our r* is {spring[1]} (paper: 137) and ADMM needs {spring[2]} iterations (paper: 59); "
        f"with stiffness 0.1 it is {num(spring[3]):.0f} and needs {spring[4]}",
        f"within {ratio:.1f}× of the paper's on every mesh",
    ]


#: (doc, words of the doc, what the page says): the values that ``expected`` derives
#: from the pages must each be in the words, and the words in the doc.
QUOTES: list[tuple[str, str, Callable[[], list[str]]]] = [
    (
        "method.md",
        "the paper's model lets the disc sink by 69 % and the ball by 76 % of the initial gap "
        "below the plane, and the contact force comes out 7.5 % and 13 % low; with small "
        "contact zones (Hertz at a = R/80) the two agree to 1.5e-3",
        _contact_model_method,
    ),
    (
        "design.md",
        "pressed far sink by 69 % and 76 % of the initial gap, their contact force 7.5 % and "
        "13 % low",
        lambda: [x for pair in _contact_model() for x in pair],
    ),
    (
        "validation.md",
        "the two models' contact forces differ by 2.6 % (the body's model's is the larger",
        _contact_model_deep_indenter,
    ),
    (
        "validation.md",
        "(element size a/4 … a/128)",
        lambda: [_hertz_prose()[-1]],
    ),
    (
        "validation.md",
        "the least-squares L2 rate over levels 0–3 is 1.05 along the obstacle's normal and "
        "1.00 along the body's. p0 is within 0.5 % from level 1 on, and the discrete contact "
        "zone brackets the analytic a on every mesh (a error / h = 0.00).",
        lambda: _hertz_prose()[:4],
    ),
    (
        "validation.md",
        "along the obstacle's normal the p0 error keeps falling, to +0.10 % at level 5 "
        "(fitted L2 rate over levels 0–5: 0.92), and the contact force equals the load to "
        "round-off; along the body's normal the p0 error stays at +0.28 % to +0.44 % from "
        "level 2 on, the L2 rate falls to 0.36 (fitted over levels 0–5: 0.74), and the force "
        "is off by 1.4e-05.",
        lambda: _hertz_prose()[4:9],
    ),
    (
        "testing.md",
        "1.05 along the obstacle's normal and 1.00 along the body's on the levels 0–3 of",
        _cylinder_rates,
    ),
    ("validation.md", "condition number of 9.3e+09 to 1.1e+12 (m = 1000 to 20000)", _strips),
    (
        "acceleration.md",
        "The default of that run polished at the second iteration on levels 1–3 (up to 2267 "
        "contact nodes, 86,277 dofs), at 2.88× a plain solve on level 3. But a wide zone is "
        "an easy one for the ADMM: unpolished it needs only 39–43 iterations, and on level "
        "3, where the unpolished plan takes multigrid (its factorisation would cost more "
        "than `FACTOR_FLOPS_LIMIT`), the factorisation and inverse entries that the default "
        "then kept for polishing (up to 10¹² operations) made it 1.79× the unpolished time",
        _wide_sphere_polish,
    ),
    (
        "acceleration.md",
        "levels 2–4 (level 4: 490,170 and 496,527 dofs, 6074 and 6565 contact nodes; there "
        "the plan takes the path by itself), one solve after the other in one run: * "
        "polished, every solve takes 2 iterations, against 135–238 unpolished on the Hertz "
        "ball and 42–45 on the wide one, all within the KKT tolerance; * on the Hertz ball "
        "the polished solve takes 0.14–0.27 of the unpolished time, but on the wide ball, "
        "whose ADMM alone is quick, 0.51–0.68 of it; * either way it costs 4.4–7.1× a "
        "plain CG + GAMG solve of the same size: the walk takes 9–11 rounds, each 0.7–0.9 "
        "times a plain solve's Krylov iterations; * against the walk's plain primal-dual "
        "steps (the row *plain steps*), which took 11–16 rounds, it takes 0.57–0.94 of "
        "their time; * where the time goes, in plain solves "
        "(r* / set-up / walk / rest of the iterations): on the Hertz ball 1.2 / 0.4 / 5.3 / "
        "0.1 on level 2, 1.0 / 0.3 / 4.9 / 0.1 on level 3, 0.9 / 0.3 / 3.9 / 0.1 on level "
        "4; * on level 3 it took 0.32 (Hertz) and 0.26 (wide) of the time of the factorised "
        'path (`step1="factorised"`, polished from its factors) of the same run',
        _floating_3d,
    ),
    (
        "scale.md",
        "MUMPS's count is 6.64 to 31 times the model's sum (`FLOPS_CONSTANT` = 14: their "
        "geometric mean is 13.5; 11 on the scenes alone, 19.9 on the boxes), its memory 41.6 "
        "to 79.7 bytes per entry of the model (`MEMORY_CONSTANT` = 58), every figure inside "
        "the bracket, with the band's margin of 10 kept for shapes not measured. On the 3D "
        "ladder the bracket decides from 158k dofs up, where making the plan takes 0.0807 s "
        "at 257k and 0.62 s at 1.2M against 1.34 s and 8.82 s for MUMPS's analysis",
        _factor_prediction,
    ),
    (
        "validation.md",
        "with KKT residuals at round-off (≤ 7e-11)",
        lambda: _hard_cases()[:1],
    ),
    (
        "validation.md",
        "In 3D the surface metric needs 8–18 iterations in every case, the nearly "
        "incompressible block (ν = 0.499) included, where the paper's ADMM needs 242",
        lambda: _hard_cases()[1:3],
    ),
    (
        "validation.md",
        "the paper's relative-change test stops after 8 iterations at a KKT residual of 2e-4.",
        lambda: _hard_cases()[3:4],
    ),
    (
        "validation.md",
        "it stopped at a KKT residual of 1.5e-2, and with nothing in contact it needed 310 "
        "iterations.",
        lambda: _hard_cases()[4:],
    ),
    (
        "penalty.md",
        "its dense part took 1.5 ms at m = 128 and 6.7 ms at m = 256",
        lambda: _penalty_cost_2d()[:1],
    ),
    (
        "penalty.md",
        "That factorisation costs 1.21–1.45× as much as the factorisation of A + r*K in the "
        "cost table below (0.0328 s against 0.027 s at h = 1/64, 1.9 s against 1.309 s at "
        "h = 1/256)",
        lambda: _penalty_cost_2d()[1:],
    ),
    (
        "penalty.md",
        "The dense method (2D) agrees to ≤ 6.0e-15 in λ_min, ≤ 2.2e-12 in λ_max and ≤ 1.1e-12 "
        "in r*",
        lambda: _penalty_accuracy()[:1],
    ),
    (
        "penalty.md",
        "is within 1.1e-3 in r* on the same meshes and on Example 3 (levels 0, 1, 2): the "
        "λ_min layers (which stop when two agree to 2·tol) within 9.9e-4, the multigrid λ_max "
        "(its residual test at tol, one vector) within 1.5e-3.",
        lambda: _penalty_accuracy()[1:4],
    ),
    (
        "penalty.md",
        "At `1e-8` every iterative r* agrees to ≤ 1e-12.",
        lambda: _penalty_accuracy()[4:],
    ),
    (
        "penalty.md",
        "r* adds 0.11 to the paper-mode solve and 0.18 to the accelerated one. The dense "
        "eigenproblem takes 1.5 ms, 0.02 of the solve. The rest is the condensed "
        "factorisation's premium: 0.033 s against 0.027 s for A + r*K.",
        lambda: _penalty_cost_bullets()[:3],
    ),
    (
        "penalty.md",
        "the overhead is 0.25 / 0.15 at h = 1/128 and 0.21 / 0.13 at h = 1/256. The condensed "
        "factorisation's premium is 1.45× at h = 1/256 (1.9 s against 1.31 s). Its "
        "substitutions are dearer too (AMD against AMF): at h = 1/128 the auto solve exceeds "
        "the fixed-r one by 0.18 s, of which the factorisations explain 0.07 s and r* 0.007 s. "
        "The dense part of r* took 0.048 s at m = 512",
        lambda: _penalty_cost_bullets()[3:7],
    ),
    (
        "penalty.md",
        "(158k dofs; local r*, λ_max by multigrid; step 1 factorised in every column): the "
        "estimate takes 0.10 of the paper's solve and 0.18 of the accelerated one (25 "
        "iterations instead of 114). Its overhead inside the solvers is 0.12 / 0.19.",
        lambda: _penalty_cost_bullets()[7:10],
    ),
    (
        "penalty.md",
        "≤ 0.25 holds at every size, against both solves (0.25 at h = 1/128 against the paper's).",
        lambda: [
            *_penalty_cost_bullets()[10:11],
            _penalty_cost("example1 h=1/128")["(auto-admm)/admm"],
        ],
    ),
    ("penalty.md", "(0.38–0.42 of a solve)", lambda: _penalty_cost_bullets()[11:]),
    (
        "penalty.md",
        "the page [penalty_cost](benchmarks/penalty_cost.md), run 2026-12-04)",
        lambda: [provenance("penalty_cost", "penalty cost")[1].split()[0]],
    ),
    (
        "acceleration.md",
        "has a condition number of 2.66–6.98 where the paper's has 4.68–84.2 (the *surface "
        "metric rule* table below)",
        _condition_numbers,
    ),
    (
        "acceleration.md",
        "142–239 iterations to 1e-6 with the surface metric. Polishing finds the contact set "
        "in 2 iterations on every level",
        lambda: _hertz_sphere_polish()[:2],
    ),
    (
        "acceleration.md",
        "takes 0.29–0.59 of the unpolished time up to level 2 (867 contact nodes, "
        "17,640 dofs), and 2.05× it on level 3 (2032 contact nodes, 79,311 dofs), where the "
        "condensed factorisation costs 51 s beyond the plain one.",
        lambda: _hertz_sphere_polish()[2:5],
    ),
    (
        "acceleration.md",
        "(5.6 s on level 3)",
        lambda: _hertz_sphere_polish()[5:6],
    ),
    (
        "acceleration.md",
        "on level 3 the default of that run (factorised, as a floating body then was up to "
        "10¹² operations) took 2 iterations, exact to round-off, in 0.72 of the unpolished "
        "time, where the walk from ADMM's own guess (`walk alone` on the page) took 35.",
        lambda: _hertz_sphere_polish()[6:7],
    ),
    (
        "acceleration.md",
        "default was 3.21× a plain solve",
        lambda: _hertz_sphere_polish()[7:],
    ),
    (
        "acceleration.md",
        "κ grows like 1/h (12 → 37.8 → 84.2 on Example 3); κ_R stays at 2.66–6.98 everywhere.",
        lambda: _rule()[:1],
    ),
    (
        "acceleration.md",
        "(r / r_best 1.08–1.93), as the calibration below chose it: μ_min/λ_max is 0.15–0.46, "
        "at or above the rule's m = 0.15, and μ_max on the contact nodes alone is 0.67–0.91 of "
        "the whole body's. The accelerated iteration then needs at most 4 iterations more than "
        "at r_best to 1e-6 (the slab at levels 0 and 1) and 5 more to 1e-8, and one fewer on "
        "the punch at levels 0 and 1.",
        lambda: _rule()[1:5],
    ),
    (
        "acceleration.md",
        "(the slab and the clamped block at level 0: κ 4.9 and 4.68) the surface metric needs "
        "more iterations than the paper's metric (13 against 10 and 11 against 9 to 1e-6), at "
        "level 1 (κ 12 and 11.3) as many (14 and 12); elsewhere it needs 0.52–0.92 of the "
        "paper metric's count to 1e-6, and the gap widens with refinement (Example 3, levels "
        "0–2: 0.92, 0.67, 0.52).",
        lambda: _rule()[5:],
    ),
    (
        "acceleration.md",
        "On the twelve meshes of `--part rule` μ_max is 0.67–0.91 of the whole body's",
        lambda: _rule()[3:4],
    ),
    (
        "acceleration.md",
        "gives the smallest sum and the smallest maximum of the grid: 111 iterations over the "
        "nine meshes and at most 14, against 136 and 20",
        lambda: _calibration()[:1],
    ),
    (
        "acceleration.md",
        "r / r_best 1.79 at level 1, where the default needs 14 / 18 iterations against 10 / 13 "
        "at r_best.",
        lambda: _calibration()[1:],
    ),
    (
        "acceleration.md",
        "shows the counts at 158k–2.27M dofs",
        lambda: [_scale_3d()[-1].replace("from 158k to ", "158k–")],
    ),
    (
        "scale.md",
        "took 0.88–1.55 the factorised time below 10¹⁰ operations and 0.25–0.89 above it "
        "(0.30 at 158k dofs); the default's choice between them took at most 0.45 s",
        _step1_crossover,
    ),
    (
        "scale.md",
        "On its run of 2026-12-06 22:56 UTC",
        lambda: [provenance("inner_tolerance", "inner tolerance")[1]],
    ),
    (
        "scale.md",
        "the rule took 1.67×, 1.77× and 1.60× a plain CG + GAMG solve on the 158k, graded "
        "350k and hexahedral 212k held bodies, against 2.23×, 2.20× and 1.99× by the rule "
        "before, in 12–14 iterations (13–15 before); on the floating Hertz sphere, "
        "unpolished, 219 iterations in 23.5 s against 238 in 24.6 s at level 2, and 122 "
        "iterations in 68.9 s against 169 in 100 s at level 3.",
        _inner_tolerance,
    ),
    (
        "scale.md",
        "On the run of 2026-12-06 01:02 UTC (`python benchmarks/scale_3d.py --mpi "
        "--snes-limit 1200`)",
        lambda: list(provenance("scale_3d", "scale 3d")),
    ),
    (
        "scale.md",
        "the default took 1.7–2.2× the plain CG + GAMG solve at every uniform size from 158k "
        "to 2.27M dofs (1.74× at 1.2M), and 1.94× on the graded mesh, at 1.2–1.4× its peak "
        "memory (5.9 GB at 2.27M dofs), in 14–15 iterations;",
        lambda: [*_scale_3d()[:5], _scale_3d()[-1]],
    ),
    (
        "scale.md",
        "it was 10.8–18.4× faster than SNES VI where SNES VI ran, its answer within 1–2e-7 of "
        "SNES VI's",
        lambda: _scale_3d()[5:7],
    ),
    (
        "scale.md",
        "r* was 0.079–0.097 of the solve, 0.088 on the graded mesh;",
        lambda: _scale_3d()[7:8],
    ),
    (
        "scale.md",
        "under `mpiexec -n 2` the solve took 0.53× the serial time at 257k dofs and 0.56× at 1.2M.",
        lambda: _scale_3d_mpi()[:1],
    ),
    (
        "scale.md",
        "Step 2 went from 0.31 to 0.32 s at 1.2M and from 0.096 to 0.086 s at 257k",
        lambda: _scale_3d_mpi()[1:3],
    ),
    (
        "scale.md",
        "so did λ_min's surface problem at both sizes (0.048 → 0.045 s and 0.18 → 0.22 s)",
        lambda: _scale_3d_mpi()[3:4],
    ),
    (
        "scale.md",
        "the parallel answers were within 1.6e-7 (257k) and 2.8e-7 (1.2M) of the serial ones",
        lambda: _scale_3d_mpi()[4:5],
    ),
    (
        "scale.md",
        "(the `tight` rows, 18–26 iterations) the gap fell to 3.2e-10 and 1.3e-10.",
        lambda: _scale_3d_mpi()[5:],
    ),
    (
        "scale.md",
        "On its run of 2026-12-04 07:51 UTC (`python benchmarks/scale_2d.py`), h = 1/512 (1.2M "
        "dofs, 1024 contact nodes) took 3 iterations and 1.18× the plain solve, and h = 1/64 to "
        "1/256 took 2 iterations and 1.14–1.46×",
        lambda: [*_scale_2d()[:2], *provenance("scale_2d", "scale 2d")],
    ),
    ("scale.md", "(at h = 1/512, 0.8 s and 2.1 s of the 18.4 s)", lambda: _scale_2d()[2:]),
    (
        "reproduction.md",
        "Table 5's r* is 36 % above the paper's (4.23e6 against 3.10e6)",
        lambda: _reproduction_example3()[:1],
    ),
    ("reproduction.md", "gives r* = 4.22575e+06", lambda: _reproduction_example3()[1:2]),
    (
        "reproduction.md",
        "ours is 6.6–8.0 % below the paper's on meshes of its sizes",
        lambda: _reproduction_example3()[2:3],
    ),
    (
        "reproduction.md",
        "29 (Table 6, level 0) against 37 (Table 5)",
        lambda: _reproduction_example3()[3:],
    ),
    (
        "reproduction.md",
        "our own fine-mesh r* = 1.4e7 needs 114 paper-mode iterations where the paper's "
        "coarse r* = 3.1e6 needs 36",
        lambda: _reproduction_fine_mesh()[:1],
    ),
    (
        "reproduction.md",
        "at the same r* and on the same mesh it needs 25 iterations",
        lambda: _reproduction_fine_mesh()[1:2],
    ),
    (
        "reproduction.md",
        "and the default, in the surface metric, 14 (the `158k` default row of [the 3D "
        "ladder](benchmarks/scale_3d.md): 157779 dofs and 2137 contact nodes, as level 3)",
        lambda: _reproduction_fine_mesh()[2:],
    ),
    (
        "reproduction.md",
        "Example 1 needs 19 iterations at r̄ and 34 at r* for h = 1/8 (paper: 19 and 35)",
        lambda: _reproduction_tables()[:1],
    ),
    ("reproduction.md", "(Table 3, m_c = 69: 99 against 43)", lambda: _reproduction_tables()[1:2]),
    (
        "reproduction.md",
        "with a spring of stiffness 2 our r* is 130 (paper: 137) and ADMM needs 70 iterations "
        "(paper: 59); with stiffness 0.1 it is 29 and needs 123",
        lambda: _reproduction_tables()[2:3],
    ),
    (
        "reproduction.md",
        "our counts (Table 4) are within 1.7× of the paper's on every mesh",
        lambda: _reproduction_tables()[3:],
    ),
]


#: (doc, words of the doc, source file, pattern whose group is the value, the value as
#: the doc writes it, or None for the group itself).
CONSTANTS: list[tuple[str, str, str, str, dict[str, str] | None]] = [
    (
        "penalty.md",
        "up to m = 500 (`penalty.dense.LAPACK_LIMIT`)",
        "src/admm_dolfinx/penalty/dense.py",
        r"^LAPACK_LIMIT = (\d+)$",
        None,
    ),
    (
        "testing.md",
        "(used above m = 500, `penalty.dense.LAPACK_LIMIT`)",
        "src/admm_dolfinx/penalty/dense.py",
        r"^LAPACK_LIMIT = (\d+)$",
        None,
    ),
    (
        "penalty.md",
        "2D with MUMPS and at most 4000 contact nodes",
        "src/admm_dolfinx/operators/condensed.py",
        r"^MAX_CONDENSED_CONTACT_NODES = (\d+)$",
        None,
    ),
    (
        "penalty.md",
        "(r_a = 1e-3 tr S_C / tr K_CC",
        "src/admm_dolfinx/penalty/dense.py",
        r"r_a = (\S+) \* float\(np\.trace\(schur\) / np\.trace\(k_cc\)\)",
        None,
    ),
    (
        "validation.md",
        "the default takes the dense form while m³ ≤ 300 n^{3/2}",
        "src/admm_dolfinx/operators/condensed.py",
        r"^DENSE_COST_RATIO = (\S+)$",
        {"300.0": "300"},
    ),
    (
        "acceleration.md",
        "(m³ ≤ 300 n^{3/2}, `condensed_factor_applies`)",
        "src/admm_dolfinx/operators/condensed.py",
        r"^DENSE_COST_RATIO = (\S+)$",
        {"300.0": "300"},
    ),
    (
        "validation.md",
        "once it needs 300 iterations or more",
        "src/admm_dolfinx/admm/messages.py",
        r"^SLOW_ITERATIONS = (\d+)$",
        None,
    ),
    (
        "acceleration.md",
        "A solve that needs 300 iterations or more says so",
        "src/admm_dolfinx/admm/messages.py",
        r"^SLOW_ITERATIONS = (\d+)$",
        None,
    ),
    (
        "scale.md",
        "`plan.FACTOR_FLOPS_LIMIT` = 10¹⁰ operations",
        "src/admm_dolfinx/admm/plan.py",
        r"^FACTOR_FLOPS_LIMIT = (\S+)$",
        {"1e10": "10¹⁰"},
    ),
    (
        "acceleration.md",
        "a held body takes multigrid from 10¹⁰",
        "src/admm_dolfinx/admm/plan.py",
        r"^FACTOR_FLOPS_LIMIT = (\S+)$",
        {"1e10": "10¹⁰"},
    ),
    (
        "scale.md",
        "τ_k = max(10⁻¹⁵, min(τ₀ k^{−3/2}, σ r_{k−1}))",
        "src/admm_dolfinx/admm/inexact.py",
        r"^TAU_FLOOR = (\S+)$",
        {"1e-15": "10⁻¹⁵"},
    ),
    (
        "scale.md",
        "τ_k = max(10⁻¹⁵, min(τ₀ k^{−3/2}, σ r_{k−1}))",
        "src/admm_dolfinx/admm/inexact.py",
        r"^DECAY = (\S+)$",
        {"1.5": "k^{−3/2}"},
    ),
    (
        "scale.md",
        "takes σ = 3·10⁻³ (`SIGMA_HELD`)",
        "src/admm_dolfinx/admm/inexact.py",
        r"^SIGMA_HELD = (\S+)$",
        {"3e-3": "3·10⁻³"},
    ),
    (
        "scale.md",
        "keeps σ = 3·10⁻⁴ (`SIGMA_FLOATING`)",
        "src/admm_dolfinx/admm/inexact.py",
        r"^SIGMA_FLOATING = (\S+)$",
        {"3e-4": "3·10⁻⁴"},
    ),
    (
        "scale.md",
        "`penalty.surface.SURFACE_PENALTY_TOL` = 0.1",
        "src/admm_dolfinx/penalty/surface.py",
        r"^SURFACE_PENALTY_TOL = (\S+)$",
        None,
    ),
    (
        "scale.md",
        "(`FLOPS_CONSTANT` = 14: their geometric mean",
        "src/admm_dolfinx/linalg/factor_prediction.py",
        r"^FLOPS_CONSTANT = (\S+)$",
        {"14.0": "= 14:"},
    ),
    (
        "scale.md",
        "(`MEMORY_CONSTANT` = 58)",
        "src/admm_dolfinx/linalg/factor_prediction.py",
        r"^MEMORY_CONSTANT = (\S+)$",
        {"58.0": "= 58)"},
    ),
    (
        "scale.md",
        "within a factor `PREDICTION_BAND` = 10 either way",
        "src/admm_dolfinx/linalg/factor_prediction.py",
        r"^PREDICTION_BAND = (\S+)$",
        {"10.0": "= 10 "},
    ),
    (
        "scale.md",
        "more than half the memory available (`plan.MEMORY_FRACTION`)",
        "src/admm_dolfinx/admm/plan.py",
        r"^MEMORY_FRACTION = (\S+)$",
        {"0.5": "half"},
    ),
    (
        "acceleration.md",
        "The constants b = ¼, m = 0.15 are",
        "src/admm_dolfinx/penalty/surface.py",
        r"^BETA_FRACTION = (\S+)$",
        {"0.25": "b = ¼"},
    ),
    (
        "acceleration.md",
        "The constants b = ¼, m = 0.15 are",
        "src/admm_dolfinx/penalty/surface.py",
        r"^MU_MIN_FRACTION = (\S+)$",
        None,
    ),
    (
        "method.md",
        '`mode="paper"` does exactly that, and its `rtol = 1e-5` reproduces',
        "src/admm_dolfinx/admm/settings.py",
        r"^PAPER_RTOL = (\S+)$",
        None,
    ),
    (
        "acceleration.md",
        "The defaults α = 1.6, memory 5 and polishing with up to 10 correction rounds",
        "src/admm_dolfinx/admm/settings.py",
        r'"accelerated": \{\s*"alpha": (\S+),',
        None,
    ),
    (
        "acceleration.md",
        "The defaults α = 1.6, memory 5 and polishing with up to 10 correction rounds",
        "src/admm_dolfinx/admm/settings.py",
        r'"accelerated": \{\s*"alpha": \S+,\s*"anderson": (\d+),',
        None,
    ),
    (
        "acceleration.md",
        "The defaults α = 1.6, memory 5 and polishing with up to 10 correction rounds",
        "src/admm_dolfinx/admm/settings.py",
        r"^    polish_rounds: int = (\d+)$",
        None,
    ),
    # the tolerances of tests that "What the tests compare with" quotes
    (
        "testing.md",
        "(κ_R < κ/2, μ_max a lower bound within 10 %, r 1.0–1.8 times the plain ADMM's best)",
        "tests/admm/test_surface_metric.py",
        r"assert mu\.max\(\) / mu\.min\(\) < lam\.max\(\) / lam\.min\(\) / (\d+)$",
        {"2": "κ_R < κ/2"},
    ),
    (
        "testing.md",
        "(κ_R < κ/2, μ_max a lower bound within 10 %, r 1.0–1.8 times the plain ADMM's best)",
        "tests/admm/test_surface_metric.py",
        r"assert (\S+) \* mu\.max\(\) <= info\.mu_max <= mu\.max\(\)",
        {"0.9": "within 10 %"},
    ),
    (
        "testing.md",
        "(κ_R < κ/2, μ_max a lower bound within 10 %, r 1.0–1.8 times the plain ADMM's best)",
        "tests/admm/test_surface_metric.py",
        r"assert (\S+ <= info\.r / r_plain <= \S+)$",
        {"1.0 <= info.r / r_plain <= 1.8": "r 1.0–1.8 times"},
    ),
    (
        "testing.md",
        "the dense method ≤ 1e-9; the iterative one ≤ 1e-6 at tight tolerance, ≤ 5 % at the "
        "default;",
        "tests/penalty/test_estimate.py",
        r"_compare\(loose, ev\[0\], ev\[-1\], (\S+)\)$",
        {"0.05": "≤ 5 % at the default"},
    ),
    (
        "testing.md",
        "active-set polishing against SNES VI on Example 1 (h = 1/16, 1/32: u to ≤ 1e-9, λ to "
        "≤ 1e-8, KKT ≤ 1e-10,",
        "tests/admm/test_polish.py",
        r"assert rel_diff\(_global\(problem, result\.u\.x\.array\), "
        r"_global\(problem, ref\.u\.x\.array\)\) <= (\S+)$",
        None,
    ),
    # the contact model a page's tables were measured in, as the chapters say it
    (
        "validation.md",
        "in the paper's contact model (along the body's normal, on every row",
        "benchmarks/hard_cases.py",
        r'^MODEL = "(\w+)"$',
        {"body": "the paper's contact model"},
    ),
    (
        "penalty.md",
        "in the paper's contact model and metric",
        "benchmarks/penalty_cost.py",
        r'^MODEL = "(\w+)"$',
        {"body": "the paper's contact model"},
    ),
    (
        "acceleration.md",
        "levels 0–2, in the paper's contact model (along the body's normal)",
        "benchmarks/surface_metric.py",
        r'^MODEL = "(\w+)"$',
        {"body": "the paper's contact model"},
    ),
    (
        "acceleration.md",
        "`python benchmarks/polish_3d.py --scene hertz_sphere` (5 min; the default contact "
        "model, along the obstacle's normal;",
        "benchmarks/polish_3d.py",
        r'"hertz_sphere": \(\s*\w+,\s*"(\w+)",',
        {"obstacle": "the default contact model"},
    ),
    (
        "acceleration.md",
        "solves Example 3, in the paper's contact model (along the body's normal), with",
        "benchmarks/polish_3d.py",
        r'"example3": \(\s*\w+,\s*"(\w+)",',
        {"body": "the paper's contact model"},
    ),
    (
        "reproduction.md",
        "in the paper's contact model (along the body's normal, `contact_normal=\"body\"`)",
        "src/admm_dolfinx/studies/reproduce.py",
        r'^PAPER_MODEL = "(\w+)"$',
        {"body": 'contact_normal="body"'},
    ),
    (
        "validation.md",
        "(The solves run at rtol 1e-9;",
        "benchmarks/hertz_validation.py",
        r"ADMMSolver\(problem, rtol=(\S+)\)",
        None,
    ),
]


def _quote_problems(doc, words, expected) -> list[str]:
    words = _flat(words)
    if words not in _doc(doc):
        return [f"docs/{doc} no longer says: {words}"]
    try:
        values = expected()
    except AssertionError as err:  # the page no longer has the row, or a bound fails
        return [f"docs/{doc} quotes a page that changed ({err}): {words}"]
    return [f"the page gives {v!r}; docs/{doc} says: {words}" for v in values if v not in words]


def _constant_problems(doc, words, source, pattern, written) -> list[str]:
    words = _flat(words)
    if words not in _doc(doc):
        return [f"docs/{doc} no longer says: {words}"]
    value = source_constant(source, pattern)
    shown = written.get(value, f"(the code now has {value})") if written else value
    return [] if shown in words else [f"{source} has {value}; docs/{doc} says: {words}"]


# One test per chapter (each reports every stale number of its chapter at once).
CHAPTERS = sorted({doc for doc, *_ in QUOTES} | {doc for doc, *_ in CONSTANTS})


@pytest.mark.parametrize("chapter", CHAPTERS)
def test_quoted_numbers_are_the_pages(chapter):
    problems = [p for q in QUOTES if q[0] == chapter for p in _quote_problems(*q)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("chapter", CHAPTERS)
def test_quoted_constants_are_the_codes(chapter):
    problems = [p for c in CONSTANTS if c[0] == chapter for p in _constant_problems(*c)]
    assert not problems, "\n".join(problems)


_INCLUDE = re.compile(r"```\{include\} (\S+)\n((?::[\w-]+: .*\n)*)```")


def _includes():
    found = []
    for doc in sorted(DOCS.glob("*.md")):
        for match in _INCLUDE.finditer(doc.read_text()):
            options = dict(re.findall(r":([\w-]+): \"(.*)\"", match.group(2)))
            found.append((doc.name, match.group(1), options))
    return found


def test_included_sections_exist():
    """Each ``{include}`` of a page names a section the page has (and ends where one does)."""
    includes = _includes()
    assert len(includes) >= 7
    for doc, target, options in includes:
        page = (DOCS / target).resolve()
        assert page.parent == PAGES.resolve(), f"{doc} includes {target}, not a benchmark page"
        text = page.read_text()
        start = options.get("start-after")
        assert start and start.startswith("## "), f"{doc}: include {target} without a section"
        assert f"\n{start}\n" in text, f"{target} has no section {start!r} ({doc})"
        if "end-before" in options:
            after = text.split(f"\n{start}\n", 1)[1]
            assert f"\n{options['end-before']}\n" in f"\n{after}", (doc, target, options)


def test_no_chapter_pastes_a_page_row():
    """A page's table is included, not copied: a pasted copy would not follow a rerun."""
    rows = set()
    for page in PAGES.glob("*.md"):
        lines = page.read_text().splitlines()
        for line, following in zip(lines, [*lines[1:], ""], strict=True):
            if line.startswith("| ") and not following.startswith("|---"):  # not a header
                rows.add(line.strip())
    for doc in sorted([*DOCS.glob("*.md"), ROOT / "README.md"]):
        pasted = [line for line in doc.read_text().splitlines() if line.strip() in rows]
        assert not pasted, f"{doc.name} pastes rows of a page, include them: {pasted[:2]}"
