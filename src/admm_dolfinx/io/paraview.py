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

The path is checked before anything is opened (the folder it goes into must exist and
be writable), and an existing ``.bp`` folder is written over only if this class wrote
it: ADIOS2 empties the folder it opens, and the package deletes nothing it did not
write. Each folder it writes carries a marker file, :data:`MARKER`, for that check.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import ufl
from dolfinx import fem, io
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from admm_dolfinx._mpi import rebuilt_exception, run_on_rank0
from admm_dolfinx.admm.result import ADMMResult
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_zone import active_marker, gap_function

__all__ = ["MARKER", "ContactWriter"]

#: The file that marks a ``.bp`` folder as written by :class:`ContactWriter`.
MARKER = ".admm-dolfinx-vtx"
#: The names ADIOS2 (BP4, BP5) writes into a ``.bp`` folder.
_ADIOS2_NAMES = re.compile(r"^((data|md|mmd)\.\d+|md\.idx|profiling\.json)$")


def _check_vtx_path(path: Path) -> None:
    """Raise unless ``path`` can be written as a VTX folder without deleting another's files."""
    parent = path.parent
    if not parent.is_dir():
        raise FileNotFoundError(
            f"Cannot write {str(path)!r}: the folder {str(parent)!r} does not exist (or is "
            "not a folder). Create it first, or choose another path."
        )
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(
            f"Cannot write {str(path)!r}: no write permission in {str(parent)!r}. Choose a "
            "writable location."
        )
    if not (path.exists() or path.is_symlink()):
        return
    if not path.is_dir() or path.is_symlink():
        raise FileExistsError(
            f"Cannot write {str(path)!r}: a file of that name exists, and a VTX output is a "
            "folder. Choose another path, or move the file."
        )
    names = sorted(entry.name for entry in path.iterdir())
    if not names:
        return
    ours = MARKER in names
    foreign = [name for name in names if name != MARKER and not _ADIOS2_NAMES.match(name)]
    if not ours or foreign:
        shown = ", ".join(repr(name) for name in (foreign or names)[:5])
        raise FileExistsError(
            f"Cannot write {str(path)!r}: the folder exists and holds files this package did "
            f"not write ({shown}{', ...' if len(foreign or names) > 5 else ''}); writing "
            "would delete them. Choose a new path, or move the folder away yourself."
        )


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
        path: The ``.bp`` folder to write, in an existing folder. An existing one is
            replaced only if an earlier ContactWriter wrote it.
        von_mises: Optional ``u ↦`` von Mises stress as a scalar UFL expression (e.g.
            :meth:`admm_dolfinx.scenes.material.LinearElastic.von_mises`).

    Raises:
        ValueError: If ``path`` does not end in ``.bp``.
        OSError: On every rank, if its folder does not exist or cannot be written, or
            ``path`` exists and holds files this package did not write.

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
        comm = problem.comm

        def failure(name: str, text: str, is_os_error: bool) -> Exception:
            return rebuilt_exception(name, text)  # the same OSError kind on every rank

        run_on_rank0(comm, lambda: _check_vtx_path(path.absolute()), failure)
        self.path = path
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
        self._writer = io.VTXWriter(comm, str(path), fields, engine="BP4")
        # ADIOS2 has created (and emptied) the folder: mark it as this package's
        run_on_rank0(
            comm, lambda: (path / MARKER).write_text("admm_dolfinx ContactWriter\n"), failure
        )

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
