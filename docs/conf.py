"""Sphinx configuration of the admm_dolfinx book (``make docs``; builds offline)."""

from __future__ import annotations

import os

import admm_dolfinx

project = "admm_dolfinx"
author = "the admm_dolfinx developers"
copyright = "2026, the admm_dolfinx developers"  # noqa: A001
release = admm_dolfinx.__version__

extensions = [
    "myst_nb",  # MyST markdown, and the demos (jupytext "light" scripts) as executed notebooks
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",  # Google-style docstrings
    "sphinx.ext.mathjax",
]
exclude_patterns = ["_build", "**.ipynb_checkpoints", "README.md", "conf.py", "demos/out_*"]
source_suffix = {".md": "myst-nb", ".py": "myst-nb"}
nb_custom_formats = {".py": ["jupytext.reads", {"fmt": "py:light"}]}
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# Every demo is executed at every build; an error in a demo fails the build.
nb_execution_mode = "force"
nb_execution_timeout = 900
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_kernel_rgx_aliases = {".*": "python3"}

autodoc_typehints = "description"
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "show-inheritance": True}
napoleon_google_docstring = True
napoleon_numpy_docstring = False

html_theme = "alabaster"
html_title = f"admm_dolfinx {release}"
html_static_path: list[str] = []
suppress_warnings = ["mystnb.unknown_mime_type", "myst.header"]

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("OMP_NUM_THREADS", "1")
nb_execution_in_temp = True  # the demos write their outputs into a temporary folder
