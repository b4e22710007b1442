"""The inner tolerance of an iterative step 1: σ of the inexact rule, held against floating.

The multigrid step 1 solves iteration k's system to the relative residual
τ_k = max(τ_floor, min(τ_0 k^{−3/2}, σ r_{k−1})) (``admm_dolfinx.admm.inexact``). The
plan takes σ = ``SIGMA_HELD`` for a body held by its Dirichlet conditions and
σ = ``SIGMA_FLOATING`` for one that the contact alone holds. This script measures both
sides of that rule, each case in one run, one solve after the other on the same
assembled problem:

* held bodies (Example 3's block on the half-ball, the paper's contact model, the
  surface metric), the sizes ``158k`` and ``graded 350k`` of the 3D ladder
  (``benchmarks/scale_3d.py``) and a held-out kind, hexahedra (``hex 212k``);
* a floating body, the Hertz sphere (the obstacle's normal, held by the contact alone)
  at levels 2 and 3, unpolished (the path of a floating body past the polishing
  limits).

For each, ``step1="iterative"`` at σ = 3e-4, 1e-3, 3e-3 and 1e-2 (``expert={"inner_sigma":
σ}``; the row ``rule`` marks the plan's own choice), CG stopping on the unpreconditioned
relative residual ‖b − Ax‖/‖b‖ (``norm``: the package's default,
``admm_dolfinx.linalg.petsc.CG_RESIDUAL_NORM``); then the rule before that default,
PETSc's preconditioned residual ‖B(b − Ax)‖/‖Bb‖ with σ = 1e-2 (held) or 1e-3
(floating) (``rule before``), whose test spends a multigrid cycle per solve on ‖Bb‖
and another on the last residual; and a plain elastic solve of the same
matrix, CG + GAMG with the rigid-body modes to ``ksp_rtol`` 1e-8 (held bodies; the
floating sphere's A is singular). Columns: ADMM iterations, Krylov iterations of step
1, whether the KKT check tightened the tolerances, seconds of step-1 solves and of the
whole solve (from the solver's construction: the plan, r*, the multigrid set-up and the
iterations; assembly excluded, for the plain solve likewise), ``/plain`` the whole
solve over the plain one, the largest recomputed KKT residual, and ``vs first`` the
relative difference of the displacement from the σ = 3e-4 solve's (both meet the KKT
tolerance 1e-6, so they differ by up to that much).

    python benchmarks/inner_tolerance.py            # all five cases (about 15 min)
    python benchmarks/inner_tolerance.py --quick    # two small meshes (smoke test)
    python benchmarks/inner_tolerance.py --only "graded 350k"

Writes out_benchmarks/inner_tolerance.csv.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc
from scale_3d import LADDER, MODEL
from tables import print_and_save, select
from timing import timed

import admm_dolfinx
from admm_dolfinx.admm.inexact import SIGMA_FLOATING, SIGMA_HELD
from admm_dolfinx.admm.plan import make_plan
from admm_dolfinx.linalg.petsc import CG_RESIDUAL_NORM, ITERATIVE_OPTIONS, apply_options
from admm_dolfinx.scenes import example3, example3_hexahedral, hertz_sphere

NORM = CG_RESIDUAL_NORM["ksp_norm_type"]
SIGMAS = (SIGMA_FLOATING, 1e-3, SIGMA_HELD, 1e-2)
#: The rule's σ before CG_RESIDUAL_NORM, in PETSc's preconditioned norm.
BEFORE = {"held": 1e-2, "floating": 1e-3}
#: A stalled solve stops here (it is reported, not waited for).
MAX_ITER = 600


def _block(name):
    level, h_bottom, h_top = LADDER[name]
    return lambda: example3(level=level, h_bottom=h_bottom, h_top=h_top).problem(
        contact_normal=MODEL
    )


#: name: (how the body is held, the problem)
CASES = {
    "158k": ("held", _block("158k")),
    "graded 350k": ("held", _block("graded 350k")),
    "hex 212k": ("held", lambda: example3_hexahedral(cells=32).problem(contact_normal=MODEL)),
    "hertz sphere level 2": ("floating", lambda: hertz_sphere(level=2).problem()),
    "hertz sphere level 3": ("floating", lambda: hertz_sphere(level=3).problem()),
}
QUICK = {
    "20k": ("held", lambda: example3(level=2).problem(contact_normal=MODEL)),
    "hertz sphere level 0": ("floating", lambda: hertz_sphere(level=0).problem()),
}


def warm_up() -> None:
    """Compile every form once (small meshes of each kind), untimed: the first solve in
    a process would otherwise carry the compilation."""
    problems = (
        example3(level=0).problem(contact_normal=MODEL),
        example3_hexahedral(cells=4).problem(contact_normal=MODEL),
        hertz_sphere(level=0).problem(),
    )
    for problem in problems:
        with warnings.catch_warnings():  # the coarse meshes' under-resolution
            warnings.simplefilter("ignore")
            with admm_dolfinx.ADMMSolver(problem, step1="iterative", polish=False) as solver:
                solver.solve()
        if not problem.rigid_motions.floating:
            plain_solve(problem)


def plain_solve(problem) -> float:
    """Seconds of one elastic solve A u = f: GAMG set-up and CG to 1e-8."""
    b = problem.create_vector()
    problem.assemble_rhs(0.0, b)
    x = b.duplicate()
    ksp = PETSc.KSP().create(problem.comm)

    def solve():
        ksp.setOperators(problem.A)  # carries the rigid-body near null space
        apply_options(ksp, "plain_", {**ITERATIVE_OPTIONS, "ksp_rtol": 1e-8}, setup=True)
        ksp.solve(b, x)

    seconds, _ = timed(solve)
    for obj in (ksp, x, b):
        obj.destroy()
    return seconds


def contact_solve(problem, sigma, norm):
    """(seconds, result, step-1 solve seconds, the plan's σ, the solver) at σ and CG's norm."""
    expert = {"inner_sigma": sigma}
    holder = {}

    def solve():
        solver = admm_dolfinx.ADMMSolver(
            problem,
            step1="iterative",
            polish=False,
            max_iter=MAX_ITER,
            petsc_options={"ksp_norm_type": norm},
            expert=expert,
        )
        holder["solver"] = solver
        try:
            return solver.solve()
        except admm_dolfinx.ADMMConvergenceError as error:  # a stall: reported
            return error.result

    seconds, result = timed(solve)
    solver = holder["solver"]
    step1_seconds = MPI.COMM_WORLD.allreduce(solver.operator.solve_time, op=MPI.MAX)
    chosen = solver.plan.inner_sigma
    return seconds, result, step1_seconds, chosen, solver


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two small meshes")
    parser.add_argument("--only", help="comma-separated case names")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    cases = select(parser, QUICK if args.quick else CASES, args.only)
    comm = MPI.COMM_WORLD
    root = comm.rank == 0
    if root:
        Path(args.out).mkdir(parents=True, exist_ok=True)
    warm_up()
    rows: list[dict] = []
    for name, (held, build) in cases.items():
        problem = build()
        dofs = problem.V.dofmap.index_map.size_global * 3
        plain = plain_solve(problem) if held == "held" else None
        reference = None
        # what the plan chooses on its own
        settings = admm_dolfinx.ADMMSettings.create(step1="iterative", polish=False)
        rule_sigma = make_plan(problem, settings).inner_sigma
        configs = [(sigma, NORM) for sigma in SIGMAS] + [(BEFORE[held], "preconditioned")]
        for sigma, norm in configs:
            seconds, result, step1_seconds, chosen, solver = contact_solve(problem, sigma, norm)
            label = f"{sigma:g}"
            if norm != NORM:
                label += " (rule before)"
            elif sigma == rule_sigma:
                label += " (rule)"
            u = result.u.x.petsc_vec
            if reference is None:
                reference = u.copy()
                difference = "–"
            else:
                difference = f"{(u - reference).norm() / reference.norm():.1e}"
            rows.append(
                {
                    "case": name,
                    "body": held,
                    "dofs": dofs,
                    "contact nodes": problem.contact.num_global,
                    "σ": label,
                    "norm": norm,
                    "converged": result.converged,
                    "iterations": result.iterations,
                    "Krylov its": result.step1.krylov_iterations,
                    "tightened": result.step1.tightened,
                    "step-1 solves s": f"{step1_seconds:.3g}",
                    "solve s": f"{seconds:.3g}",
                    "/plain": "–" if plain is None else f"{seconds / plain:.2f}",
                    "kkt": f"{result.kkt.max():.1e}",
                    "vs first": difference,
                }
            )
            assert chosen == sigma
            solver.destroy()
            if root:
                print_and_save(rows, Path(args.out) / "inner_tolerance.csv")
        if plain is not None:
            rows.append({"case": name, "body": held, "dofs": dofs, "σ": "plain CG+GAMG"})
            rows[-1]["solve s"] = f"{plain:.3g}"
        reference.destroy()
        if root:
            print_and_save(rows, Path(args.out) / "inner_tolerance.csv")


if __name__ == "__main__":
    main()
