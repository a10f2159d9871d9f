"""Sphinx configuration of the sppo_sb3 documentation (Markdown pages through MyST, API pages through autodoc).

Build it with ``.venv/bin/pip install -c constraints.txt -e ".[docs]"`` and
``.venv/bin/sphinx-build -W --keep-going -b html docs docs/_build/html``.
"""

from __future__ import annotations

import os
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)  # autodoc imports the package of this checkout, installed or not

with open(os.path.join(ROOT, "sppo_sb3", "version.txt")) as file_handler:
    release = file_handler.read().strip()
version = release
project = "sppo_sb3"
author = "the sppo_sb3 authors"
copyright = "the sppo_sb3 authors"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"

# Data, not pages: the tables and summaries scripts/plot_results.py writes next to its figures. The pages that show them
# include them (docs/results/appendix_tables.md) or offer their files for download.
exclude_patterns = [
    "_build",
    "figures/**",
]

# MyST: anchors for headings down to ####, so that `page.md#a-heading` links resolve as they do on GitHub.
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]

# autodoc: the docstrings use Sphinx's own field lists (:param:, :return:), so no napoleon. Type hints go in the
# description, where long signatures stay readable.
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented"
autodoc_class_signature = "separated"
# A method without a docstring of its own stays without one: the docstrings of gymnasium and SB3 it overrides are
# theirs to render (in their own styles), not this package's.
autodoc_inherit_docstrings = False

html_theme = "furo"
html_title = f"sppo_sb3 {release}"
html_static_path: list[str] = []
