"""Sphinx configuration of the symplid documentation.

Why Sphinx: the docstrings are numpydoc with Sphinx cross-reference roles, the CLI is click
(sphinx-click renders every command and option from the code), the examples are scripts
(sphinx-gallery runs them and shows their figures) and the tutorials are MyST pages executed
at build (myst-nb) -- the stack of the projects symplid's users know (ArviZ, PyMC, BlackJAX,
dynamax). Build (from the repository root)::

    SYMPLID_EXAMPLE_BUDGET=quick sphinx-build -j auto -W --keep-going -b html docs docs/_build/html
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(ROOT / "src"))

# The examples and tutorials read this budget; the build runs them small.
os.environ.setdefault("SYMPLID_EXAMPLE_BUDGET", "quick")
os.environ.setdefault("MPLBACKEND", "Agg")

import symplid  # noqa: E402  (after the path above)

project = "symplid"
author = "the symplid developers"
copyright = "the symplid developers"
version = release = symplid.__version__

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "numpydoc",
    "sphinx.ext.mathjax",
    "sphinx_click",
    "sphinx_copybutton",
    "sphinx_gallery.gen_gallery",
    "symplid_api",
    "symplid_refs",
    "symplid_settings",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "**/.ipynb_checkpoints",
    "studies/*/report.md",  # included by the studies' pages
    "studies/*/cells",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
    "auto_examples/*.md5",
    "auto_examples/*.json",
    "README.md",
]

# Broken cross-references fail the build (with -W); see _ext/symplid_refs.py for how a
# reference to an existing but undocumented name is rendered.
nitpicky = True

# ---------------------------------------------------------------- MyST and notebooks
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = os.environ.get("SYMPLID_DOCS_EXECUTE", "force")
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_execution_in_temp = True  # the tutorials write their files in a temporary folder

# ---------------------------------------------------------------- API reference
autodoc_typehints = "none"  # the numpydoc sections carry the types
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True}
numpydoc_show_class_members = False  # autodoc's :members: lists them
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False  # types stay text ("array (n, d)"), not references
numpydoc_validation_checks: set[str] = set()

# ---------------------------------------------------------------- gallery of examples
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"\.py$",  # run every example
    "ignore_pattern": r"(__init__|_common)\.py$",
    "image_scrapers": ("symplid_gallery.png_scraper",),
    "reset_argv": "symplid_gallery.reset_argv",
    "remove_config_comments": True,
    "download_all_examples": False,
    "plot_gallery": os.environ.get("SYMPLID_DOCS_GALLERY", "True"),
    "abort_on_example_error": True,
    # the examples run side by side in as many processes as sphinx-build's -j gives (joblib),
    # each in its own: the longest examples take minutes, mostly compiling on one core
    "parallel": True,
    "min_reported_time": 1,
    "show_signature": False,
    "default_thumb_file": str(HERE / "figures" / "fig1_phase_portraits.png"),
}

# ---------------------------------------------------------------- HTML
html_theme = "pydata_sphinx_theme"
html_title = f"symplid {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
}
html_show_sourcelink = False
