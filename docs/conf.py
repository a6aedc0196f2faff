"""Sphinx configuration: ``sphinx-build -W -b html docs docs/_build/html``."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mavsid  # noqa: E402

project = "mavsid"
author = "the mavsid authors"
copyright = "2026, the mavsid authors"
release = mavsid.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]

# The API reference is generated on every build from the package itself (autosummary,
# recursive): a module that is added, moved or removed needs no edit here. The stubs of the
# previous build are removed first so that a module that moved leaves no stale page.
shutil.rmtree(Path(__file__).parent / "api" / "generated", ignore_errors=True)
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented"
autodoc_member_order = "bysource"
autodoc_inherit_docstrings = False
autodoc_mock_imports: list[str] = []

napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_ivar = True
napoleon_use_rtype = False
napoleon_preprocess_types = False

templates_path = ["_templates"]
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]
default_role = "code"
nitpicky = False
# An ambiguous short name in a type hint (two modules defining a ``Model``) resolves to one of
# them with a warning; that is no error in a page, so it does not fail the build.
suppress_warnings = ["config.cache", "ref.python"]

html_theme = "pydata_sphinx_theme"
html_title = f"mavsid {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_static_path: list[str] = []
# Pages without sub-pages need no left sidebar: their tables get the width.
html_sidebars = {page: [] for page in ("index", "install", "validation", "performance")}
html_show_sourcelink = False
