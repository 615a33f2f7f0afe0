"""Sphinx configuration of goniofrost's documentation (MyST Markdown, pydata-sphinx-theme).

Build: ``python -m sphinx -W -n docs docs/_build/html`` (the ``docs`` extra has what it needs).
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                    # the goniofrost of this checkout, for autodoc and argparse
sys.path.insert(0, str(Path(__file__).parent / "_ext"))

project = "goniofrost"
author = "the goniofrost developers"
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinxarg.ext", "goniofrost_docs"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "benchmarks/results"]
myst_enable_extensions = ["colon_fence", "attrs_block", "deflist"]
myst_heading_anchors = 3
nitpicky = True
# Signatures without annotations: the docstrings state types and shapes in words, and numpy's or the
# standard library's types would otherwise need their inventories (no network in a test).
autodoc_typehints = "none"
autodoc_member_order = "bysource"
html_theme = "pydata_sphinx_theme"
html_title = "goniofrost"
html_static_path = []
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}
