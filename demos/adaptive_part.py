# # Accuracy on request: a part pressed onto a ball, refined to 1 %
#
# A part's mesh is usually made for its shape, not for the few square millimetres
# where it touches something. There the pressure peaks, and a coarse mesh gets the
# peak wrong without the solve failing: it converges, on the wrong mesh. This demo
# hands the question "how fine must the mesh be there?" to
# {py:func}`admm_dolfinx.solve_adaptive`: it solves, estimates the error of the peak
# pressure, refines where the estimator points (the contact zone first) and stops
# when the estimate is below the target. It illustrates
#
# * a `build(mesh, facet_tags)` function that rebuilds the user's own problem (forms,
#   material, Dirichlet conditions, obstacle) on every refined mesh,
# * the warning a plain solve on the coarse mesh gives (its contact zone spans too
#   few nodes to trust the peak pressure),
# * the history of the levels: dofs, estimate, iterations and CPU seconds,
# * the answer checked against Hertz's estimate for the computed force.
#
# The part is a block 1 × 1 × 0.5 meshed coarsely (h = 0.25) by gmsh; its top is
# pushed down by 0.002 onto a rigid ball of radius 2 that touches the middle of its
# bottom face.
#
# Run `python demos/adaptive_part.py` or `mpirun -n 2 python demos/adaptive_part.py`.
# Output: the table of the levels in `out_adaptive_part/levels.txt`.

# +
from __future__ import annotations

# isort: off
import admm_dolfinx  # first: it loads the PyPI wheel's MPI and PETSc before dolfinx does

# isort: on
import argparse
import sys
from pathlib import Path

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

from admm_dolfinx.io.output import output_folder
from admm_dolfinx.scenes.material import LinearElastic

parser = argparse.ArgumentParser(description="A part refined to a target error")
parser.add_argument("--h", type=float, default=0.25, help="the first mesh's size")
parser.add_argument("--target", type=float, default=0.01, help="relative error of p_max")
parser.add_argument("--out", default="out_adaptive_part", help="output folder")
# In the book this runs in a Jupyter kernel, whose own arguments are not the demo's.
args = parser.parse_args([] if "ipykernel" in sys.modules else None)
comm = MPI.COMM_WORLD


def say(*text):
    if comm.rank == 0:
        print(*text, flush=True)


# -

# ## The part and its first mesh
#
# gmsh builds the block and tags its faces: 1 the bottom (the contact boundary Γ_C),
# 2 the top. The mesh is uniform and coarse: four elements across the width.

# +
BOTTOM, TOP = 1, 2
WIDTH, HEIGHT = 1.0, 0.5


def part_mesh(h: float):
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    if comm.rank == 0:
        gmsh.model.add("block")
        box = gmsh.model.occ.addBox(-WIDTH / 2, -WIDTH / 2, 0.0, WIDTH, WIDTH, HEIGHT)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [box], 1)
        for _, surface in gmsh.model.getEntities(2):
            z = gmsh.model.occ.getCenterOfMass(2, surface)[2]
            if abs(z) < 1e-9:
                gmsh.model.addPhysicalGroup(2, [surface], BOTTOM)
            elif abs(z - HEIGHT) < 1e-9:
                gmsh.model.addPhysicalGroup(2, [surface], TOP)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
        gmsh.model.mesh.generate(3)
    data = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=3)
    gmsh.finalize()
    return data.mesh, data.facet_tags


msh, facet_tags = part_mesh(args.h)
say(f"first mesh: {msh.topology.index_map(0).size_global} nodes")
# -

# ## The user's problem, as a function of the mesh
#
# Everything that lives on the mesh is rebuilt from the mesh: the function space, the
# forms, the Dirichlet condition. The ball sits below the bottom face's centre, its
# top touching it.

# +
material = LinearElastic(E=1.0, nu=0.3)
BALL = admm_dolfinx.Ball(center=(0.0, 0.0, -2.0), radius=2.0)
PUSH = 0.002


def build(msh, facet_tags, contact_normal="obstacle"):
    V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = material.bilinear_form(u, v)
    L = ufl.dot(fem.Constant(msh, np.zeros(3)), v) * ufl.dx
    top = fem.locate_dofs_topological(V, 2, facet_tags.find(TOP))
    push = fem.dirichletbc(np.array([0.0, 0.0, -PUSH]), top, V)
    return admm_dolfinx.ContactProblem(
        a, L, [push], facet_tags, BOTTOM, BALL, contact_normal=contact_normal
    )


# -

# ## A plain solve on the first mesh
#
# It converges, and it says that its peak pressure cannot be trusted: the contact
# zone is smaller than the elements around it.

# +
coarse = build(msh, facet_tags)
with admm_dolfinx.ADMMSolver(coarse) as solver:
    first = solver.solve()
say(f"first mesh: p_max = {first.max_pressure:.4g}")
say(first.warning or "(no warning)")
coarse.destroy()
# -

# ## Refined to the target
#
# `solve_adaptive` rebuilds the problem on each level with `build`, starts each solve
# from the previous level's answer, and stops when the estimated error of the peak
# pressure is at most the target. The estimate comes from the last three levels
# (their differences, at the observed order of convergence); the marking from an
# edge-bubble error estimator weighted towards the contact zone (the book's
# *Adaptive refinement* section says how).

# +
adaptive = admm_dolfinx.solve_adaptive(
    build, msh, facet_tags, target=args.target, quantity="max_pressure"
)
say(adaptive.summary())
result = adaptive.result
with output_folder(comm, Path(args.out)) as staging:
    if comm.rank == 0:
        (Path(staging) / "levels.txt").write_text(adaptive.summary() + "\n")
say(f"wrote {args.out}/levels.txt")
say(result.warning or "the last level's contact zone is resolved")
# -

# ## Against Hertz
#
# A flat face on a ball is Hertz's sphere on a plane turned over: for the computed
# contact force F, Hertz gives the contact radius a = (3FR/4E*)^(1/3) and the peak
# pressure p0 = 3F/(2πa²). The block is not a half-space (its thickness is 7.5 times
# the contact radius), so this is an estimate, not the exact answer. The peak that
# `solve_adaptive` controls is recovered from the nodal pressures by a local
# least-squares fit: on tetrahedra the nodal values scatter by a few percent around
# the pressure, and their largest takes the largest of that scatter.

# +
force = float(np.linalg.norm(result.contact_force))
e_star = material.E / (1.0 - material.nu**2)
a_hertz = (3.0 * force * BALL.radius / (4.0 * e_star)) ** (1.0 / 3.0)
p0_hertz = 3.0 * force / (2.0 * np.pi * a_hertz**2)
say(
    f"F = {force:.4g}: Hertz a = {a_hertz:.4g}, p0 = {p0_hertz:.4g}; refined: peak "
    f"{adaptive.value:.4g} ({adaptive.value / p0_hertz - 1:+.1%}; the largest nodal value "
    f"{result.max_pressure:.4g}); first mesh {first.max_pressure / p0_hertz - 1:+.1%}"
)
# -

# ## Which contact model
#
# Hertz's theory measures the gap and the pressure along one direction, the normal of
# the flat surface. Here the flat surface is the body's, so the body's normal (the
# paper's model, `contact_normal="body"`) is the one Hertz describes; the default,
# the obstacle's normal, is radial on the ball and tilts the traction outwards. On
# the refined mesh, both (the book's *Validation* page says when each is right):

# +
from admm_dolfinx.adapt.recovery import recovered_peak_pressure

for model in ("obstacle", "body"):
    problem = build(adaptive.mesh, adaptive.facet_tags, contact_normal=model)
    with admm_dolfinx.ADMMSolver(problem) as solver:
        answer = solver.solve()
    f = float(np.linalg.norm(answer.contact_force))
    a_h = (3.0 * f * BALL.radius / (4.0 * e_star)) ** (1.0 / 3.0)
    peak = recovered_peak_pressure(problem, answer.multiplier)
    p0_h = 3.0 * f / (2.0 * np.pi * a_h**2)
    say(
        f"contact_normal={model!r}: F = {f:.5g}, peak {peak:.5g}, Hertz p0 for that F "
        f"{p0_h:.5g} ({peak / p0_h - 1:+.1%}), "
        f"horizontal force {np.linalg.norm(answer.contact_force[:2]):.2e}"
    )
    problem.destroy()
adaptive.problem.destroy()
# -
