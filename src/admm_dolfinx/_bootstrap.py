"""Import order guard for the PyPI DOLFINx wheel.

The ``dolfinx-solver-real`` wheel ships DOLFINx with its own PETSc, SLEPc and MPI,
and must be imported before ``dolfinx``, ``petsc4py`` or ``slepc4py``.  In a conda,
apt or Docker FEniCSx environment the module does not exist and nothing is needed.
"""

from __future__ import annotations

import importlib.util

if importlib.util.find_spec("dolfinx_solver") is not None:
    import dolfinx_solver  # noqa: F401

try:
    import dolfinx  # noqa: F401
except ImportError as err:  # pragma: no cover - depends on the environment
    raise ImportError(
        "admm_dolfinx needs DOLFINx 0.11 with petsc4py and slepc4py. Install it into a "
        "FEniCSx environment (conda, Docker, apt), or install the PyPI wheel with "
        "`pip install dolfinx-solver-real` (or `pip install '.[fenics]'` in the admm_dolfinx "
        "source folder)."
    ) from err
