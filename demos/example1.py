# # Example 1: an elastic rectangle pressed onto a rigid foundation
#
# This demo reproduces Example 1 of Koko (2019) end to end. It illustrates
#
# * building a scene (mesh from gmsh, tagged boundary, material, loads, obstacle),
# * turning it into a {py:class}`admm_dolfinx.ContactProblem`,
# * solving with {py:class}`admm_dolfinx.ADMMSolver` (one factorisation, many solves),
# * checking the answer through its KKT residuals, and
# * writing the displacement and contact pressure for ParaView, plus a JSON summary.
#
# The body is Ω = (0, 2) × (0, 1) in plane strain, E = 2000, ν = 0.3. It is clamped
# on the left side, pushed down by a traction of 10 on the top, and its bottom side
# Γ_C may touch a flat rigid foundation 0.01 below it:
#
#     u_n − g ≤ 0,   σ_n ≤ 0,   (u_n − g) σ_n = 0   on Γ_C.
#
# Run it with `python demos/example1.py` or `mpirun -n 2 python demos/example1.py`;
# `--help` lists the options. Output goes to `out_example1/`.

# +
from __future__ import annotations

import argparse
import logging

from mpi4py import MPI

import admm_dolfinx
from admm_dolfinx.output import atomic_directory, write_json, write_xdmf
from admm_dolfinx.scenes import example1

parser = argparse.ArgumentParser(description=__doc__ or "Example 1 of Koko (2019)")
parser.add_argument("--h", type=float, default=1 / 32, help="mesh size (default 1/32)")
parser.add_argument("--mesher", choices=["gmsh", "builtin"], default="gmsh")
parser.add_argument("--penalty", default="auto", help="penalty r, or 'auto' for r*")
parser.add_argument(
    "--rtol",
    type=float,
    default=admm_dolfinx.admm.DEFAULT_RTOL,
    help="relative-change tolerance (default %(default)g)",
)
parser.add_argument("--out", default="out_example1", help="output folder")
parser.add_argument("--verbose", action="store_true", help="log every ADMM iteration")
args = parser.parse_args()

comm = MPI.COMM_WORLD
logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")


def say(*text):
    if comm.rank == 0:
        print(*text, flush=True)


# -

# ## The scene
#
# {py:func}`admm_dolfinx.scenes.example1` declares only what the physics needs: the
# rectangle meshed by gmsh on rank 0 and distributed, its four sides tagged, the
# clamp, the traction and the analytic foundation `Plane((0, -0.01), (0, 1))`, whose
# normal points from the obstacle towards the body.

scene = example1(comm, h=args.h, mesher=args.mesher)
problem = scene.problem()
say(
    f"Example 1, h = {args.h:.4g}: {scene.num_nodes} nodes, "
    f"{problem.num_contact_nodes} contact nodes, {comm.size} process(es)"
)

# ## The solve
#
# Each ADMM iteration is one forward/backward substitution with the Cholesky factors
# of A + r NᵀMN, a node-wise projection and a multiplier update.

penalty = args.penalty if args.penalty == "auto" else float(args.penalty)
with admm_dolfinx.ADMMSolver(
    problem, penalty=penalty, rtol=args.rtol, petsc_options_prefix="example1_"
) as solver:
    result = solver.solve()
say(result.summary())

# ## Output
#
# The displacement and the contact pressure λ (a P1 function, zero off Γ_C) go to
# XDMF; the numbers go to `summary.json`. The folder appears only once complete.

with atomic_directory(comm, args.out) as folder:
    write_xdmf(folder / "solution.xdmf", [result.u, result.pressure])
    write_json(
        comm,
        folder / "summary.json",
        {
            "scene": "example1",
            "h": args.h,
            "nodes": scene.num_nodes,
            "contact_nodes": problem.num_contact_nodes,
            "processes": comm.size,
            "penalty": result.penalty,
            "iterations": result.iterations,
            "active_nodes": result.num_active,
            "kkt": result.kkt.as_dict(),
            "timings": result.timings,
            "max_pressure": result.extra["max_pressure"],
        },
    )
say(f"wrote {args.out}/solution.xdmf and {args.out}/summary.json")
problem.destroy()
