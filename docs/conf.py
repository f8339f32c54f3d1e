"""Sphinx configuration of the cedra documentation site: ./build.sh docs (build/docs/), tests/test_docs.py.

MyST Markdown pages; the FMU reference (reference/) is generated here, at every build, from the one variable table
(cedra.fmu.reference), so it is never typed by hand."""
from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent / "python"))

import cedra  # noqa: E402
from cedra.fmu.reference import write_site_reference  # noqa: E402

write_site_reference(DOCS / "reference")

project = "cedra"
author = "the cedra authors"
copyright = "the cedra authors"
version = release = cedra.__version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown"}
master_doc = "index"
exclude_patterns = ["_build"]
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3
suppress_warnings = []
nitpicky = True
# type hints of external libraries (numpy, casadi, pathlib, ...) have no documentation to link to here (no network:
# no intersphinx); everything of cedra's own is checked
nitpick_ignore_regex = [(r"py:.*", r"^(?!cedra\.).*")]

html_theme = "alabaster"
html_title = f"cedra {release}"
html_static_path: list[str] = []
html_theme_options = {"description": "CEDRA rescue rover dynamics as FMI 2.0 FMUs", "page_width": "1200px",
                      "body_max_width": "none"}

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "undoc-members": False}


def _plain_docstring(app, what, name, obj, options, lines):
    """cedra's docstrings are plain text (code in backticks, aligned tables), not reStructuredText: show them as
    written, in a literal block, instead of letting reST reinterpret indentation and asterisks."""
    if lines:
        text = [ln for ln in lines]
        lines[:] = ["::", ""] + ["    " + ln if ln.strip() else "" for ln in text] + [""]


def setup(app):
    app.connect("autodoc-process-docstring", _plain_docstring)
