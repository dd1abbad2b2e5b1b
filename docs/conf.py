"""Sphinx configuration of sb3_macb's documentation (python -m sphinx -W docs docs/_build/html)."""

import os
import sys

sys.path.insert(0, os.path.abspath(".."))

from sb3_macb import __version__  # noqa: E402

project = "sb3_macb"
author = "the sb3_macb developers"
version = release = __version__
extensions = ["sphinx.ext.autodoc", "myst_parser"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
html_theme = "alabaster"
autodoc_member_order = "bysource"
autodoc_typehints = "description"
myst_heading_anchors = 3
