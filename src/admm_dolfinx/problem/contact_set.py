"""Contact geometry on the tagged facets: nodes, contact directions, lumped mass, gap.

Everything here is parallel-safe: facet integrals are assembled by DOLFINx and
summed across process boundaries, so a contact facet that spans two ranks yields the
same nodal normal and mass on both.

Notation (docs/design.md §1): contact node j has the lumped mass M_jj = ∫_Γc φ_j ds, the
contact direction d_j (the row of N: (N u)_j = u_j · d_j) and the gap g_j. With the
default ``contact_normal="obstacle"``, d_j = −ν_j, ν_j the obstacle's unit normal at
the point closest to x_j, and g_j the signed distance; with ``"body"`` (the paper's),
d_j = n_j, the body's area-weighted, normalised outward normal, and g_j the distance
along it (see :mod:`admm_dolfinx.problem.obstacles`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import warn
from admm_dolfinx._mpi import collective_call, from_rank0, gather_concat, probe_vector
from admm_dolfinx.problem.obstacles import Obstacle, implements

__all__ = [
    "CONTACT_NORMALS",
    "VERTEX_RULE",
    "ContactSet",
    "ExcludedNodes",
    "build_contact_set",
    "compute_gap",
    "dirichlet_fixed",
    "evaluate_obstacle",
    "mesh_bounds",
    "read_only",
]

#: Vertex quadrature on facets: turns facet mass integrals into the lumped (diagonal)
#: mass ∫ φ_j ds and evaluates nodal fields exactly at the nodes.
VERTEX_RULE = {"quadrature_rule": "vertex", "quadrature_degree": 1}

#: A node whose normal has less than this much length left after removing the
#: Dirichlet-fixed components has its normal displacement prescribed: it is not a
#: contact node.
_FIXED_NORMAL_TOL = 1e-8


#: A facet marker: one tag, or a tuple of tags whose facets together form the part
#: (as in ``ds((1, 2))``).
Marker = int | tuple[int, ...]


def as_marker(marker: object, name: str = "contact_marker") -> Marker:
    """Check a facet marker and return it as an int or a tuple of distinct ints.

    Raises:
        TypeError: If it is not an int or a non-empty sequence of ints (bools refused).
    """

    def one(value: object) -> int:
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise TypeError(
                f"`{name}` must be a facet tag (int) or a tuple of tags, got {marker!r}."
            )
        return int(value)

    if isinstance(marker, list | tuple | np.ndarray):
        values = tuple(dict.fromkeys(one(value) for value in marker))
        if not values:
            raise TypeError(f"`{name}` is an empty sequence; pass at least one facet tag.")
        return values[0] if len(values) == 1 else values
    return one(marker)


def marked_facets(facet_tags: mesh.MeshTags, marker: Marker) -> npt.NDArray[np.int32]:
    """The local facets tagged with ``marker`` (any of its tags), sorted."""
    values = marker if isinstance(marker, tuple) else (marker,)
    found = [facet_tags.find(value) for value in values]
    return np.unique(np.concatenate(found)).astype(np.int32)


def _contact_measure(msh: mesh.Mesh, facet_tags: mesh.MeshTags, marker: Marker) -> ufl.Measure:
    """Return the vertex-rule exterior facet measure restricted to ``marker``.

    Args:
        msh: The body's mesh.
        facet_tags: Facet tags of the body's mesh.
        marker: Tag, or tuple of tags, of the candidate contact facets Γ_C.

    Returns:
        ``ds(marker)`` with the vertex quadrature rule.
    """
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags, metadata=VERTEX_RULE)
    return ds(marker)


@dataclass
class ExcludedNodes:
    """The owned nodes of Γ_C whose normal displacement a Dirichlet condition fixes.

    They are not contact nodes (nothing can change their normal displacement), but
    their gap is still reported (``result.gap()``).

    Attributes:
        dofs: Local indices of their scalar (Q) dofs.
        nodes: Their local node (block) indices in the displacement space.
        coordinates: Their coordinates, shape (k, gdim).
        body_normals: The body's outward unit normals there.
        normals: The contact directions the obstacle gives them.
        gap: Their gap.
    """

    dofs: npt.NDArray[np.int32]
    nodes: npt.NDArray[np.int32]
    coordinates: npt.NDArray[np.float64]
    body_normals: npt.NDArray[np.float64]
    normals: npt.NDArray[np.float64]
    gap: npt.NDArray[np.float64]


@dataclass
class ContactSet:
    """The contact nodes owned by this rank and their geometry.

    Attributes:
        Q: Scalar P1 space on the body's mesh (the space of p, λ, g and M), collapsed
            from the displacement space so that its dof i is node i of V.
        normal: The contact directions as a field in the displacement space; zero away
            from the contact nodes. It is what the UFL form of NᵀMN uses.
        dofs: Local indices of the owned Q dofs that are contact nodes, shape (m_loc,).
        nodes: The matching local node (block) indices of the displacement space.
        normals: The contact directions, the rows of N: the direction in which node j
            approaches the obstacle (−ν_j, or the body's n_j in the paper's model),
            shape (m_loc, gdim).
        free_normals: n_j with its Dirichlet-fixed components zeroed: the rows of Nᵀ
            that act on free dofs.
        mass: Lumped contact mass M_jj, shape (m_loc,).
        gap: Normalised gap g_j, shape (m_loc,); +inf where the node can never touch.
        coordinates: Node coordinates, shape (m_loc, gdim).
        body_normals: The body's outward unit normals n_j, shape (m_loc, gdim).
        contact_normal: The model of the rows of N: ``"obstacle"`` (−ν_j) or
            ``"body"`` (n_j).
        num_global: Total number m of contact nodes over all ranks.
        num_excluded: Nodes on Γ_C (all ranks) whose normal displacement is fixed by a
            Dirichlet condition and which are therefore not contact nodes.
        q_to_node: For every local dof of Q, its node (block) in the displacement space.
        probe: Pseudo-random values in (−½, ½) per contact node that depend only on its
            coordinates: the start of the eigenvalue solves, the same on every partition.
        excluded: The owned nodes of Γ_C that are not contact nodes (their normal
            displacement is prescribed), with their gap.
        measure: ``ds(Γ_C)`` with the vertex quadrature rule, the one measure of every
            form on Γ_C (NᵀMN, the nodal normals and masses, the surface metric); for
            a quadrature of its own, ``measure.reconstruct(metadata={...})``.
    """

    Q: fem.FunctionSpace
    normal: fem.Function
    dofs: npt.NDArray[np.int32]
    nodes: npt.NDArray[np.int32]
    normals: npt.NDArray[np.float64]
    free_normals: npt.NDArray[np.float64]
    mass: npt.NDArray[np.float64]
    gap: npt.NDArray[np.float64]
    coordinates: npt.NDArray[np.float64]
    body_normals: npt.NDArray[np.float64]
    contact_normal: str
    num_global: int
    num_excluded: int
    q_to_node: npt.NDArray[np.int64]
    probe: npt.NDArray[np.float64]
    excluded: ExcludedNodes
    measure: ufl.Measure


def check_contact_facets(msh: mesh.Mesh, facet_tags: mesh.MeshTags, marker: Marker) -> int:
    """Check that ``marker`` tags at least one exterior facet; collective.

    Args:
        msh: The body's mesh.
        facet_tags: Its facet tags.
        marker: The contact marker.

    Returns:
        The global number of tagged facets.

    Raises:
        ValueError: On every rank alike, if no rank has a facet with ``marker`` or if a
            tagged facet is an interior facet.
    """
    tdim = msh.topology.dim
    local = marked_facets(facet_tags, marker)
    msh.topology.create_connectivity(tdim - 1, tdim)
    exterior = mesh.exterior_facet_indices(msh.topology)
    n_interior = int(np.count_nonzero(~np.isin(local, exterior)))
    counts = msh.comm.allreduce(np.array([local.size, n_interior]), op=MPI.SUM)
    if counts[0] == 0:
        present = np.unique(facet_tags.values)
        all_values = sorted(set(np.concatenate(msh.comm.allgather(present)).tolist()))
        raise ValueError(
            f"No facets are tagged with contact marker {marker} on any process "
            f"(the facet tags hold the values {all_values}). Pass the marker of the "
            "candidate contact boundary Γ_C."
        )
    if counts[1] > 0:
        raise ValueError(
            f"{counts[1]} facet(s) tagged with contact marker {marker} are interior "
            "facets. Contact facets must lie on the boundary of the body."
        )
    return int(counts[0])


def mesh_bounds(msh: mesh.Mesh) -> npt.NDArray[np.float64]:
    """The (2, 3) array of the mesh's lower and upper corners over all ranks; collective.

    A rank without cells (or nodes) takes part with neutral bounds.
    """
    x = msh.geometry.x
    lo, hi = np.empty(3), np.empty(3)
    msh.comm.Allreduce(np.ascontiguousarray(x.min(axis=0, initial=np.inf)), lo, op=MPI.MIN)
    msh.comm.Allreduce(np.ascontiguousarray(x.max(axis=0, initial=-np.inf)), hi, op=MPI.MAX)
    return np.vstack([lo, hi])


def dirichlet_fixed(V: fem.FunctionSpace, bcs: Sequence[fem.DirichletBC]) -> npt.NDArray:
    """Return a (num_local_nodes, bs) boolean array: which dof components are fixed."""
    bs = V.dofmap.index_map_bs
    n_local = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
    fixed = np.zeros(n_local * bs, dtype=bool)
    for bc in bcs:
        dofs, _ = bc.dof_indices()
        fixed[dofs] = True
    return fixed.reshape(-1, bs)


def _assemble_over_contact(form: ufl.Form, V: fem.FunctionSpace) -> npt.NDArray[np.float64]:
    """Assemble a linear form, sum across ranks and return owned+ghost values."""
    vec = fem_petsc.assemble_vector(fem.form(form))
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    with vec.localForm() as loc:
        values = loc.array.copy()
    vec.destroy()
    return values


#: ``contact_normal`` values: along the obstacle's normal (default) or the body's.
CONTACT_NORMALS = ("obstacle", "body")


def build_contact_set(
    V: fem.FunctionSpace,
    facet_tags: mesh.MeshTags,
    marker: Marker,
    bcs: Sequence[fem.DirichletBC],
    obstacle: Obstacle,
    length_scale: float,
    contact_normal: str = "obstacle",
) -> ContactSet:
    """Find the contact nodes and compute their normals, mass and gap; collective.

    Args:
        V: P1 vector displacement space.
        facet_tags: Facet tags of V's mesh.
        marker: Contact marker (a tag or a tuple of tags).
        bcs: Dirichlet conditions on V; a node whose normal displacement they fix is
            not a contact node.
        obstacle: The rigid obstacle.
        length_scale: The body's size (see :func:`compute_gap`).
        contact_normal: Along which direction non-penetration is measured:
            ``"obstacle"`` (−ν_j, the obstacle's normal at the closest point) or
            ``"body"`` (the body's nodal normal n_j, the paper's model).

    Returns:
        The contact set.

    Raises:
        ValueError: If every node of Γ_C has its normal displacement fixed, or the
            obstacle's answer is unusable (see :func:`compute_gap`).
    """
    msh = V.mesh
    gdim = msh.geometry.dim
    bs = V.dofmap.index_map_bs
    ds_c = _contact_measure(msh, facet_tags, marker)

    # Area-weighted nodal normal: vertex rule gives Σ_F |F|/n_v · n_F at each node.
    v = ufl.TestFunction(V)
    raw = _assemble_over_contact(ufl.inner(ufl.FacetNormal(msh), v) * ds_c, V).reshape(-1, bs)
    length = np.linalg.norm(raw, axis=1)
    on_contact = length > 0.0
    normals_all = np.zeros_like(raw)
    normals_all[on_contact] = raw[on_contact] / length[on_contact, None]
    fixed = dirichlet_fixed(V, bcs)

    Q, q_to_v = V.sub(0).collapse()
    q_to_node = np.asarray(q_to_v).reshape(-1) // bs
    w = ufl.TestFunction(Q)
    mass_all = _assemble_over_contact(w * ds_c, Q)

    n_owned_q = Q.dofmap.index_map.size_local
    n_owned_nodes = V.dofmap.index_map.size_local
    owned_nodes = q_to_node[:n_owned_q]
    if np.any(owned_nodes >= n_owned_nodes):  # pragma: no cover - DOLFINx invariant
        raise RuntimeError("internal: collapsed scalar space does not share V's ownership")
    # candidates: owned nodes of Γ_C; their contact directions (rows of N) and gaps
    candidates = np.flatnonzero(on_contact[owned_nodes] & (mass_all[:n_owned_q] > 0.0))
    candidate_nodes = owned_nodes[candidates]
    coordinates = Q.tabulate_dof_coordinates()[candidates, :gdim]
    body_normals = normals_all[candidate_nodes, :gdim]
    comm = msh.comm
    gap, directions = evaluate_obstacle(obstacle, coordinates, body_normals, comm, contact_normal)
    free = np.where(fixed[candidate_nodes, :gdim], 0.0, directions)
    keep = np.linalg.norm(free, axis=1) > _FIXED_NORMAL_TOL
    dofs = candidates[keep].astype(np.int32)
    nodes = candidate_nodes[keep].astype(np.int32)

    n_owned_on_contact = int(np.count_nonzero(on_contact[:n_owned_nodes]))
    n_global, n_on_contact = comm.allreduce(np.array([dofs.size, n_owned_on_contact]), op=MPI.SUM)
    if n_global == 0:
        raise ValueError(
            f"All {n_on_contact} nodes of the contact boundary (marker {marker}) have their "
            "normal displacement fixed by the Dirichlet conditions, so nothing can come "
            "into contact. Remove the Dirichlet condition from the contact boundary or "
            "choose another contact marker."
        )
    all_gap, all_directions = gap, directions
    gap, directions = gap[keep], directions[keep]
    _check_gap_values(gap, coordinates[keep], comm, length_scale, f"{obstacle!r}", contact_normal)

    normal = fem.Function(V, name="contact_normal")
    normal.x.array[:] = 0.0
    normal.x.array.reshape(-1, bs)[nodes, :gdim] = directions
    normal.x.scatter_forward()

    return ContactSet(
        Q=Q,
        normal=normal,
        dofs=dofs,
        nodes=nodes,
        normals=directions,
        free_normals=free[keep],
        mass=mass_all[dofs].copy(),
        gap=gap,
        coordinates=coordinates[keep],
        body_normals=body_normals[keep],
        contact_normal=contact_normal,
        num_global=int(n_global),
        num_excluded=int(n_on_contact - n_global),
        q_to_node=q_to_node,
        probe=probe_vector(coordinates[keep]),
        excluded=ExcludedNodes(
            dofs=candidates[~keep].astype(np.int32),
            nodes=candidate_nodes[~keep].astype(np.int32),
            coordinates=coordinates[~keep],
            body_normals=body_normals[~keep],
            normals=all_directions[~keep],
            gap=all_gap[~keep],
        ),
        measure=ds_c,
    )


def read_only(array: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """A read-only float64 copy of ``array``: what user code is handed."""
    copy = np.array(array, dtype=np.float64, copy=True)
    copy.flags.writeable = False
    return copy


def _guarded(comm: MPI.Comm, fn, name: str):
    """User code ``fn()`` on every rank, with a clear message if it writes its inputs."""

    def call():
        try:
            return fn()
        except ValueError as error:
            if "read-only" in str(error):
                raise ValueError(
                    f"{name} tried to write into its inputs, which are read-only (they are "
                    "the problem's node coordinates and normals): compute into new arrays "
                    "(e.g. n = n.copy() first)."
                ) from error
            raise

    return collective_call(comm, call, name)


def evaluate_obstacle(
    obstacle: Obstacle,
    coordinates: npt.NDArray[np.float64],
    body_normals: npt.NDArray[np.float64],
    comm: MPI.Comm,
    contact_normal: str,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The gap and the contact direction (a row of N) at each node; collective.

    User code: it gets read-only copies, and if it raises on one rank every rank
    raises. With ``"obstacle"`` the direction is −ν (the obstacle's normal at the
    closest point, turned towards the obstacle) and the gap the signed distance; with
    ``"body"`` the body's normal and the distance along it. A node that can never touch
    (gap +inf) keeps the body's normal (it constrains nothing).

    Raises:
        ValueError: On every rank, for an obstacle that does not implement the model's
            method, or an answer of the wrong shape or with bad normals.
    """
    name = type(obstacle).__name__
    k, gdim = coordinates.shape
    x, n = read_only(coordinates), read_only(body_normals)
    if contact_normal == "obstacle":
        if not implements(obstacle, "signed_distance"):
            raise ValueError(
                f"{name} implements only gap(x, n), the distance along the body's "
                "normals: build the problem with contact_normal='body' (the paper's "
                "model), or implement signed_distance(x) -> (g, nu) for the default model "
                "along the obstacle's normal."
            )
        answer = _guarded(comm, lambda: obstacle.signed_distance(x), f"{name}.signed_distance")
        try:
            gap, nu = (np.asarray(a, dtype=np.float64) for a in answer)
        except (TypeError, ValueError):
            gap, nu = np.full(0, np.nan), np.zeros((0, gdim))
        shapes = gap.shape in ((k,), (k, 1)) and nu.shape == (k, gdim)
        if not comm.allreduce(shapes, op=MPI.LAND):
            raise ValueError(
                f"{name}.signed_distance must return (g, nu) with g of shape (k,) and nu of "
                "shape (k, gdim) for x of shape (k, gdim), on every process."
            )
        gap = gap.reshape(-1).copy()
        finite = np.isfinite(gap)
        length = np.linalg.norm(nu, axis=1)
        bad = finite & ~(np.isfinite(length) & (length > 0.0))
        if comm.allreduce(int(np.count_nonzero(bad)), op=MPI.SUM):
            raise ValueError(
                f"{name}.signed_distance returned a zero or non-finite normal at a node with "
                "a finite distance; nu must be the obstacle's unit normal there."
            )
        with np.errstate(invalid="ignore", divide="ignore"):
            directions = np.where(finite[:, None], -nu / length[:, None], n)
        return gap, directions
    if contact_normal != "body":
        raise ValueError(
            f"contact_normal must be one of {CONTACT_NORMALS}, got {contact_normal!r}."
        )
    if not implements(obstacle, "gap"):
        raise ValueError(
            f"{name} implements only signed_distance(x), along the obstacle's normal: use "
            "contact_normal='obstacle' (the default), or implement gap(x, n) for the "
            "paper's model along the body's normals."
        )
    raw = _guarded(comm, lambda: obstacle.gap(x, n), f"{name}.gap")
    try:
        gap = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        gap = np.full(0, np.nan)
    if not comm.allreduce(gap.shape in ((k,), (k, 1)), op=MPI.LAND):
        raise ValueError(
            f"{name}.gap returned an array of the wrong shape or type on some process; it "
            "must return one float per contact node, shape (k,) for x and n of shape "
            "(k, gdim)."
        )
    return gap.reshape(-1).copy(), np.array(body_normals, dtype=np.float64, copy=True)


def compute_gap(
    obstacle: Obstacle,
    contact: ContactSet,
    comm: MPI.Comm,
    length_scale: float,
) -> tuple[npt.NDArray[np.float64], ...]:
    """The gap and contact directions of the contact set's nodes for an obstacle.

    Args:
        obstacle: The rigid obstacle.
        contact: The contact set (its nodes, coordinates, body normals and model).
        comm: The mesh's communicator.
        length_scale: The body's size (the diagonal of its bounding box); a node that
            starts deeper inside the obstacle than this is an input error.

    Returns:
        (g, directions), shapes (m_loc,) and (m_loc, gdim), and the same of the
        excluded nodes (:class:`ExcludedNodes`).

    Raises:
        ValueError: On every rank, if the obstacle's answer has the wrong shape, a NaN
            or −inf gap, or a penetration deeper than the body's size.
    """
    m = contact.coordinates.shape[0]
    excluded = contact.excluded
    gap, directions = evaluate_obstacle(
        obstacle,
        np.concatenate([contact.coordinates, excluded.coordinates]),
        np.concatenate([contact.body_normals, excluded.body_normals]),
        comm,
        contact.contact_normal,
    )
    _check_gap_values(
        gap[:m], contact.coordinates, comm, length_scale, f"{obstacle!r}", contact.contact_normal
    )
    return gap[:m], directions[:m], gap[m:], directions[m:]


def _check_gap_values(gap, coordinates, comm, length_scale, what, contact_normal) -> None:
    """Refuse NaN, −inf and absurd penetrations; warn when no or every node touches."""
    behind = gap == -np.inf
    if contact_normal == "body" and comm.allreduce(int(np.count_nonzero(behind)), op=MPI.SUM):
        raise ValueError(
            f"Some contact nodes start inside {what} with their body normal pointing away "
            "from it (the gap along the normal is -inf): the paper's model, "
            "contact_normal='body', cannot push them out along their normals. Use "
            "contact_normal='obstacle' (the default), or check the obstacle's position."
        )
    bad = ~(np.isfinite(gap) | (gap == np.inf))
    deep = np.isfinite(gap) & (gap < -length_scale)
    for mask, problem in (
        (bad, "is NaN or -inf"),
        (deep, f"is a penetration deeper than the body's size ({length_scale:.3g})"),
    ):
        examples = gather_concat(comm, coordinates[mask][:5])
        n_bad = comm.allreduce(int(np.count_nonzero(mask)), op=MPI.SUM)
        if n_bad > 0:
            points = from_rank0(comm, None if examples is None else examples[0][:5].tolist())
            raise ValueError(
                f"The gap to {what} {problem} at {n_bad} contact node(s), e.g. at {points}. "
                "The gap must be finite (negative: the node starts inside the obstacle), "
                "or +inf where the node can never touch the obstacle; check the "
                "obstacle's position and its gap()."
            )
    counts = comm.allreduce(
        np.array(
            [
                gap.size,
                np.count_nonzero(gap == np.inf),
                np.count_nonzero(gap < -1e-12 * length_scale),  # round-off of a gap 0
            ]
        ),
        op=MPI.SUM,
    )
    total, never, inside = (int(v) for v in counts)
    if total and never == total:
        warn(
            f"No contact node can ever touch {what}: every gap is +inf. Check the "
            "obstacle's position, and that its normal points from the obstacle towards "
            "the body."
        )
    elif total and inside == total:
        warn(
            f"Every contact node starts inside {what} (every gap is negative). If that "
            "is not meant, check the obstacle's position and that its normal points "
            "from the obstacle towards the body."
        )
