"""Sphinx configuration of the microhom documentation site.

Built with Sphinx + MyST (the pages are markdown), myst-nb (tutorials are MyST-markdown notebooks,
executed at every build) and autodoc/napoleon (the API reference comes from the docstrings).
Build: ``python -m sphinx -W --keep-going -n -b html docs docs/_build/html`` (see README).
"""
import os
import sys

sys.path.insert(0, os.path.abspath(".."))
sys.path.insert(0, os.path.abspath("."))

import apigen  # noqa: E402  (docs/apigen.py writes docs/api/*.rst from the packages)

project = "microhom"
author = "the microhom developers"
copyright = "2026, the microhom developers"

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "IPython.sphinxext.ipython_console_highlighting",   # the ipython3 lexer of executed cells
]

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence"]
myst_heading_anchors = 3
nb_execution_mode = "force"          # every tutorial runs at every build
nb_execution_timeout = 900
nb_execution_raise_on_error = True   # a failing notebook fails the build
nb_execution_show_tb = True

autodoc_member_order = "bysource"
autodoc_typehints = "none"           # the docstrings state types, units and shapes
# no "show-inheritance" key: autodoc treats any value, False included, as the flag being set
# (it then lists private bases such as dem.engine.contact_laws._Composed)
autodoc_default_options = {"members": True}
napoleon_numpy_docstring = True
napoleon_google_docstring = False
napoleon_use_rtype = False
napoleon_use_param = False       # parameter types are free text (shapes, units), not cross-references
napoleon_use_ivar = True
# "Attributes" (the fields of result dataclasses) rendered like "Parameters": their types are free
# text with shapes and units, e.g. "(S,) int array", not cross-references
napoleon_custom_sections = [("Attributes", "params_style")]

nitpicky = True
# names from libraries we do not link to (no network at build time, so no intersphinx)
nitpick_ignore_regex = [
    (r"py:.*", r"(np|numpy|scipy|sp|pd|pandas|matplotlib|numba|sympy|dask|meshio)\..*"),
    (r"py:class", r"(optional|array_like|array|ndarray|callable|bool|int|float|str|dict|list|tuple|None|path-like|file-like|object)"),
]

exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints", "jupyter_execute"]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}

html_theme = "furo"
html_title = "microhom"
html_static_path = []

apigen.write_api_pages(os.path.dirname(os.path.abspath(__file__)))
