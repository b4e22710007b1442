"""A factorisation's cost from the mesh alone: the model of nested dissection against MUMPS.

The step-1 plan of a 3D body (``admm_dolfinx.admm.plan``) decides between a MUMPS
factorisation and multigrid by what the factorisation would cost. It first brackets
that cost from the mesh (``admm_dolfinx.linalg.factor_prediction``: nested dissection
on a box of the body's proportions and volume, C Σ_k 2^k s_k³ operations and
C_m Σ_k 2^k s_k² bytes, each within a factor ``PREDICTION_BAND`` either way) and runs
MUMPS's analysis only where the two ends of the bracket lead to different choices.
This script measures the model against MUMPS's own figures (its sequential analysis,
the one a serial plan runs) on

* the package's 3D scenes: Example 3's block at levels 1 and 2, the sizes of the 3D
  ladder (``benchmarks/scale_3d.py``), hexahedra, the Hertz sphere (a quarter-ball)
  at levels 0 to 3, a slab (``pressed_block``, half-depth 0.1), the flat punch and
  the 3D pressed ball;
* boxes of other shapes, linear elasticity on DOLFINx's built-in meshes: cubes,
  bars, a slab and a plate of tetrahedra, degree 2, and hexahedra.

The constants were fitted to all of these (their geometric means), so the boxes are
not held out; the last rows give the means of each set alone.

Columns: the dofs; ``Σ 2^k s³`` the model's operations before their constant;
MUMPS's count and ``MUMPS / Σ s³`` (the constant each mesh asks for); whether MUMPS's
count lies in the bracket; MUMPS's memory, ``MUMPS bytes / Σ s²`` and whether it lies
in the memory bracket; the seconds of MUMPS's analysis and of the model (the mesh's
bounds and volume and the count); ``flops vs limit`` where the flops bracket lies
against ``FACTOR_FLOPS_LIMIT`` (below, above, or straddling it: for a held body whose
memory fits, a factorisation, multigrid, or MUMPS's analysis decides). For the
scenes, ``plan`` is the default plan's step 1 and what chose between a factorisation
and multigrid (``solver.plan.step1_basis``), and ``plan s`` the time of making the
plan (all of it, the rules of r* and polishing included).

    python benchmarks/factor_prediction.py            # all cases (about 5 min)
    python benchmarks/factor_prediction.py --quick    # three small meshes (smoke test)
    python benchmarks/factor_prediction.py --only "158k,cube tet 30"

Writes out_benchmarks/factor_prediction.csv.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI
from scale_3d import LADDER as SCALE_LADDER
from surface_metric import block_variant
from tables import print_and_save, select
from timing import timed

import admm_dolfinx
from admm_dolfinx.admm.plan import FACTOR_FLOPS_LIMIT, make_plan
from admm_dolfinx.linalg.factor_estimate import mumps_estimate
from admm_dolfinx.linalg.factor_prediction import (
    FLOPS_CONSTANT,
    MEMORY_CONSTANT,
    PREDICTION_BAND,
    mesh_volume,
    predict_factorisation,
)
from admm_dolfinx.problem.contact_set import mesh_bounds
from admm_dolfinx.scenes import example3, example3_hexahedral, hertz_sphere, pressed_ball
from admm_dolfinx.scenes.library import flat_punch

#: the sizes of the 3D ladder measured here (benchmarks/scale_3d.py; 2.2M left out)
LADDER = {name: SCALE_LADDER[name] for name in ("158k", "257k", "530k", "1.2M", "graded 350k")}


def _ladder(name):
    level, h_bottom, h_top = LADDER[name]
    return lambda: example3(level=level, h_bottom=h_bottom, h_top=h_top)


#: name: a scene
SCENES = {
    "example 3 level 1": lambda: example3(level=1),
    "example 3 level 2": lambda: example3(level=2),
    **{name: _ladder(name) for name in LADDER},
    "hex 16": lambda: example3_hexahedral(cells=16),
    "hex 32": lambda: example3_hexahedral(cells=32),
    **{f"hertz sphere {k}": (lambda k=k: hertz_sphere(level=k)) for k in range(4)},
    "slab level 2": lambda: block_variant("slab", 2),
    "slab level 3": lambda: block_variant("slab", 3),
    "flat punch": lambda: flat_punch(cells=8),
    "pressed ball 3D": lambda: pressed_ball(gdim=3, h=0.05),
}
#: name: (box sides, cells per side, degree, cell type)
BOXES = {
    "cube tet 30": ((1, 1, 1), (30, 30, 30), 1, "tetrahedron"),
    "cube tet 45": ((1, 1, 1), (45, 45, 45), 1, "tetrahedron"),
    "bar tet 6x6x150": ((1, 1, 25), (6, 6, 150), 1, "tetrahedron"),
    "bar tet 10x10x100": ((1, 1, 10), (10, 10, 100), 1, "tetrahedron"),
    "slab tet 60x60x5": ((12, 12, 1), (60, 60, 5), 1, "tetrahedron"),
    "plate tet 80x80x2": ((40, 40, 1), (80, 80, 2), 1, "tetrahedron"),
    "cube P2 15": ((1, 1, 1), (15, 15, 15), 2, "tetrahedron"),
    "bar P2 5x5x60": ((1, 1, 12), (5, 5, 60), 2, "tetrahedron"),
    "cube hex 30": ((1, 1, 1), (30, 30, 30), 1, "hexahedron"),
}
QUICK = ("example 3 level 1", "hertz sphere 0", "cube tet 8")
SMALL_BOXES = {"cube tet 8": ((1, 1, 1), (8, 8, 8), 1, "tetrahedron")}


def box_matrix(sides, cells, degree, cell_type):
    """(mesh, A) of linear elasticity on a box (no boundary conditions: the pattern)."""
    import ufl
    from dolfinx import fem, mesh
    from dolfinx.fem import petsc as fem_petsc

    msh = mesh.create_box(
        MPI.COMM_WORLD,
        [np.zeros(3), np.array(sides, dtype=float)],
        list(cells),
        getattr(mesh.CellType, cell_type),
    )
    V = fem.functionspace(msh, ("Lagrange", degree, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    eps = ufl.sym(ufl.grad(u))
    a = fem.form(ufl.inner(2.0 * eps + ufl.tr(eps) * ufl.Identity(3), ufl.grad(v)) * ufl.dx)
    A = fem_petsc.assemble_matrix(a)
    A.assemble()
    return msh, A


def measure(name: str, kind: str, msh, A, problem=None) -> dict:
    n = A.getSize()[0]

    def model():
        sides = np.diff(mesh_bounds(msh), axis=0)[0]
        return predict_factorisation(sides, mesh_volume(msh), n, processes=msh.comm.size)

    model_s, bracket = timed(model)
    operations = bracket.model_flops / FLOPS_CONSTANT
    entries = bracket.memory[0] * PREDICTION_BAND / MEMORY_CONSTANT
    analysis_s, estimate = timed(lambda: mumps_estimate(A, prefix="prediction_"))
    if bracket.flops[1] <= FACTOR_FLOPS_LIMIT:
        side = "below"
    elif bracket.flops[0] > FACTOR_FLOPS_LIMIT:
        side = "above"
    else:
        side = "straddles"
    row = {
        "case": name,
        "kind": kind,
        "dofs": n,
        "Σ 2^k s³": f"{operations:.3g}",
        "MUMPS flops": f"{estimate.flops:.3g}",
        "MUMPS / Σ s³": f"{estimate.flops / operations:.3g}",
        "flops in bracket": bracket.flops[0] <= estimate.flops <= bracket.flops[1],
        "MUMPS GB": f"{estimate.memory / 1e9:.3g}",
        "MUMPS bytes / Σ s²": f"{estimate.memory / entries:.3g}",
        "memory in bracket": bracket.memory[0] <= estimate.memory <= bracket.memory[1],
        "analysis s": f"{analysis_s:.3g}",
        "model s": f"{model_s:.2g}",
        "flops vs limit": side,
        "_ratios": (estimate.flops / operations, estimate.memory / entries),
    }
    if problem is not None:
        settings = admm_dolfinx.ADMMSettings.create()
        plan_s, plan = timed(lambda: make_plan(problem, settings))
        row["plan"] = f"{plan.step1} ({plan.step1_basis})"
        row["plan s"] = f"{plan_s:.3g}"
    return row


def _summary(rows: list[dict], label: str) -> dict:
    """The geometric mean and range of the two ratios over these rows."""
    ratios = np.array([row["_ratios"] for row in rows])
    mean = np.exp(np.log(ratios).mean(axis=0))
    low, high = ratios.min(axis=0), ratios.max(axis=0)
    return {
        "case": f"geometric mean (range): {label}",
        "MUMPS / Σ s³": f"{mean[0]:.3g} ({low[0]:.3g} to {high[0]:.3g})",
        "MUMPS bytes / Σ s²": f"{mean[1]:.3g} ({low[1]:.3g} to {high[1]:.3g})",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="three small meshes")
    parser.add_argument("--only", help="comma-separated case names")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    boxes = {**BOXES, **SMALL_BOXES}
    names = QUICK if args.quick else [*SCENES, *BOXES]
    cases = select(parser, dict.fromkeys(names), args.only)
    root = MPI.COMM_WORLD.rank == 0
    if root:
        Path(args.out).mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    for name in cases:
        if name in boxes:
            msh, A = box_matrix(*boxes[name])
            rows.append(measure(name, "box", msh, A))
            A.destroy()
        else:
            problem = SCENES[name]().problem()
            rows.append(measure(name, "scene", problem.mesh, problem.A, problem))
        summaries = [_summary(rows, "all")]
        for kind in ("scene", "box"):
            if 0 < sum(row["kind"] == kind for row in rows) < len(rows):
                summaries.append(_summary([r for r in rows if r["kind"] == kind], kind))
        summaries[0]["flops in bracket"] = (
            f"FLOPS_CONSTANT {FLOPS_CONSTANT:g}, MEMORY_CONSTANT {MEMORY_CONSTANT:g}, "
            f"band {PREDICTION_BAND:g}"
        )
        shown = [{k: v for k, v in row.items() if not k.startswith("_")} for row in rows]
        if root:
            print_and_save([*shown, *summaries], Path(args.out) / "factor_prediction.csv")


if __name__ == "__main__":
    main()
