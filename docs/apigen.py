"""Write one API page per public module of ``microhom`` and ``dem`` (docs/api/*.rst).

Called by ``conf.py`` at every build, so the reference follows the code: a new module appears by
itself. A module is public if neither it nor a parent package starts with an underscore and it is
not a command-line entry (``__main__``). Each page documents the names in the module's ``__all__``
(autodoc's default), so an undocumented public name shows up as an empty entry, and the test
``tests/test_docstrings.py`` fails on it.
"""
from __future__ import annotations

import importlib
import os
import pkgutil

PACKAGES = ("microhom", "dem")
TITLES = {"microhom": "microhom: the theory", "dem": "dem: the discrete methods"}


def public_modules(package):
    """Sorted public module names below ``package`` (the package itself included)."""
    pkg = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(pkg.__path__, prefix=package + "."):
        parts = info.name.split(".")
        if any(p.startswith("_") for p in parts):
            continue
        names.append(info.name)
    return sorted(names)


def write_api_pages(docs_dir):
    out = os.path.join(docs_dir, "api")
    os.makedirs(out, exist_ok=True)
    index = ["API reference", "=============", "",
             "Generated from the docstrings. Units, shapes and the paper's equation numbers are "
             "stated there.", ""]
    for package in PACKAGES:
        index += [TITLES[package], "-" * len(TITLES[package]), "", ".. toctree::", "   :maxdepth: 1", ""]
        for mod in public_modules(package):
            index.append(f"   {mod}")
            body = [mod, "=" * len(mod), "", f".. automodule:: {mod}", "   :members:", ""]
            _write(os.path.join(out, f"{mod}.rst"), "\n".join(body))
        index.append("")
    _write(os.path.join(out, "index.rst"), "\n".join(index))
    written = {f"{m}.rst" for p in PACKAGES for m in public_modules(p)} | {"index.rst"}
    for name in os.listdir(out):            # pages of modules that no longer exist
        if name.endswith(".rst") and name not in written:
            os.remove(os.path.join(out, name))


def _write(path, text):
    old = open(path).read() if os.path.exists(path) else None
    if old != text:                      # keep mtimes (Sphinx's incremental build) when unchanged
        with open(path, "w") as fh:
            fh.write(text)
