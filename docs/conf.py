"""Sphinx configuration: MyST Markdown pages, the furo theme, an API reference generated from docstrings.

Built by the test suite with warnings as errors (tests/test_docs.py): ``sphinx-build -W -b html docs BUILD``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

from plm_highway._version import __version__  # noqa: E402

project = "plm-highway"
author = "the plm-highway maintainers"
version = release = __version__
# Targeted automodule directives only (docs/api.md): a recursive autosummary over the whole package takes minutes.
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3
html_theme = "furo"
html_title = "plm-highway"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
# A report page includes its committed report; one whose report is not committed yet is left out of the site
# (the index lists the reports by glob, so nothing points at it).
REPORTS = {"reports/population.md": ROOT / "figures/population/report.md",
           "reports/mitigations.md": ROOT / "figures/mitigations/report.md"}
exclude_patterns += [page for page, report in REPORTS.items() if not report.is_file()]
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# Pages link to committed files outside docs/ (reports' CSVs, figures): MyST cannot resolve those as documents.
# The sim2real reference abbreviates a JSON example with "...", which Pygments' JSON lexer refuses.
suppress_warnings = ["myst.xref_missing", "myst.header", "misc.highlighting_failure"]
