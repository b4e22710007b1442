"""A ParaView file of a contact solve, over load steps (VTX, ADIOS2).

:class:`ContactWriter` writes, at each call of :meth:`ContactWriter.write`, the
displacement, the contact pressure, the remaining gap, the active set and (if the
material's von Mises stress is given) the von Mises stress, as one time of a VTX
``.bp`` folder that ParaView opens directly (``File → Open``, the "ADIOS2VTXReader").

Every field is written in the displacement's element (P1 or Q1) on the mesh the
solver used, so curved (second-order) geometry and every cell type the solver accepts
are written alike. The von Mises stress, discontinuous in u's gradient, is written as
its lumped L² projection (the nodal average v_i = ∫ σ_vm φ_i dx / ∫ φ_i dx).
All methods are collective.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import ufl
from dolfinx import fem, io
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from admm_dolfinx.admm.result import ADMMResult
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_zone import active_marker, gap_function

__all__ = ["ContactWriter"]


def _assembled(form: ufl.Form) -> np.ndarray:
    """The owned values of an assembled linear form (ghost contributions added)."""
    vec = fem_petsc.assemble_vector(fem.form(form))
    try:
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec.array_r.copy()
    finally:
        vec.destroy()


class ContactWriter:
    """Write a contact solution to a VTX file, one time per load step.

    Args:
        problem: The contact problem whose solutions are written.
        path: The ``.bp`` folder to write (created or replaced, as by
            :class:`dolfinx.io.VTXWriter`).
        von_mises: Optional ``u ↦`` von Mises stress as a scalar UFL expression (e.g.
            :meth:`admm_dolfinx.problem.material.LinearElastic.von_mises`).

    Example::

        with ContactWriter(problem, "contact.bp", material.von_mises) as writer:
            for step, load in enumerate(loads):
                ...
                writer.write(solver.solve(), t=step)
    """

    def __init__(
        self,
        problem: ContactProblem,
        path: str | os.PathLike,
        von_mises: Callable[[fem.Function], ufl.core.expr.Expr] | None = None,
    ):
        path = Path(path)
        if path.suffix != ".bp":
            raise ValueError(f"A VTX file is a folder ending in .bp, got {str(path)!r}.")
        self.problem = problem
        Q = problem.contact.Q
        self.u = fem.Function(problem.V, name="displacement")
        self.pressure = fem.Function(Q, name="contact_pressure")
        self.gap = fem.Function(Q, name="gap")
        self.active = fem.Function(Q, name="active_set")
        fields = [self.u, self.pressure, self.gap, self.active]
        self._von_mises_form: ufl.Form | None = None
        self.von_mises: fem.Function | None = None
        if von_mises is not None:
            self.von_mises = fem.Function(Q, name="von_mises")
            q = ufl.TestFunction(Q)
            self._von_mises_form = von_mises(self.u) * q * ufl.dx
            self._lumped = _assembled(q * ufl.dx)
            fields.append(self.von_mises)
        self._writer = io.VTXWriter(problem.comm, str(path), fields, engine="BP4")

    def write(self, result: ADMMResult, t: float = 0.0) -> None:
        """Write the solution ``result`` as time ``t``; collective."""
        problem = self.problem
        self.u.x.array[:] = result.u.x.array
        self.pressure.x.array[:] = result.pressure.x.array
        self.gap.x.array[:] = gap_function(problem, result.u).x.array
        self.active.x.array[:] = active_marker(problem, result.multiplier).x.array
        if self.von_mises is not None and self._von_mises_form is not None:
            n_owned = self.von_mises.function_space.dofmap.index_map.size_local
            values = _assembled(self._von_mises_form)
            with np.errstate(divide="ignore", invalid="ignore"):
                nodal = np.where(self._lumped > 0.0, values / self._lumped, 0.0)
            self.von_mises.x.array[:n_owned] = nodal[:n_owned]
            self.von_mises.x.scatter_forward()
        self._writer.write(float(t))

    def close(self) -> None:
        """Close the file; collective."""
        self._writer.close()

    def __enter__(self) -> ContactWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
