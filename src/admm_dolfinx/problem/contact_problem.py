"""The discrete contact problem: operators assembled from the user's UFL forms.

:class:`ContactProblem` turns

* the elasticity bilinear form ``a`` and load ``L`` (UFL, P1 vector space),
* Dirichlet conditions ``bcs`` (the DOLFINx way: symmetric elimination),
* the facet tags with the candidate contact boundary Γ_C, and
* an analytic rigid :class:`~admm_dolfinx.problem.obstacles.Obstacle`

into the data of the quadratic programme (docs/design.md §1)

    minimise ½ uᵀA u − fᵀu   subject to   N u ≤ g,

namely the stiffness ``A``, the normal mass ``K = NᵀMN`` (a UFL form with the vertex
rule and the field of contact directions), the lifted load, the lumped mass ``M`` and
the gap ``g``.  ``N`` itself is node-local (``(N u)_j = u_j · d_j``, d_j the contact
direction of node j: see :mod:`admm_dolfinx.problem.contact_set`) and is applied directly to owned
nodal values; it never needs a matrix.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import speaking_for
from admm_dolfinx.linalg.petsc import PetscOwner
from admm_dolfinx.problem.checks import check_dirichlet_conditions, check_finite, check_stiffness
from admm_dolfinx.problem.contact_set import (
    CONTACT_NORMALS,
    ContactSet,
    Marker,
    as_marker,
    build_contact_set,
    check_contact_facets,
    compute_gap,
    dirichlet_fixed,
    mesh_bounds,
)
from admm_dolfinx.problem.obstacles import Obstacle, obstacle_state
from admm_dolfinx.problem.rigid_motions import RigidMotions, analyse_rigid_motions, near_nullspace

__all__ = ["ContactProblem"]


def _cpp(obj):
    """The C++ object behind a DOLFINx Python wrapper (or the object itself)."""
    return getattr(obj, "_cpp_object", obj)


def _argument_space(form: ufl.Form, number: int) -> fem.FunctionSpace:
    for arg in form.arguments():
        if arg.number() == number:
            return arg.ufl_function_space()
    raise ValueError("internal: argument not found")  # pragma: no cover


def _form_data(form: ufl.Form) -> list[np.ndarray]:
    """Copies of the values of the Constants and Functions in a UFL form (local parts)."""
    data = [np.array(c.value, copy=True) for c in form.constants()]
    data += [np.array(f.x.array, copy=True) for f in form.coefficients()]
    return data


def _bc_data(bcs: Sequence[fem.DirichletBC]) -> list[np.ndarray]:
    """Copies of the values of Dirichlet conditions (a Constant's or a Function's)."""
    data = []
    for bc in bcs:
        g = bc.g
        data.append(np.array(g.value if hasattr(g, "value") else g.x.array, copy=True))
    return data


def _changed(now: list[np.ndarray], before: list[np.ndarray]) -> bool:
    return len(now) != len(before) or any(
        x.shape != y.shape or not np.array_equal(x, y, equal_nan=True)
        for x, y in zip(now, before, strict=False)
    )


def _check_obstacle(obstacle: Obstacle, gdim: int) -> None:
    if not isinstance(obstacle, Obstacle):
        raise TypeError(
            f"`obstacle` must be an admm_dolfinx.Obstacle (Plane, Ball or a subclass), "
            f"got {type(obstacle).__name__}."
        )
    obstacle.check_dimension(gdim)


def _check_forms(a: ufl.Form, L: ufl.Form) -> fem.FunctionSpace:
    if not isinstance(a, ufl.Form) or len(a.arguments()) != 2:
        raise TypeError(
            "`a` must be a bilinear UFL form (e.g. inner(sigma(u), eps(v)) * dx), "
            f"got {type(a).__name__}."
        )
    if not isinstance(L, ufl.Form) or len(L.arguments()) != 1:
        raise TypeError(
            "`L` must be a linear UFL form (e.g. dot(t, v) * ds(1)); for a problem without "
            "loads use `ufl.dot(fem.Constant(mesh, np.zeros(gdim)), v) * ufl.dx`. "
            f"Got {type(L).__name__}."
        )
    V = _argument_space(a, 0)
    if _argument_space(a, 1) != V or _argument_space(L, 0) != V:
        raise ValueError("`a` and `L` must use one and the same displacement space.")
    msh = V.mesh
    gdim = msh.geometry.dim
    element = V.ufl_element()
    shape = tuple(element.reference_value_shape)
    if shape != (gdim,):
        raise ValueError(
            f"The displacement space must be a vector space with {gdim} components "
            f"(value shape {(gdim,)}), got value shape {shape}. Create it with "
            f'fem.functionspace(mesh, ("Lagrange", 1, ({gdim},))).'
        )
    basix_element = getattr(element, "basix_element", None)
    family = getattr(basix_element, "family", None)
    degree = element.embedded_superdegree
    if (
        degree != 1
        or str(family) != "ElementFamily.P"
        or getattr(basix_element, "discontinuous", False)
    ):
        raise ValueError(
            f"The displacement space must be continuous P1 Lagrange, got {element}. The "
            "lumped contact mass and nodal normals of this method are defined for P1 "
            f'only: use fem.functionspace(mesh, ("Lagrange", 1, ({gdim},))).'
        )
    return V


class ContactProblem(PetscOwner):
    """Frictionless contact of a linear elastic body with a rigid obstacle.

    Args:
        a: Bilinear UFL form of the elasticity operator on a P1 vector space V.
        L: Linear UFL form of the loads on V.
        bcs: Dirichlet conditions on V (or its sub-spaces); may be empty.
        facet_tags: Facet tags of V's mesh.
        contact_marker: Tag of the candidate contact facets Γ_C, or a tuple of tags
            whose facets together form Γ_C (as in ``ds((1, 2))``).
        obstacle: The rigid obstacle.
        contact_normal: Along which direction non-penetration is measured at each
            contact node: ``"obstacle"`` (default) the obstacle's normal at the node's
            closest point, with the signed distance as the gap, as a rigid-master
            contact code does (a curved body stays out of a plane however wide the
            contact zone); ``"body"`` the body's own nodal normal, with the distance
            along it (the paper's model, exact only where the body's surface is
            parallel to the obstacle; :mod:`admm_dolfinx.studies.reproduce` uses it).
        form_compiler_options: Passed to :func:`dolfinx.fem.form`.
        jit_options: Passed to :func:`dolfinx.fem.form`.

    Raises:
        TypeError: If the forms are not UFL forms of the right arity.
        ValueError: For a space that is not P1 vector Lagrange, facet tags of another
            mesh, a marker without facets, Dirichlet conditions on all of Γ_C, or a NaN
            or -inf gap.

    Attributes:
        V: Displacement space.
        A: Stiffness with Dirichlet rows/columns eliminated (unit diagonal), PETSc Mat.
        K: Normal mass NᵀMN with Dirichlet rows/columns eliminated (zero diagonal).
        contact: The :class:`~admm_dolfinx.problem.contact_set.ContactSet`.
    """

    #: What :meth:`destroy` frees (matrices and vectors of the problem).
    _petsc_objects = ("A", "K", "near_nullspace", "_load", "_lift_k")
    # Assembled by the constructor (:meth:`_assemble_operators`), freed and set to None
    # by :meth:`destroy`, after which the problem is not to be used.
    A: PETSc.Mat
    K: PETSc.Mat
    near_nullspace: PETSc.NullSpace
    _load: PETSc.Vec
    _lift_k: PETSc.Vec

    def __init__(
        self,
        a: ufl.Form,
        L: ufl.Form,
        bcs: Sequence[fem.DirichletBC],
        facet_tags: mesh.MeshTags,
        contact_marker: Marker,
        obstacle: Obstacle,
        *,
        contact_normal: str = "obstacle",
        form_compiler_options: dict | None = None,
        jit_options: dict | None = None,
    ):
        t_start = time.perf_counter()
        if contact_normal not in CONTACT_NORMALS:
            raise ValueError(
                f"contact_normal must be 'obstacle' (non-penetration measured along the "
                "obstacle's normal at each node's closest point, the default) or 'body' "
                f"(along the body's own normal, the paper's model); got {contact_normal!r}."
            )
        V = _check_forms(a, L)
        with speaking_for(V.mesh.comm):  # its warnings on rank 0 of the mesh's communicator
            self._build(
                V,
                a,
                L,
                bcs,
                facet_tags,
                contact_marker,
                obstacle,
                contact_normal,
                form_compiler_options,
                jit_options,
                t_start,
            )

    def _build(
        self,
        V,
        a,
        L,
        bcs,
        facet_tags,
        contact_marker,
        obstacle,
        contact_normal,
        form_compiler_options,
        jit_options,
        t_start,
    ) -> None:
        """The constructor's work; collective."""
        msh = V.mesh
        _check_obstacle(obstacle, msh.geometry.dim)
        if not isinstance(facet_tags, mesh.MeshTags):
            raise TypeError(f"`facet_tags` must be dolfinx MeshTags, got {type(facet_tags)}.")
        if _cpp(facet_tags.topology) is not _cpp(msh.topology):
            raise ValueError(
                "`facet_tags` belong to a different mesh than the forms. Create them with "
                "dolfinx.mesh.meshtags(mesh, mesh.topology.dim - 1, ...) on the mesh of the "
                "displacement space."
            )
        if facet_tags.dim != msh.topology.dim - 1:
            raise ValueError(
                f"`facet_tags` tag entities of dimension {facet_tags.dim}; facet tags of "
                f"dimension {msh.topology.dim - 1} are needed."
            )
        contact_marker = as_marker(contact_marker)
        if isinstance(bcs, fem.DirichletBC):
            raise TypeError("`bcs` must be a list of DirichletBC objects: pass [bc], not bc.")
        bcs = list(bcs or [])
        for bc in bcs:
            if not isinstance(bc, fem.DirichletBC):
                raise TypeError(f"`bcs` must hold dolfinx DirichletBC objects, got {type(bc)}.")
        check_dirichlet_conditions(V, bcs)

        check_contact_facets(msh, facet_tags, contact_marker)

        self.V = V
        self.mesh = msh
        self.comm: MPI.Comm = msh.comm
        self.bcs = bcs
        self.obstacle = obstacle
        self.facet_tags = facet_tags
        #: The tag, or tuple of tags, of Γ_C.
        self.contact_marker: Marker = contact_marker
        #: (2, 3) lower and upper corners of the body (all ranks).
        self.bounds = mesh_bounds(msh)
        #: The body's size: the diagonal of its bounding box.
        self.length_scale = float(np.linalg.norm(self.bounds[1] - self.bounds[0]))
        self.contact: ContactSet = build_contact_set(
            V, facet_tags, self.contact_marker, bcs, obstacle, self.length_scale, contact_normal
        )
        #: Along which normal non-penetration is measured (``"obstacle"`` or ``"body"``).
        self.contact_normal = contact_normal
        #: Counts the changes of N (a moved curved obstacle turns the obstacle's
        #: normals): a solver built on an older N rebuilds its penalty and factors.
        self.operator_version = 0
        try:  # assigns A, K, _load and _lift_k; a failure frees those already made
            self._assemble_operators(a, L, form_compiler_options, jit_options)
        except BaseException:
            self.destroy()  # collective: every rank raised alike
            raise
        self._obstacle_state = obstacle_state(obstacle)
        #: Wall-clock seconds spent building the operators (``assembly``).
        self.timings = {"assembly": time.perf_counter() - t_start}

    def _assemble_operators(self, a, L, form_compiler_options, jit_options) -> None:
        """A, K = NᵀMN and the load, each checked; collective."""
        V, bcs = self.V, self.bcs
        opts = {"form_compiler_options": form_compiler_options, "jit_options": jit_options}
        u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
        n_h = self.contact.normal
        ds_c = self.contact.measure
        self._a = fem.form(a, **opts)
        self._a_ufl, self._a_data = a, _form_data(a)
        self._k = fem.form(ufl.inner(ufl.dot(u, n_h), ufl.dot(v, n_h)) * ds_c, **opts)
        self._L = fem.form(L, **opts)
        self._L_ufl = L

        self.A = fem_petsc.assemble_matrix(self._a, bcs=bcs)
        self.A.assemble()
        bs = V.dofmap.index_map_bs
        n_owned = V.dofmap.index_map.size_local
        fixed = dirichlet_fixed(V, bcs).reshape(-1)
        dof_coordinates = np.repeat(V.tabulate_dof_coordinates()[:n_owned], bs, axis=0)
        dof_coordinates[:, 0] += np.tile(np.arange(bs), n_owned) * 0.618
        #: Mean diagonal of A over the free dofs; also the diagonal of its Dirichlet rows,
        #: so that A is as well scaled as the elasticity itself (for E = 1e-16 as for 1e6).
        self.stiffness_scale = check_stiffness(self.A, fixed, dof_coordinates)
        diagonal = self.A.getDiagonal()
        with diagonal as values:
            values[fixed[: n_owned * bs]] = self.stiffness_scale
        self.A.setDiagonal(diagonal, addv=PETSc.InsertMode.INSERT_VALUES)
        diagonal.destroy()
        self.A.assemble()
        #: The rigid body motions, attached to A as its near null space for multigrid
        #: (a matrix made from A by ``duplicate`` must be given it again).
        self.near_nullspace = near_nullspace(V)
        self.A.setNearNullSpace(self.near_nullspace)
        self.K = fem_petsc.assemble_matrix(self._k, bcs=bcs, diag=0.0)
        self.K.assemble()

        self._load = fem_petsc.create_vector(V)
        self._lift_k = fem_petsc.create_vector(V)
        self._assemble_load()
        self._update_contact_stiffness()
        c = self.contact
        #: The rigid motions that A does not resist (each held by the contact).
        self.rigid_motions: RigidMotions = analyse_rigid_motions(
            self.A, V, c.nodes, c.normals, c.mass, self.stiffness_scale, self.bounds
        )

    def _assemble_load(self) -> None:
        """Assemble f from L and the Dirichlet values, in place; collective.

        The load is lifted by A and, separately, by K, so that the right-hand side of
        (A + rK) u = ... is load_A + r lift_K for any r.
        """
        bcs = self.bcs
        for vec in (self._load, self._lift_k):
            with vec.localForm() as local:
                local.set(0.0)
        fem_petsc.assemble_vector(self._load, self._L)
        fem_petsc.apply_lifting(self._load, [self._a], bcs=[bcs])
        self._load.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        # Dirichlet rows of A hold the stiffness scale s on the diagonal: s u_D = s g
        fem_petsc.set_bc(self._load, bcs, alpha=self.stiffness_scale)
        fem_petsc.apply_lifting(self._lift_k, [self._k], bcs=[bcs])
        self._lift_k.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        fem_petsc.set_bc(self._lift_k, bcs, alpha=0.0)
        check_finite(
            self.comm,
            self._load,
            "The load vector assembled from `L` and the Dirichlet values",
            "Give finite loads (the Constants and Functions of `L`) and finite prescribed "
            "displacements.",
        )
        free_load = self._load.copy()
        fem_petsc.set_bc(free_load, bcs, alpha=0.0)
        #: ‖f‖₂ over the free dofs (the scale of forces in the KKT residuals).
        self.load_norm = free_load.norm()
        #: ‖f‖₁ over the free dofs (the round-off scale of the force balance).
        self.load_norm_1 = free_load.norm(PETSc.NormType.NORM_1)
        free_load.destroy()
        #: The resultant of the applied loads, Σ_i L(φ_i) per direction (gdim,): what
        #: the contact force and the support reactions balance.
        self.applied_load = self._resultant(self._L)
        self._load_data = _form_data(self._L_ufl) + _bc_data(bcs)

    def _resultant(self, form: fem.Form) -> npt.NDArray[np.float64]:
        """Σ_i of an assembled linear form over all dofs, per direction (gdim,); collective."""
        vec = fem_petsc.assemble_vector(form)
        try:
            vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            bs = self.V.dofmap.index_map_bs
            local = vec.array_r.reshape(-1, bs)[:, : self.gdim].sum(axis=0)
        finally:
            vec.destroy()
        return np.asarray(self.comm.allreduce(local, op=MPI.SUM), dtype=np.float64)

    def _update_contact_stiffness(self) -> None:
        """Set k_j = Σ_d ñ_jd² A_(jd,jd) / M_jj, node j's own normal stiffness.

        The stiffness of node j alone against its normal motion (the others held):
        λ_j / k_j is the normal displacement its own pressure would cause, the smallest
        length of the contact (see :func:`~admm_dolfinx.problem.kkt.contact_length`).
        """
        c = self.contact
        diagonal = self.A.getDiagonal()
        try:
            bs = self.V.dofmap.index_map_bs
            values = diagonal.array_r.reshape(-1, bs)[c.nodes, : self.gdim]
        finally:
            diagonal.destroy()
        #: The contact nodes' own normal stiffness per unit area, shape (m_loc,).
        self.contact_stiffness = np.einsum("ij,ij->i", values, c.free_normals**2) / c.mass

    # ------------------------------------------------------------- load steps
    def update_load(self) -> None:
        """Reassemble the load after its data changed, e.g. for the next load step; collective.

        Call it after changing a coefficient of ``L`` (a ``fem.Constant`` or
        ``fem.Function``) or the *values* of the Dirichlet conditions. A, NᵀMN and
        the contact set do not depend on them, so a solver built on this problem keeps
        its penalty r* and its factorisation: the next ``solve()`` costs iterations
        only. (``ADMMSolver.solve`` also calls :meth:`sync_load`, so a forgotten call
        does not leave a stale load.) Changing which dofs are constrained, the forms
        themselves or the mesh needs a new :class:`ContactProblem`.

        Raises:
            ValueError: On every rank, if a Constant or Function of the bilinear form
                ``a`` (e.g. Young's modulus) changed since the problem was built: A, r*
                and the factorisation depend on it, so nothing is reassembled.
        """
        self._check_stiffness_data()
        self._assemble_load()

    def sync_load(self) -> bool:
        """Reassemble the load if its data changed since it was assembled; collective.

        Compares the values of the Constants and Functions of ``L`` and of the
        Dirichlet values with those at the last assembly (an O(n) check).

        Returns:
            Whether the load was reassembled.

        Raises:
            ValueError: As :meth:`update_load`, if the stiffness's data changed.
        """
        self._check_stiffness_data()
        stale = _changed(_form_data(self._L_ufl) + _bc_data(self.bcs), self._load_data)
        if not self.comm.allreduce(stale, op=MPI.LOR):
            return False
        self._assemble_load()
        return True

    def _check_stiffness_data(self) -> None:
        if self.comm.allreduce(_changed(_form_data(self._a_ufl), self._a_data), op=MPI.LOR):
            raise ValueError(
                "A Constant or Function of the bilinear form `a` changed since the "
                "ContactProblem was built, so the stiffness A (and with it r* and the "
                "factorisation) is out of date; only the load can be updated in place. "
                "Build a new ContactProblem and ADMMSolver for the new stiffness."
            )

    def update_obstacle(self, obstacle: Obstacle) -> None:
        """Replace the rigid obstacle, e.g. move it for the next step; collective.

        The gap g is recomputed at the same contact nodes. Where the contact directions
        (the rows of N) stay the same (the paper's body normals; a plane moved without
        turning), A, NᵀMN, r* and the factorisation stay valid, as with
        :meth:`update_load`. Where they turn (a moved curved obstacle with the default
        ``contact_normal="obstacle"``), NᵀMN is reassembled and
        :attr:`operator_version` goes up: a solver of this problem then recomputes its
        penalty and factorisation at its next solve.

        Args:
            obstacle: The new obstacle.

        Raises:
            TypeError: If ``obstacle`` is not an :class:`~admm_dolfinx.problem.obstacles.Obstacle`.
            ValueError: If it has the wrong dimension or its gap is NaN or −inf at some
                contact node, or a new contact direction is fixed by the Dirichlet
                conditions; the problem then keeps its previous obstacle.
        """
        _check_obstacle(obstacle, self.gdim)
        c = self.contact
        with speaking_for(self.comm):
            gap, directions, excluded_gap, excluded_directions = compute_gap(
                obstacle, c, self.comm, self.length_scale
            )
        turned = not np.allclose(directions, c.normals, rtol=0.0, atol=1e-13)
        turned = bool(self.comm.allreduce(turned, op=MPI.LOR))
        if turned:
            fixed = dirichlet_fixed(self.V, self.bcs)[c.nodes, : self.gdim]
            free = np.where(fixed, 0.0, directions)
            lost = np.linalg.norm(free, axis=1) <= 1e-8
            if self.comm.allreduce(int(np.count_nonzero(lost)), op=MPI.SUM):
                raise ValueError(
                    "With the new obstacle some contact directions are fixed by the "
                    "Dirichlet conditions: the set of contact nodes changes. Build a new "
                    "ContactProblem for it."
                )
            c.normals, c.free_normals = directions, free
            bs = self.V.dofmap.index_map_bs
            c.normal.x.array[:] = 0.0
            c.normal.x.array.reshape(-1, bs)[c.nodes, : self.gdim] = directions
            c.normal.x.scatter_forward()
            self.K.zeroEntries()
            # in place into K: dolfinx registers this signature with functools.singledispatch,
            # and mypy sees only the base one (which takes a form first)
            fem_petsc.assemble_matrix(self.K, self._k, bcs=self.bcs, diag=0.0)  # type: ignore[misc]
            self.K.assemble()
            self._assemble_load()  # the lifting of K by the Dirichlet values
            self._update_contact_stiffness()
            self.rigid_motions = analyse_rigid_motions(
                self.A, self.V, c.nodes, c.normals, c.mass, self.stiffness_scale, self.bounds
            )
            self.operator_version += 1
        c.gap = gap
        c.excluded.gap, c.excluded.normals = excluded_gap, excluded_directions
        self.obstacle = obstacle
        self._obstacle_state = obstacle_state(obstacle)

    def check_obstacle_unchanged(self) -> None:
        """Raise if the obstacle was changed in place since its gap was computed; collective.

        Raises:
            ValueError: On every rank, naming the fix (:meth:`update_obstacle`).
        """
        changed = obstacle_state(self.obstacle) != self._obstacle_state
        if self.comm.allreduce(changed, op=MPI.LOR):
            raise ValueError(
                f"The obstacle {self.obstacle!r} was changed in place after its gap was "
                "computed, so the problem's gap is out of date. Call "
                "problem.update_obstacle(obstacle) after moving it (or pass a new one)."
            )

    # ------------------------------------------------------------------ algebra
    @property
    def gdim(self) -> int:
        """Geometric dimension of the mesh."""
        return self.mesh.geometry.dim

    @property
    def num_contact_nodes(self) -> int:
        """Global number m of contact nodes."""
        return self.contact.num_global

    def create_vector(self) -> PETSc.Vec:
        """Return a new PETSc vector in the layout of V (caller destroys it)."""
        return fem_petsc.create_vector(self.V)

    def assemble_rhs(self, r: float, b: PETSc.Vec) -> None:
        """Set ``b`` to the lifted load for ``A + r K``; Dirichlet rows hold u_D.

        Args:
            r: Penalty parameter.
            b: Output vector in V's layout.
        """
        self._load.copy(b)
        b.axpy(r, self._lift_k)

    def apply_normal(self, u: PETSc.Vec) -> npt.NDArray[np.float64]:
        """Return ``N u`` at the owned contact nodes: ``(N u)_j = u_j · n_j``.

        Args:
            u: Displacement vector in V's layout (Dirichlet values included).

        Returns:
            Array of shape (m_loc,).
        """
        c = self.contact
        values = u.array_r.reshape(-1, self.V.dofmap.index_map_bs)[c.nodes, : self.gdim]
        return np.einsum("ij,ij->i", values, c.normals)

    def prescribed_normal_displacement(self) -> npt.NDArray[np.float64]:
        """The part of ``(N u)_j`` that Dirichlet conditions prescribe; collective.

        ``(n_j − ñ_j) · u_D,j`` at the owned contact nodes, with ñ_j the free part of
        n_j and u_D the current Dirichlet values: zero unless a condition fixes a
        component of a contact node's normal.

        Returns:
            Array of shape (m_loc,).
        """
        c = self.contact
        values = self.create_vector()
        try:
            values.set(0.0)
            fem_petsc.set_bc(values, self.bcs)
            u_d = values.array_r.reshape(-1, self.V.dofmap.index_map_bs)[c.nodes, : self.gdim]
            return np.einsum("ij,ij->i", u_d, c.normals - c.free_normals)
        finally:
            values.destroy()

    def add_normal_force(self, b: PETSc.Vec, q: npt.NDArray[np.float64]) -> None:
        """Add ``Nᵀ M q`` to ``b`` on the free dofs (Dirichlet rows untouched).

        Args:
            b: Vector in V's layout.
            q: Nodal values at the owned contact nodes, shape (m_loc,).
        """
        c = self.contact
        bs = self.V.dofmap.index_map_bs
        with b as arr:  # context form: PETSc sees the write (cached norms invalidated)
            arr.reshape(-1, bs)[c.nodes, : self.gdim] += c.free_normals * (c.mass * q)[:, None]

    def multiplier_from_residual(self, residual: PETSc.Vec) -> npt.NDArray[np.float64]:
        """Recover λ from an equilibrium residual ``R = f − A u`` that equals ``NᵀMλ``.

        At contact node j, R_j = M_jj λ_j ñ_j with ñ_j the free part of n_j, hence
        λ_j = (R_j · ñ_j) / (M_jj ‖ñ_j‖²). Used by solvers that do not carry λ.

        Args:
            residual: ``f − A u`` in V's layout.

        Returns:
            λ at the owned contact nodes, shape (m_loc,).
        """
        c = self.contact
        bs = self.V.dofmap.index_map_bs
        values = residual.array_r.reshape(-1, bs)[c.nodes, : self.gdim]
        weight = np.einsum("ij,ij->i", c.free_normals, c.free_normals)
        return np.einsum("ij,ij->i", values, c.free_normals) / (c.mass * weight)

    def pressure_function(
        self, values: npt.NDArray[np.float64], name: str = "contact_pressure"
    ) -> fem.Function:
        """Return a P1 scalar Function equal to ``values`` at contact nodes, zero elsewhere.

        Args:
            values: Nodal values at the owned contact nodes, shape (m_loc,).
            name: Name of the Function.

        Returns:
            The Function (ghosts updated).
        """
        f = fem.Function(self.contact.Q, name=name)
        f.x.array[:] = 0.0
        f.x.array[self.contact.dofs] = values
        f.x.scatter_forward()
        return f

    def global_norm(self, x: npt.NDArray[np.float64], ord: float = 2) -> float:
        """Global 2- or ∞-norm of a distributed array of nodal values; collective."""
        if ord == np.inf:
            local = float(np.max(np.abs(x))) if x.size else 0.0
            return float(self.comm.allreduce(local, op=MPI.MAX))
        return float(np.sqrt(self.comm.allreduce(float(x @ x), op=MPI.SUM)))

    def load_vector(self) -> PETSc.Vec:
        """The lifted load f (Dirichlet rows hold u_D); owned by the problem, do not modify."""
        return self._load

    def __repr__(self) -> str:
        return (
            f"ContactProblem({self.gdim}D, {self.V.dofmap.index_map.size_global} nodes, "
            f"m = {self.num_contact_nodes} contact nodes, obstacle={self.obstacle!r})"
        )
