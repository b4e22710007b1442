# # From a gmsh file to contact: a roller pressed onto a rigid plate
#
# A user's part usually arrives as a gmsh `.msh` file whose *physical groups* name
# the volume and the boundary parts. This demo takes such a file to a contact solution
# and to the outputs an engineer reaches for. It illustrates
#
# * reading a `.msh` file with its physical groups as cell and facet tags
#   ({py:func}`dolfinx.io.gmsh.read_from_msh`),
# * a contact boundary made of **two** physical groups (`ds((3, 4))` in UFL terms),
# * the contact force, the contact area, the support reaction and their balance,
# * a ParaView file with the displacement, pressure, gap, active set and von Mises
#   stress ({py:class}`admm_dolfinx.io.paraview.ContactWriter`).
#
# The part is a roller: a cylinder of radius 0.5 and length 1 (axis along y) whose top
# has been machined flat. The flat top is pushed down; the lower half of the curved
# surface, in two physical groups (front and back), may touch a rigid plate 0.005 below.
#
# Run it with `python demos/gmsh_part.py` or `mpirun -n 2 python demos/gmsh_part.py`.
# Output goes to `out_gmsh_part/`.

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
from dolfinx import mesh as dmesh
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

from admm_dolfinx.io.output import output_folder
from admm_dolfinx.io.paraview import ContactWriter
from admm_dolfinx.scenes.material import LinearElastic

parser = argparse.ArgumentParser(description="A gmsh part pressed onto a rigid plate")
parser.add_argument("--h", type=float, default=0.08, help="mesh size (default 0.08)")
parser.add_argument("--out", default="out_gmsh_part", help="output folder")
# In the book this runs in a Jupyter kernel, whose own arguments are not the demo's.
args = parser.parse_args([] if "ipykernel" in sys.modules else None)
comm = MPI.COMM_WORLD


def say(*text):
    if comm.rank == 0:
        print(*text, flush=True)


# -

# ## The file
#
# Here the file is written by gmsh's Python API, as a CAD export would write it. The
# physical groups carry the tags: 1 the volume, 2 the flat top, 5 the rest of the
# boundary (the curved surface and the two ends).

# +
BODY, TOP, FRONT, BACK, OTHER = 1, 2, 3, 4, 5
R, LENGTH, FLAT = 0.5, 1.0, 0.4  # the top is cut flat at height FLAT above the axis


def write_part(path: Path, h: float) -> None:
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("roller")
    occ = gmsh.model.occ
    cylinder = occ.addCylinder(0, 0, R, 0, LENGTH, 0, R)
    cut = occ.addBox(-R, 0, R + FLAT, 2 * R, LENGTH, R)
    occ.cut([(3, cylinder)], [(3, cut)])
    occ.synchronize()
    gmsh.model.addPhysicalGroup(3, [v for _, v in gmsh.model.getEntities(3)], BODY)
    top, other = [], []
    for _, surface in gmsh.model.getEntities(2):
        z = occ.getCenterOfMass(2, surface)[2]
        (top if abs(z - (R + FLAT)) < 1e-8 else other).append(surface)
    gmsh.model.addPhysicalGroup(2, top, TOP)
    gmsh.model.addPhysicalGroup(2, other, OTHER)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    gmsh.model.mesh.generate(3)
    gmsh.write(str(path))
    gmsh.finalize()


# -

# ## Reading it
#
# `read_from_msh` distributes the mesh and returns the physical groups as tags. The
# curved surface came out of CAD as one face; the contact boundary of this demo is its
# lower half, split into front and back: the facet tags are re-made from the file's,
# as a user would when refining a tagging.

# +
folder = Path(args.out)
with output_folder(comm, folder) as staging:
    msh_file = Path(staging) / "roller.msh"
    if comm.rank == 0:
        write_part(msh_file, args.h)
    comm.barrier()
    data = gmshio.read_from_msh(str(msh_file), comm, 0, gdim=3)
msh, facet_tags = data.mesh, data.facet_tags
say(
    f"read {msh.topology.index_map(0).size_global} nodes, "
    f"{msh.topology.index_map(3).size_global} cells; tags {sorted(set(facet_tags.values.tolist()))}"
)

fdim = 2
mid = dmesh.compute_midpoints(msh, fdim, facet_tags.indices)
lower = (
    (facet_tags.values == OTHER)
    & (mid[:, 2] < R - 1e-3)
    & (np.hypot(mid[:, 0], mid[:, 2] - R) > 0.9 * R)
)
values = facet_tags.values.copy()
values[lower & (mid[:, 1] < LENGTH / 2)] = FRONT
values[lower & (mid[:, 1] >= LENGTH / 2)] = BACK
tags = dmesh.meshtags(msh, fdim, facet_tags.indices, values)
# -

# ## The problem
#
# Steel-like units scaled to E = 1: the displacement is what matters. The flat top is
# pushed 0.01 down, so the roller presses 0.005 into the plate's initial gap.

# +
material = LinearElastic(E=1.0, nu=0.3)
V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
a = material.bilinear_form(u, v)
L = ufl.dot(fem.Constant(msh, np.zeros(3)), v) * ufl.dx
top_dofs = fem.locate_dofs_topological(V, fdim, tags.find(TOP))
push = fem.dirichletbc(np.array([0.0, 0.0, -0.01]), top_dofs, V)
plate = admm_dolfinx.Plane(point=(0.0, 0.0, -0.005), normal=(0.0, 0.0, 1.0))
problem = admm_dolfinx.ContactProblem(a, L, [push], tags, (FRONT, BACK), plate)
solver = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix="roller_")
say(solver.summary())
result = solver.solve()
say(result.summary())
# -

# ## Outputs
#
# The contact force balances the reaction of the pushed top to the solver's tolerance
# (the book's *Outputs* chapter says why it is computed with the method's lumped mass).

# +
force = result.contact_force
reaction = result.reaction_force(TOP)
imbalance = np.linalg.norm(force + reaction) / np.linalg.norm(force)
say(f"contact force {force}, support reaction {reaction}, imbalance {imbalance:.1e}")
say(
    f"contact area {result.contact_area:.4g}, mean pressure {result.mean_pressure:.4g}, "
    f"max pressure {result.max_pressure:.4g}"
)
active = result.active_facets()
n_active = comm.allreduce(
    int(np.count_nonzero(active.indices < msh.topology.index_map(fdim).size_local)), MPI.SUM
)
say(f"{n_active} facets in contact")

with output_folder(comm, folder) as staging:
    with ContactWriter(problem, Path(staging) / "roller.bp", material.von_mises) as writer:
        writer.write(result, t=0.0)
say(f"wrote {folder}/roller.bp (open it in ParaView)")
solver.destroy()
# -
