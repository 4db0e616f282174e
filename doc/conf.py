"""Sphinx configuration of fd_monitor's documentation (MyST Markdown; rosdoc2's layout).

Build: ``.venv/bin/python -m sphinx -W -b html doc /tmp/fd_monitor_doc`` (``test/test_docs.py``
runs it with warnings as errors). Every page of ``tutorial/``, ``howto/``, ``reference/`` and
``theory/`` is included by a glob in ``index.md``, so a new page appears by itself.
"""

from __future__ import annotations

import sys
from pathlib import Path

# The package from this checkout, also when it is not installed (rosdoc2 builds from source).
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

project = "fd_monitor"
author = "fd_monitor developers"
copyright = "fd_monitor developers, Apache-2.0"
release = version = "0.1.0"

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

autodoc_typehints = "none"          # the numpydoc sections state types, shapes and units
autodoc_member_order = "bysource"
napoleon_google_docstring = False
napoleon_numpy_docstring = True

html_theme = "alabaster"
html_title = "fd_monitor"
html_static_path: list[str] = []
