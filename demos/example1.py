# # Example 1: an elastic rectangle pressed onto a rigid foundation
#
# This demo reproduces Example 1 of Koko (2019) end to end. It illustrates
#
# * building a scene (gmsh mesh, tagged boundary, material, loads, rigid obstacle),
# * turning it into a {py:class}`admm_dolfinx.ContactProblem`,
# * solving with {py:class}`admm_dolfinx.ADMMSolver` at the automatic penalty r*
#   (one factorisation, many forward/backward substitutions),
# * judging the answer by its KKT residuals, and
# * writing the displacement and contact pressure for ParaView, the figures of the
#   paper (Figures 2 and 3) and a JSON summary.
#
# The body is Ω = (0, 2) × (0, 1) in plane strain, E = 2000, ν = 0.3. It is clamped
# on the left side, pushed down by a traction of 10 on the top, and its bottom side
# Γ_C may touch a flat rigid foundation at distance g = 0.01:
#
#     u_n − g ≤ 0,   σ_n ≤ 0,   (u_n − g) σ_n = 0   on Γ_C.
#
# Run it with `python demos/example1.py` or `mpirun -n 2 python demos/example1.py`;
# `--help` lists the options. Output goes to `out_example1/`.

# +
from __future__ import annotations

import argparse
import logging
import sys

from mpi4py import MPI

import admm_dolfinx
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.studies.report import write_scene_outputs
from admm_dolfinx.studies.sweep import paper_penalty_grid, sample_penalty

parser = argparse.ArgumentParser(description="Example 1 of Koko (2019)")
parser.add_argument("--h", type=float, default=1 / 32, help="mesh size (default 1/32)")
parser.add_argument("--mesher", choices=["gmsh", "builtin"], default="gmsh")
parser.add_argument("--penalty", default="auto", help="penalty r, or 'auto' for r*")
parser.add_argument(
    "--mode",
    choices=["accelerated", "paper"],
    default="accelerated",
    help="accelerated ADMM (default) or the paper's algorithm and stopping test",
)
parser.add_argument("--rtol", type=float, default=None, help="tolerance (default: the mode's)")
parser.add_argument(
    "--samples",
    type=int,
    default=200,
    help="penalties sampled in (0.1, 10)·E for Figure 2 (0: skip)",
)
parser.add_argument("--out", default="out_example1", help="output folder")
parser.add_argument("--verbose", action="store_true", help="log every ADMM iteration")
# In the book this runs in a Jupyter kernel, whose own arguments are not the demo's:
# there it samples 40 penalties instead of 200, to keep the build short.
args = parser.parse_args(["--samples", "40"] if "ipykernel" in sys.modules else None)

comm = MPI.COMM_WORLD
logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")


def say(*text):
    if comm.rank == 0:
        print(*text, flush=True)


# -

# ## The scene
#
# {py:func}`admm_dolfinx.scenes.library.example1` declares only what the physics needs: the
# rectangle meshed by gmsh on rank 0 and distributed, its four sides tagged, the
# clamp, the traction and the analytic foundation `Plane((0, -0.01), (0, 1))`, whose
# normal points from the obstacle towards the body. No obstacle mesh is needed.

scene = example1(comm, h=args.h, mesher=args.mesher)
problem = scene.problem()
say(
    f"Example 1, h = {args.h:.4g}: {scene.num_nodes} nodes, "
    f"{problem.num_contact_nodes} contact nodes, {comm.size} process(es)"
)

# ## The solve
#
# With `penalty="auto"` the solver computes r* = 1/sqrt(λ_min λ_max) from the extreme
# eigenvalues of the contact pencil. In 2D one MUMPS factorisation of A, condensed
# onto the contact dofs, gives the whole pencil densely (SLEPc's LAPACK solver) and
# serves every iteration at r* (in 3D: an iterative r*, then one factorisation of
# A + r*NᵀMN). Each ADMM iteration is one solve with those factors, a node-wise
# projection p = min(Nu + λ/r, g) and a multiplier update λ = max(λ + r(Nu − g), 0),
# accelerated by over-relaxation and Anderson mixing. In 2D, active-set polishing
# then ends the solve: once the nodes with λ > 0 are (nearly) the contact set, the
# dense contact problem for that set gives the exact solution (the summary says at
# which iteration). `--mode paper` runs the paper's Algorithm 2 instead.

penalty = args.penalty if args.penalty == "auto" else float(args.penalty)
with admm_dolfinx.ADMMSolver(
    problem, penalty=penalty, mode=args.mode, rtol=args.rtol, petsc_options_prefix="example1_"
) as solver:
    result = solver.solve()
say(result.summary())

# ## Iterations against r (the paper's Figure 2)
#
# The sampled optimum r̄ is the penalty with the fewest iterations over the paper's
# grid of 200 points in (0.1, 10)·E. The sweep reuses one factorisation (in 2D the
# condensed one: a new r costs a dense m × m factorisation) and does not polish, so
# its counts are those of the ADMM iteration itself.

sweep = None
if args.samples > 0:
    sweep = sample_penalty(
        problem, paper_penalty_grid(scene.info["E"], args.samples), mode=args.mode, rtol=args.rtol
    )
    say(
        f"sampled r̄ = {sweep.r_best:.6g} needs {sweep.iterations_best} iterations "
        f"({args.samples} samples in {sweep.time:.2f} s); r = {result.penalty:.6g} needs "
        f"{result.iterations}{' (polished)' if result.polished else ''}"
    )

# ## Output
#
# The displacement and the contact pressure λ (a P1 function, zero off Γ_C) go to
# XDMF; the figures and the numbers go beside it. The folder appears only once
# complete.

write_scene_outputs(args.out, scene, problem, result, sweep=sweep)
say(
    f"wrote {args.out}/: solution.xdmf, deformed_von_mises.png, normal_stress.png, "
    f"{'iterations_vs_r.png, ' if sweep else ''}summary.json"
)
problem.destroy()
