"""Sphinx configuration of the dtalign documentation.

Build: ``python -m sphinx -W -b html docs docs/_build/html`` (or ``nox -s docs``).
The package is imported from ``src/`` so the build documents this checkout
even when it is not installed.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import dtalign  # noqa: E402
from dtalign.pipeline.status import _doc_tables  # noqa: E402

# The status page's tables, from the enums themselves (docs/status.rst
# includes the file), so the page cannot list a status or reason the code
# does not have, or miss one; tests/test_docs_status.py holds the committed
# copy equal to this.
_STATUS_TABLES = Path(__file__).resolve().parent / "_generated" / "status_tables.rst"
if not _STATUS_TABLES.is_file() or _STATUS_TABLES.read_text(encoding="utf-8") != _doc_tables():
    _STATUS_TABLES.write_text(_doc_tables(), encoding="utf-8")

project = "dtalign"
author = "dtalign developers"
copyright = "dtalign developers"  # noqa: A001
version = release = dtalign.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
]

# Links to the Python, NumPy, SciPy (and pyarrow) documentation. Each project's
# inventory is downloaded first; without network Sphinx falls back to the
# small local copy in _intersphinx/ (make_fallback.py writes it, listing the
# names these pages link to), so the build passes offline with -W and the
# links point to the same URLs.
_FALLBACK = Path(__file__).resolve().parent / "_intersphinx"
intersphinx_mapping = {
    "python": ("https://docs.python.org/3", (None, str(_FALLBACK / "python.inv"))),
    "numpy": ("https://numpy.org/doc/stable", (None, str(_FALLBACK / "numpy.inv"))),
    "scipy": ("https://docs.scipy.org/doc/scipy", (None, str(_FALLBACK / "scipy.inv"))),
    "pyarrow": ("https://arrow.apache.org/docs", (None, str(_FALLBACK / "pyarrow.inv"))),
}
intersphinx_timeout = 10  # seconds per inventory before the local fallback

# Every cross-reference must resolve: a dead link is a build error under -W.
nitpicky = True
nitpick_ignore = [
    # Numba documents its cache classes in source only (no inventory entry)
    ("py:class", "numba.core.caching.FunctionCache"),
]

# numpydoc: each class documents its attributes in its docstring; do not
# also generate member tables (they would duplicate those entries).
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc Parameters sections carry the types
autodoc_default_options = {"undoc-members": False}

templates_path: list[str] = []
exclude_patterns = ["_build", "_generated", "_intersphinx"]
html_theme = "alabaster"
html_static_path = ["_static"]
# Code blocks hold lines of up to about 130 columns (the command line's
# output): no 800px cap on the body (the basic theme's body_max_width, about
# 80 columns of code), a page wide enough for such lines beside the sidebar,
# and _static/dtalign.css lets a wider block scroll rather than be cut off.
html_css_files = ["dtalign.css"]
html_theme_options = {
    "description": "Sub-pixel polyline alignment against an edge distance transform",
    "fixed_sidebar": True,
    "page_width": "1400px",
    "body_max_width": "none",
}
