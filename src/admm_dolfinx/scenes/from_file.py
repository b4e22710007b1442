"""A scene from the user's own gmsh mesh file: tags, supports, loads and an obstacle.

What ``admm-dolfinx run --mesh part.msh`` builds: a linear elastic body (P1) meshed
in gmsh, whose boundary parts are physical groups of facets (their tags), clamped or
displaced on some tags, loaded by tractions on others and by a body force, pressed
onto a rigid :class:`~admm_dolfinx.Plane` or :class:`~admm_dolfinx.Ball`. Python users
build the same with their own UFL forms (the README's quick start); this is the
command line's version of it, with every input checked up front.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

from admm_dolfinx._mpi import run_on_rank0
from admm_dolfinx.problem.obstacles import Obstacle
from admm_dolfinx.scenes.library import Scene
from admm_dolfinx.scenes.material import LinearElastic
from admm_dolfinx.scenes.meshing import gmsh_session, mesh_and_facet_tags

__all__ = ["scene_from_file"]


def _vector(name: str, value: Sequence[float], gdim: int) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.shape != (gdim,) or not np.all(np.isfinite(array)):
        raise ValueError(
            f"{name} must be {gdim} finite numbers for this {gdim}D mesh, got {list(value)}."
        )
    return array


def scene_from_file(
    path: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    contact: int,
    obstacle: Obstacle,
    fixed: Sequence[int] = (),
    displaced: Mapping[int, Sequence[float]] | None = None,
    tractions: Mapping[int, Sequence[float]] | None = None,
    body_force: Sequence[float] | None = None,
    E: float = 1000.0,
    nu: float = 0.3,
) -> Scene:
    """Read a gmsh ``.msh`` file and set up its contact scene; collective.

    Args:
        path: The mesh file (gmsh's ``.msh``; the facets of every boundary part that
            is named below must be in a physical group, whose tag names it).
        comm: Communicator of the mesh.
        contact: Tag of the contact boundary Γ_C.
        obstacle: The rigid obstacle (its normal points from it towards the body).
        fixed: Tags clamped (u = 0).
        displaced: Tag → prescribed displacement vector.
        tractions: Tag → surface traction vector (force per unit area).
        body_force: Force per unit volume (None: none).
        E: Young's modulus.
        nu: Poisson's ratio.

    Returns:
        The scene (name: the file's stem).

    Raises:
        FileNotFoundError: If the file does not exist (on every rank).
        ValueError: For a tag that is not a physical group of facets of the mesh (the
            message lists those it has), a tag used twice, a vector of the wrong size,
            or nothing that holds the body or loads it.
    """
    path = Path(path)
    if not comm.allreduce(path.is_file(), op=MPI.LAND):
        raise FileNotFoundError(f"No mesh file {str(path)!r} (a gmsh .msh file is expected).")
    displaced = dict(displaced or {})
    tractions = dict(tractions or {})
    named = [contact, *fixed, *displaced, *tractions]
    repeated = sorted({tag for tag in named if named.count(tag) > 1})
    if repeated:
        raise ValueError(
            f"Tag(s) {repeated} are given more than one role (contact, fixed, displaced, "
            "traction): each boundary part has one."
        )
    if not fixed and not displaced and not tractions and body_force is None:
        raise ValueError(
            "Nothing loads the body: give --fixed/--displace tags that press it onto the "
            "obstacle, or --traction/--body-force loads."
        )
    check = LinearElastic(E, nu)  # validates E and ν with its own message

    with gmsh_session(path.stem) as gmsh:

        def read() -> int:
            gmsh.merge(str(path))
            return int(gmsh.model.getDimension())

        def failure(kind: str, text: str, _: bool) -> Exception:
            return ValueError(f"gmsh could not read {str(path)!r}: {kind}: {text}")

        gdim = run_on_rank0(comm, read, failure)
        if gdim not in (2, 3):
            raise ValueError(f"{str(path)!r} holds a {gdim}D mesh; 2D or 3D is needed.")
        data = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=gdim)
    try:
        msh, facet_tags = mesh_and_facet_tags(data)
    except RuntimeError as error:
        raise ValueError(f"{str(path)!r}: {error} The boundary parts need tags.") from None
    present = sorted(comm.allreduce(set(np.unique(facet_tags.values).tolist()), op=MPI.BOR))
    missing = [tag for tag in named if tag not in present]
    if missing:
        raise ValueError(
            f"{str(path)!r} has no facets tagged {missing}; its physical groups of "
            f"facets are {present}."
        )
    obstacle.check_dimension(gdim)

    V = fem.functionspace(msh, ("Lagrange", 1, (gdim,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    fdim = gdim - 1
    bcs = []
    for tag in fixed:
        dofs = fem.locate_dofs_topological(V, fdim, facet_tags.find(tag))
        bcs.append(fem.dirichletbc(np.zeros(gdim), dofs, V))
    for tag, value in displaced.items():
        dofs = fem.locate_dofs_topological(V, fdim, facet_tags.find(tag))
        bcs.append(fem.dirichletbc(_vector(f"--displace {tag}", value, gdim), dofs, V))
    zero = fem.Constant(msh, np.zeros(gdim))
    L = ufl.dot(zero, v) * ufl.dx
    for tag, value in tractions.items():
        t = fem.Constant(msh, _vector(f"--traction {tag}", value, gdim))
        L = L + ufl.dot(t, v) * ds(tag)
    if body_force is not None:
        f = fem.Constant(msh, _vector("--body-force", body_force, gdim))
        L = L + ufl.dot(f, v) * ufl.dx
    cells = msh.topology.index_map(gdim).size_local
    diameters = msh.h(gdim, np.arange(cells, dtype=np.int32))
    count = comm.allreduce(cells, op=MPI.SUM)
    mean_h = comm.allreduce(float(np.sum(diameters)), op=MPI.SUM) / max(count, 1)
    return Scene(
        name=path.stem,
        mesh=msh,
        facet_tags=facet_tags,
        markers={"contact": contact},
        material=check,
        V=V,
        a=check.bilinear_form(u, v),
        L=L,
        bcs=bcs,
        contact_marker=contact,
        obstacle=obstacle,
        h=mean_h,
        info={"file": str(path), "E": E, "nu": nu},
    )
