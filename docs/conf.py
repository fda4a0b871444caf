"""Sphinx configuration of the roadcollab documentation (``make docs``; ``.ci/run`` builds it with ``-W``)."""

from __future__ import annotations

import roadcollab

project = "roadcollab"
author = "roadcollab contributors"
copyright = "2026, roadcollab contributors"
release = version = getattr(roadcollab, "__version__", "0.1.0")

extensions = [
    "myst_parser",               # Markdown pages (docs/*.md), written by several branches
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",                  # the package's docstrings are numpydoc (tests/test_docstrings.py)
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3

autosummary_generate = True
autosummary_imported_members = False
# Members by their defining module, not by ``__all__``: a re-exported class (privacy.secagg_messages re-exports
# wire.secagg's messages) is documented once, where it is defined.
autodoc_default_options = {"members": True, "ignore-module-all": True}
autodoc_typehints = "none"           # numpydoc's Parameters sections carry the types, shapes and units
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# numpydoc turns a References section into citations; they are sources, not always cited in the text.
suppress_warnings = ["ref.citation"]

html_theme = "alabaster"
html_static_path: list[str] = []
