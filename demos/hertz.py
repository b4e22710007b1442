# # Example 2: the Hertz problem, a cylinder resting on a rigid foundation
#
# This demo reproduces Example 2 of Koko (2019). It illustrates contact on a *curved*
# boundary (the nodal normals are not axis-aligned) and a *floating* body: nothing
# but the foundation stops the quarter cylinder from moving vertically, so the
# stiffness A is singular. Neither needs any action from the user: A + rNᵀMN is
# invertible, and the automatic penalty detects the rigid motion seen by Γ_C and
# leaves it out of r*.
#
# Geometry (a consistent reading of the paper): a cylinder of radius R = 8, E = 2000,
# ν = 0.3, touching the plane y = 0 at the origin. By symmetry the quarter
# 0 ≤ x ≤ R, 0 ≤ y ≤ R of the disc centred at (0, R) is modelled: u_x = 0 on the
# symmetry line x = 0, a downward traction of total force 1600 on the top side y = R,
# and Γ_C the quarter arc.
#
# Run `python demos/hertz.py --level 1` or under `mpirun -n 2`. Output: `out_hertz/`.

# +
from __future__ import annotations

import argparse
import logging
import sys

from mpi4py import MPI

import admm_dolfinx
from admm_dolfinx.scenes.library import example2
from admm_dolfinx.studies.report import write_scene_outputs
from admm_dolfinx.studies.sweep import paper_penalty_grid, sample_penalty

parser = argparse.ArgumentParser(description="Example 2 (Hertz) of Koko (2019)")
parser.add_argument(
    "--level", type=int, default=1, help="mesh level: 0, 1, 2, ... ≈ 35, 69, 137, ... contact nodes"
)
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
    help="penalties sampled in (0.1, 10)·E for Figure 5 (0: skip)",
)
parser.add_argument("--out", default="out_hertz", help="output folder")
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

# ## Scene and problem

scene = example2(comm, level=args.level)
problem = scene.problem()
say(
    f"Hertz, level {args.level}: {scene.num_nodes} nodes, "
    f"{problem.num_contact_nodes} contact nodes, {comm.size} process(es)"
)

# ## Solve
#
# The summary reports how many rigid motions the penalty estimate deflated (one: the
# vertical translation).

penalty = args.penalty if args.penalty == "auto" else float(args.penalty)
with admm_dolfinx.ADMMSolver(
    problem, penalty=penalty, mode=args.mode, rtol=args.rtol, petsc_options_prefix="hertz_"
) as solver:
    result = solver.solve()
say(result.summary())
if solver.penalty_estimate is not None:
    say(f"rigid motions deflated from r*: {solver.penalty_estimate.details['rigid_modes']}")

# ## Iterations against r (the paper's Figure 5)

sweep = None
if args.samples > 0:
    sweep = sample_penalty(
        problem, paper_penalty_grid(scene.info["E"], args.samples), mode=args.mode, rtol=args.rtol
    )
    say(
        f"sampled r̄ = {sweep.r_best:.6g} needs {sweep.iterations_best} iterations; "
        f"r = {result.penalty:.6g} needs {result.iterations}"
        f"{' (polished)' if result.polished else ''}"
    )

# ## Output: the deformed configuration (Fig. 6) and the normal stress (Fig. 7)
#
# The normal stress is plotted against the angle from the lowest point of the arc.

write_scene_outputs(args.out, scene, problem, result, sweep=sweep, coordinate="angle")
say(f"wrote {args.out}/")
problem.destroy()
