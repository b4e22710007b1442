# # Load steps: a block pressed further and further onto a rigid cylinder
#
# Contact problems are often solved for a sequence of loads: a ramp of prescribed
# displacements, an increasing force, an obstacle that moves. This demo shows how
# to do that with your own DOLFINx mesh and UFL forms, and what it costs.
#
# The stiffness A and the normal mass NᵀMN do not depend on the load, the Dirichlet
# values or the position of the obstacle, so neither do the penalty r* nor the
# factorisation of A + r*NᵀMN. After the first step a load step is therefore
# ADMM iterations only:
#
# * change the data (here the value of a `fem.Constant` that holds the prescribed
#   displacement of the top),
# * call `problem.update_load()` (or `problem.update_obstacle(...)` for a moved
#   obstacle), and
# * solve again, warm-started from the previous step.
#
# The body is the block (−1, 1) × (0, 1), E = 2000, ν = 0.3, plane strain. Its top
# is moved down by d and its bottom Γ_C meets a rigid cylinder (a disc in 2D) of
# radius 2 that touches the bottom at x = 0: the contact zone grows with d. Each
# step is also solved from scratch (new problem, new r*, new factorisation), to
# show what the reuse saves, measured side by side.
#
# Run `python demos/load_steps.py` or under `mpirun -n 2`. Output:
# `out_load_steps/` (a JSON table of the steps and a plot of the contact pressure).

# +
from __future__ import annotations

import argparse
import sys
import time

import admm_dolfinx  # first: it loads the MPI and PETSc that DOLFINx was built with

# isort: split
import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx.io.output import output_folder, write_json
from admm_dolfinx.io.plotting import plot_contact_pressure

parser = argparse.ArgumentParser(description="Load steps: a block pressed onto a cylinder")
parser.add_argument("--n", type=int, default=64, help="cells along the bottom (default 64)")
parser.add_argument("--steps", type=int, default=6, help="load steps (default 6)")
parser.add_argument("--depth", type=float, default=0.04, help="final top displacement")
parser.add_argument("--out", default="out_load_steps", help="output folder")
# In the book this runs in a Jupyter kernel, whose own arguments are not the demo's.
args = parser.parse_args([] if "ipykernel" in sys.modules else None)

comm = MPI.COMM_WORLD


def say(*text):
    if comm.rank == 0:
        print(*text, flush=True)


# -

# ## The mesh, the forms and the obstacle: plain DOLFINx

msh = mesh.create_rectangle(comm, [[-1.0, 0.0], [1.0, 1.0]], [args.n, args.n // 2])
TOP, BOTTOM = 1, 2
top_facets = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 1.0))
bottom_facets = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0.0))
facets = np.concatenate([top_facets, bottom_facets])
values = np.concatenate([np.full(top_facets.size, TOP), np.full(bottom_facets.size, BOTTOM)])
order = np.argsort(facets)
tags = mesh.meshtags(msh, 1, facets[order], values[order].astype(np.int32))

V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
E, nu = 2000.0, 0.3
mu, lmbda = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
eps = ufl.sym(ufl.grad(u))
a = ufl.inner(2 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(2), ufl.sym(ufl.grad(v))) * ufl.dx
L = ufl.dot(fem.Constant(msh, (0.0, 0.0)), v) * ufl.dx  # no body force
top_dofs = fem.locate_dofs_topological(V, 1, tags.find(TOP))
cylinder = admm_dolfinx.Ball(center=(0.0, -2.0), radius=2.0)


def contact_problem(depth: float):
    """The problem with the top moved down by ``depth``, and the Constant holding it."""
    top_motion = fem.Constant(msh, (0.0, -depth))
    bcs = [fem.dirichletbc(top_motion, top_dofs, V)]
    return admm_dolfinx.ContactProblem(a, L, bcs, tags, BOTTOM, cylinder), top_motion


# ## The steps
#
# One problem and one solver for all the steps; the first solve computes r* and the
# factorisation. Every step is compared with a solve from scratch.

depths = np.linspace(args.depth / args.steps, args.depth, args.steps)
problem, top_motion = contact_problem(0.0)
t0 = time.perf_counter()
solver = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix="steps_")  # r*, factorisation
t_setup = time.perf_counter() - t0
rows, pressures, previous = [], [], None
for step, depth in enumerate(depths, start=1):
    t0 = time.perf_counter()
    top_motion.value[:] = (0.0, -depth)
    problem.update_load()
    result = solver.solve(warm_start=previous)
    t_step = time.perf_counter() - t0

    t0 = time.perf_counter()
    fresh_problem, _ = contact_problem(depth)
    with admm_dolfinx.ADMMSolver(fresh_problem, petsc_options_prefix="fresh_") as fresh:
        reference = fresh.solve()
    t_fresh = time.perf_counter() - t0
    difference = result.u.x.petsc_vec.copy()
    difference.axpy(-1.0, reference.u.x.petsc_vec)
    error = difference.norm() / reference.u.x.petsc_vec.norm()
    difference.destroy()
    fresh_problem.destroy()

    in_contact = problem.contact.coordinates[result.multiplier > 0.0, 0]
    half_width = comm.allreduce(float(np.max(np.abs(in_contact), initial=0.0)), op=MPI.MAX)
    rows.append(
        {
            "step": step,
            "depth": float(depth),
            "active": result.num_active,
            "half_width": half_width,
            "max_pressure": result.max_pressure,
            "iterations": result.iterations,
            "time": t_step,
            "fresh_iterations": reference.iterations,
            "fresh_time": t_fresh,
            "difference_to_fresh": error,
        }
    )
    pressures.append((f"d = {depth:.4g}", result.multiplier.copy()))
    previous = result

say(f"{comm.size} process(es), {problem.num_contact_nodes} contact nodes")
say(f"set-up once: r* = {solver.penalty:.5g} and the factorisation, {t_setup:.3f} s")
say("step   depth  active  half-width  max pressure  its  time [s] | from scratch: its  time [s]")
for row in rows:
    say(
        f"{row['step']:4d}  {row['depth']:.4f}  {row['active']:6d}  {row['half_width']:10.4f}"
        f"  {row['max_pressure']:12.5g}  {row['iterations']:3d}  {row['time']:8.3f} |"
        f"  {row['fresh_iterations']:16d}  {row['fresh_time']:8.3f}"
    )
ratio = (t_setup + sum(r["time"] for r in rows)) / sum(r["fresh_time"] for r in rows)
worst = max(r["difference_to_fresh"] for r in rows)
say(
    f"{len(rows)} steps, set-up included: {ratio:.2f} of the time of solving each from "
    f"scratch; |u - u_scratch| / |u| <= {worst:.1e} (both stop at rtol 1e-6)"
)

# ## Output: only these files, each written whole or not at all

with output_folder(comm, args.out) as folder:
    summary = {"r": solver.penalty, "setup_time": t_setup, "steps": rows}
    write_json(comm, folder / "steps.json", summary)
    plot_contact_pressure(
        problem, pressures, folder / "pressure.png", title="contact pressure per load step"
    )
say(f"wrote {args.out}/")
solver.destroy()
problem.destroy()
