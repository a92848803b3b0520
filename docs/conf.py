"""The documentation site (Sphinx): ``make docs`` builds it into ``build/docs``, offline,
every warning an error.

Why Sphinx: the verbs' docstrings are numpydoc (as python-control's and scipy's), which
Sphinx renders natively with autodoc/autosummary and numpydoc; myst-parser reads the
Markdown pages that also read well on a forge and in a terminal; myst-nb renders the
example notebook, executed at build time, so its figures are always what the code draws
now; sphinx-argparse writes the command-line reference from the parser itself.

``make docs-student`` (``-t student``) leaves the instructor notes out: the copy a lab
gives its students.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE / "_ext"))

import labrig  # noqa: E402

project = "labrig"
author = "the labrig developers"
copyright = "2026, the labrig developers (MIT licence)"
version = release = labrig.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "myst_nb",
    "sphinxarg.ext",
    "labrig_catalogue",   # docs/_ext: the effect catalogue from the catalogue itself
]

exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints"]
if tags.has("student"):   # noqa: F821  (Sphinx's own name in conf.py)
    exclude_patterns += ["instructor/**"]
    # the pages that list them (index, teaching) name excluded documents: not an error here
    suppress_warnings = ["toc.excluded", "myst.xref_missing"]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
# the pages are also read on a forge and in a terminal: a link to a file of the repository
# outside docs/ (a config, a test) is a plain link there and a literal here
myst_url_schemes = ["http", "https", "mailto"]

# the example notebook runs at every build (about half a minute): its figures are the
# code's, never a stale picture; a cell that fails fails the build
nb_execution_mode = "force"
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True

autosummary_generate = True
autodoc_typehints = "none"          # numpydoc's Parameters say the types
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "furo"
html_title = f"labrig {release}"
html_show_sourcelink = False
# offline: nothing is fetched (no intersphinx); importing labrig above held numpy's BLAS to
# one thread, and the notebook's kernel inherits it, so its fits are the command line's
