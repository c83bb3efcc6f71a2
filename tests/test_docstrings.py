"""Every public name of microhom and dem has a docstring, and every field of a result dataclass is
documented in its class docstring (the API reference of the documentation site is built from them).

Public: the names in a module's ``__all__`` (modules without ``__all__`` fail: they must say what is
public), in every module the documentation's API pages list (``docs/apigen.py``'s rule: no
underscore in the module path, no ``__main__``).
"""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil

import pytest

PACKAGES = ("microhom", "dem")


def _public_modules():
    out = []
    for package in PACKAGES:
        pkg = importlib.import_module(package)
        out.append(package)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=package + "."):
            if any(p.startswith("_") for p in info.name.split(".")):
                continue
            out.append(info.name)
    return sorted(out)


MODULES = _public_modules()

@pytest.mark.parametrize("modname", MODULES)
def test_module_has_docstring_and_all(modname):
    mod = importlib.import_module(modname)
    assert (mod.__doc__ or "").strip(), f"module {modname} has no docstring"
    assert hasattr(mod, "__all__"), f"module {modname} does not declare __all__ (what is public?)"
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f"{modname}.__all__ names missing attributes: {missing}"


@pytest.mark.parametrize("modname", MODULES)
def test_public_names_documented(modname):
    mod = importlib.import_module(modname)
    undocumented = []
    for name in getattr(mod, "__all__", []):
        obj = getattr(mod, name)
        if not (inspect.isfunction(obj) or inspect.isclass(obj) or callable(obj)):
            continue                                    # constants are documented in the module
        doc = inspect.getdoc(obj) or ""
        if inspect.isclass(obj) and doc == (inspect.getdoc(obj.__mro__[1]) or None):
            doc = ""                                    # inherited docstring only
        if not doc.strip():
            undocumented.append(name)
            continue
        if inspect.isclass(obj) and dataclasses.is_dataclass(obj):
            own = obj.__dict__.get("__doc__") or ""
            fields = [f.name for f in dataclasses.fields(obj) if f.repr or f.metadata.get("export", True)]
            absent = [f for f in fields if f not in own]
            if absent:
                undocumented.append(f"{name} (fields {absent})")
    assert not undocumented, f"{modname}: undocumented public names: {undocumented}"
