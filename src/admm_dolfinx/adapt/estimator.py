"""An a-posteriori error estimator for Signorini contact: hierarchical, edge by edge.

The error of a P1 solution (u_h, λ_h) is estimated in the space of the quadratic
edge bubbles ψ_e = 4 φ_a φ_b that P2 adds to P1 (Bank & Smith 1993; for obstacle
problems Zou, Veeser, Kornhuber & Gräser 2011, *Numer. Math.* 117). The residual of
the equilibrium tested with a bubble,

    R(ψ_e e_i) = L(ψ_e e_i) − a(u_h, ψ_e e_i) − ∫_Γc λ_h d·(ψ_e e_i) ds,

vanishes for P1 test functions (Galerkin orthogonality) but not for bubbles: it holds
the interior stress jumps, the traction residual on Γ_N and, on Γ_C, the mismatch of
the normal stress and the contact pressure (the contact terms of residual estimators,
Hild & Nicaise 2007, Weiss & Wohlmuth 2010), all without writing the strong form: it
is assembled from the user's own forms ``a`` and ``L``. The bubble's energy-norm
correction gives the edge indicator

    η_e² = Σ_i R(ψ_e e_i)² / a(ψ_e e_i, ψ_e e_i)      (Dirichlet-fixed components left out),

with the bubble's stiffness a(ψ_e e_i, ψ_e e_i) ≈ BUBBLE_STIFFNESS k ∫ψ_e dx from the
stiffness per volume k of its two end nodes (A_ii / ∫φ_i dx), which saves assembling a
P2 matrix. On Γ_C a second term measures how deep the obstacle enters the deformed
body at the edge's midpoint (on the body's true surface where one is given): an
entry δ_e between the nodes costs the bubble's energy a(ψ_e d, ψ_e d) δ_e². The
estimator drives the marking; the error of a quantity (the peak pressure) is
estimated from successive levels (:mod:`admm_dolfinx.adapt.quantities`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.adapt.surface import Surface, project_on_surface
from admm_dolfinx.admm.result import ADMMResult
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import evaluate_obstacle, marked_facets

__all__ = ["BUBBLE_STIFFNESS", "EdgeIndicators", "edge_indicators", "relative_energy_error"]

#: a(ψ_e, ψ_e) / (k ∫ψ_e) of an edge bubble, k the stiffness per volume of a hat
#: function: 4 in 1D (∫ψ'² = 16/(3h), ∫ψ = 2h/3, against 2/h² for the hat), the scale
#: the indicator needs (its constant cancels in the marking).
BUBBLE_STIFFNESS = 4.0


class EdgeIndicators:
    """η_e² on the local edges of a mesh (owned edges; zero on the others).

    Attributes:
        values: η_e² per local edge (edge index of the mesh's topology).
        owned: Which local edges this rank owns (each edge counted once over the ranks).
        midpoints: The edges' midpoints, shape (edges, gdim).
    """

    def __init__(
        self,
        values: npt.NDArray[np.float64],
        owned: npt.NDArray[np.bool_],
        midpoints: npt.NDArray[np.float64],
    ):
        self.values = values
        self.owned = owned
        self.midpoints = midpoints

    def localised(self, center: npt.ArrayLike, radius: float) -> EdgeIndicators:
        """The indicators weighted by how much a point quantity at ``center`` sees them.

        The error of a local quantity (the pressure at a point) is the residual weighted
        by the influence function of that point (the dual solution of dual-weighted
        residual estimators), whose gradient decays as the stress of a point load,
        r^{1−d}; its share of an edge's error falls as (radius/r)^d beyond ``radius``.

        Args:
            center: Where the quantity is read (the pressure peak).
            radius: The size of the zone it depends on (the contact zone's half-width).
        """
        distance = np.linalg.norm(self.midpoints - np.asarray(center)[None, :], axis=1)
        gdim = self.midpoints.shape[1]
        weight = np.minimum(1.0, (radius / np.maximum(distance, 1e-300)) ** gdim)
        return EdgeIndicators(self.values * weight, self.owned, self.midpoints)

    def total(self, comm) -> float:
        """η² = Σ_e η_e² over every rank; collective."""
        return float(comm.allreduce(float(self.values[self.owned].sum()), op=MPI.SUM))


def _arguments(form: ufl.Form) -> tuple[ufl.Argument, ufl.Argument | None]:
    """(test, trial) of a form (trial None for a linear form)."""
    args = sorted(form.arguments(), key=lambda arg: arg.number())
    return args[0], args[1] if len(args) > 1 else None


def _edge_dofs(V2: fem.FunctionSpace) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """(edge, block dof of its midpoint) for every local edge of V2's mesh."""
    msh = V2.mesh
    tdim = msh.topology.dim
    msh.topology.create_entities(1)
    msh.topology.create_connectivity(tdim, 1)
    c2e = msh.topology.connectivity(tdim, 1)
    layout = V2.dofmap.dof_layout
    cells = V2.dofmap.list
    edges_per_cell = c2e.offsets[1] - c2e.offsets[0] if c2e.offsets.size > 1 else 0
    pairs_e, pairs_d = [], []
    for local in range(int(edges_per_cell)):
        (dof,) = layout.entity_dofs(1, local)
        pairs_e.append(c2e.array[c2e.offsets[:-1] + local])
        pairs_d.append(cells[:, dof])
    if not pairs_e:
        return np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int32)
    edges = np.concatenate(pairs_e)
    dofs = np.concatenate(pairs_d)
    edges, first = np.unique(edges, return_index=True)
    return edges.astype(np.int32), dofs[first].astype(np.int32)


def _fixed_components(problem: ContactProblem, vertices: npt.NDArray) -> npt.NDArray[np.bool_]:
    """(edges, gdim): components a Dirichlet condition fixes at both ends of each edge."""
    V = problem.V
    bs = V.dofmap.index_map_bs
    n_local = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
    fixed = np.zeros(n_local * bs, dtype=bool)
    for bc in problem.bcs:
        dofs, _ = bc.dof_indices()
        fixed[dofs] = True
    fixed = fixed.reshape(-1, bs)[:, : problem.gdim]
    node = _vertex_to_node(problem)
    ends = node[vertices]
    return fixed[ends[:, 0]] & fixed[ends[:, 1]]


def _vertex_to_node(problem: ContactProblem) -> npt.NDArray[np.int32]:
    """The displacement space's node (block dof) at every local vertex."""
    msh = problem.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim, 0)
    c2v = msh.topology.connectivity(tdim, 0)
    cells = problem.V.dofmap.list
    n_vertices = msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts
    node = np.zeros(n_vertices, dtype=np.int32)
    if cells.size:
        node[c2v.array.reshape(cells.shape)] = cells
    return node


def _assembled(form: fem.Form) -> npt.NDArray[np.float64]:
    """The owned values of an assembled linear form (ghost contributions added)."""
    vec = fem_petsc.assemble_vector(form)
    try:
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec.array_r.copy()
    finally:
        vec.destroy()


def edge_indicators(
    problem: ContactProblem, result: ADMMResult, surface: Surface | None = None
) -> EdgeIndicators:
    """The hierarchical indicators η_e² of a solution on every local edge; collective.

    Args:
        problem: The contact problem (its forms, Dirichlet conditions, Γ_C).
        result: Its solution.
        surface: The body's true surface (a map to its nearest points), for the
            midpoints of Γ_C's edges; None: the mesh's facets are the surface.

    Returns:
        The indicators.
    """
    msh, gdim = problem.mesh, problem.gdim
    V2 = fem.functionspace(msh, ("Lagrange", 2, (gdim,)))
    v2 = ufl.TestFunction(V2)
    test, _ = _arguments(problem._a_ufl)
    (load_test, _) = _arguments(problem._L_ufl)
    residual = ufl.replace(problem._L_ufl, {load_test: v2}) - ufl.replace(
        ufl.action(problem._a_ufl, result.u), {test: v2}
    )
    # ds(Γ_C) with the default quadrature (the contact set's own is the vertex rule)
    ds_c = problem.contact.measure.reconstruct(metadata={})
    contact = result.pressure * ufl.dot(problem.contact.normal, v2) * ds_c
    r = _assembled(fem.form(residual - contact)).reshape(-1, gdim)
    bubble = _assembled(fem.form(ufl.dot(ufl.as_vector([1.0] * gdim), v2) * ufl.dx))
    bubble = bubble.reshape(-1, gdim)[:, 0]

    # the hat functions' stiffness per volume at every node, for the bubbles' stiffness
    per_volume = _stiffness_per_volume(problem)
    edges, dofs = _edge_dofs(V2)
    owned = dofs < V2.dofmap.index_map.size_local
    edges, dofs = edges[owned], dofs[owned]
    msh.topology.create_connectivity(1, 0)
    vertices = msh.topology.connectivity(1, 0).array.reshape(-1, 2)[edges]
    node = _vertex_to_node(problem)
    k = 0.5 * (per_volume[node[vertices[:, 0]]] + per_volume[node[vertices[:, 1]]])
    energy = BUBBLE_STIFFNESS * k * bubble[dofs][:, None]  # a(ψ e_i, ψ e_i) per component
    free = ~_fixed_components(problem, vertices)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(free & (energy > 0.0), r[dofs] ** 2 / energy, 0.0)
    eta2 = terms.sum(axis=1)
    eta2 += _contact_midpoints(problem, result, edges, vertices, node, energy, surface)

    n_edges = msh.topology.index_map(1).size_local + msh.topology.index_map(1).num_ghosts
    values = np.zeros(n_edges)
    values[edges] = eta2
    mask = np.zeros(n_edges, dtype=bool)
    mask[edges] = True
    all_edges = msh.topology.connectivity(1, 0).array.reshape(-1, 2)
    coordinates = _vertex_coordinates(msh)
    midpoints = 0.5 * (coordinates[all_edges[:, 0]] + coordinates[all_edges[:, 1]])
    return EdgeIndicators(values, mask, midpoints)


def relative_energy_error(problem: ContactProblem, result: ADMMResult, eta2: float) -> float | None:
    """η² / (a(u_h, u_h) − η²): the strain energy's estimated relative error; collective.

    The hierarchical estimator's η² estimates ‖u − u_h‖²_a. Where the obstacle's
    motion drives the body (displacements prescribed, no loads), the Galerkin solution
    is stiffer by its energy error, a(u_h, u_h) = a(u, u) + ‖u − u_h‖²_a, and the
    contact force is the energy's conjugate (for a rigid flat punch pressed δ,
    a(u, u) = F δ): the ratio estimates the force's relative error
    (:func:`~admm_dolfinx.adapt.adaptive.solve_adaptive` with
    ``quantity="contact_force"``). Where loads fix the force, the discrete energy
    is the lower one and the ratio over-estimates the energy's error.

    Args:
        problem: The contact problem (its bilinear form).
        result: Its solution.
        eta2: η² = Σ_e η_e² over the whole mesh.

    Returns:
        The ratio; infinity where η² is not below a(u_h, u_h) (an error of 100 % or
        more); None where the solution has no energy (nothing deforms).
    """
    test, trial = _arguments(problem._a_ufl)
    energy_form = ufl.replace(problem._a_ufl, {test: result.u, trial: result.u})
    local = np.real(fem.assemble_scalar(fem.form(energy_form)))
    energy = float(problem.comm.allreduce(float(local), op=MPI.SUM))
    if not energy > 0.0:
        return None
    if eta2 >= energy:
        return math.inf
    return float(eta2) / (energy - float(eta2))


def _stiffness_per_volume(problem: ContactProblem) -> npt.NDArray[np.float64]:
    """A_ii / ∫φ_i dx per node and component, on owned and ghost nodes; collective."""
    V, gdim = problem.V, problem.gdim
    bs = V.dofmap.index_map_bs
    Q, q_to_node = problem.contact.Q, problem.contact.q_to_node
    n_owned = Q.dofmap.index_map.size_local
    volume = _assembled(fem.form(ufl.TestFunction(Q) * ufl.dx))
    diagonal = problem.A.getDiagonal()
    try:
        stiffness = diagonal.array_r.reshape(-1, bs)[:, :gdim].copy()
    finally:
        diagonal.destroy()
    n_nodes = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
    out = np.zeros((n_nodes, gdim))
    carrier = fem.Function(Q)
    owned_nodes = q_to_node[:n_owned]
    for i in range(gdim):  # Q's owned dofs are V's owned nodes, in another order
        carrier.x.array[:] = 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            carrier.x.array[:n_owned] = np.where(
                volume > 0.0, stiffness[owned_nodes, i] / volume, 0.0
            )
        carrier.x.scatter_forward()
        out[q_to_node, i] = carrier.x.array
    return out


def _contact_edges(problem: ContactProblem) -> npt.NDArray[np.int32]:
    """The local edges of Γ_C's facets."""
    msh = problem.mesh
    fdim = msh.topology.dim - 1
    facets = marked_facets(problem.facet_tags, problem.contact_marker)
    if fdim == 1:
        return facets
    msh.topology.create_connectivity(fdim, 1)
    f2e = msh.topology.connectivity(fdim, 1)
    per_facet = int(f2e.offsets[1] - f2e.offsets[0]) if f2e.offsets.size > 1 else 0
    if not facets.size or not per_facet:
        return np.zeros(0, dtype=np.int32)
    return np.unique(f2e.array.reshape(-1, per_facet)[facets]).astype(np.int32)


def _contact_midpoints(problem, result, edges, vertices, node, energy, surface) -> npt.NDArray:
    """δ_e² a(ψ_e d, ψ_e d) on Γ_C's edges: the obstacle entering the deformed midpoint."""
    gdim = problem.gdim
    out = np.zeros(edges.size)
    if problem.contact.contact_normal != "obstacle":  # the paper's model: not checked
        return out
    on_contact = np.flatnonzero(np.isin(edges, _contact_edges(problem)))
    coordinates = _vertex_coordinates(problem.mesh)
    u = result.u.x.array.reshape(-1, problem.V.dofmap.index_map_bs)[:, :gdim]
    ends = vertices[on_contact]
    midpoint = 0.5 * (coordinates[ends[:, 0]] + coordinates[ends[:, 1]])
    if surface is not None:  # on every rank: the call is collective
        midpoint = project_on_surface(problem.comm, surface, np.ascontiguousarray(midpoint))
    deformed = midpoint + 0.5 * (u[node[ends[:, 0]]] + u[node[ends[:, 1]]])
    gap, directions = evaluate_obstacle(
        problem.obstacle, deformed, np.zeros_like(deformed), problem.comm, "obstacle"
    )
    depth = np.where(np.isfinite(gap), np.maximum(-gap, 0.0), 0.0)
    normal_energy = np.einsum("ij,ij->i", energy[on_contact], directions**2)
    out[on_contact] = normal_energy * depth**2
    return out


def _vertex_coordinates(msh: mesh.Mesh) -> npt.NDArray[np.float64]:
    """The coordinates of every local vertex (affine meshes: vertex = geometry node)."""
    tdim = msh.topology.dim
    n_vertices = msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts
    msh.topology.create_connectivity(0, tdim)
    nodes = mesh.entities_to_geometry(msh, 0, np.arange(n_vertices, dtype=np.int32))
    return msh.geometry.x[nodes[:, 0], : msh.geometry.dim]
