"""The optional dependencies (extras) and how to install the missing ones.

The package is installed from its source folder, not from PyPI, so a message names
both routes: the dependency itself from PyPI, or the extra from the source folder.
"""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

__all__ = ["EXTRAS", "available", "install_hint", "require"]

#: module → (PyPI name, the package's extra that brings it)
EXTRAS = {
    "gmsh": ("gmsh", "scenes"),
    "pyvista": ("pyvista", "plot"),
    "matplotlib": ("matplotlib", "plot"),
    "osqp": ("osqp", "bench"),
    "scipy": ("scipy", "bench"),
}


def install_hint(module: str) -> str:
    """How to install ``module``: from PyPI, or as the package's extra."""
    pypi, extra = EXTRAS.get(module, (module, None))
    hint = f"`pip install {pypi}`"
    if extra is not None:
        hint += f", or `pip install '.[{extra}]'` in the admm_dolfinx source folder"
    return hint


def available(module: str) -> bool:
    """Whether ``module`` can be imported (without importing it)."""
    return importlib.util.find_spec(module) is not None


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module``, or raise an ImportError that says what needs it and how to install it.

    Args:
        module: The module's name (``"gmsh"``).
        purpose: What needs it (``"The scenes build their meshes with gmsh"``).
    """
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(f"{purpose}, which is not installed: {install_hint(module)}.") from err
