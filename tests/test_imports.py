"""The layout's nevers, checked on every ``import``/``from`` node of the source (imports inside
functions included, relative imports resolved), and once more at run time.

Arrows: studies -> dem -> microhom. Inside ``dem``:

* ``dem.engine`` (the simulator) never imports the free-hexagon method or the scenes;
* ``dem.analysis`` (what analyses a contact network) never imports the simulator, so a packing
  from any code is analysed without the DEM (``dem.engine``);
* ``dem.io`` (readers and writers) imports neither the simulator nor the analysis;
* ``dem.hexagons`` (the second discrete method) imports neither the disk engine, the analysis nor
  the scenes; ``dem.runtime`` (what both methods share) imports nothing of ``dem``;
* ``microhom`` never imports ``dem`` or ``studies``.
"""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# package (or module) -> the packages its source must never import
NEVER = {
    "microhom": ("dem", "studies"),
    "dem": ("studies",),
    "dem.engine": ("dem.hexagons", "dem.scenes", "studies"),
    "dem.analysis": ("dem.engine", "dem.hexagons", "dem.scenes"),
    "dem.io": ("dem.engine", "dem.analysis", "dem.hexagons", "dem.scenes"),
    "dem.hexagons": ("dem.engine", "dem.analysis", "dem.scenes", "dem.io"),
    "dem.runtime": ("dem.engine", "dem.analysis", "dem.hexagons", "dem.scenes", "dem.io"),
}


def _imported(tree, package_parts):
    """Absolute dotted name of every import in ``tree`` (relative imports resolved against the
    module's package ``package_parts``); ``from a import b`` yields ``a.b`` as well as ``a``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parent = package_parts[:len(package_parts) - (node.level - 1)]
                base = ".".join(parent + ([node.module] if node.module else []))
            yield node.lineno, base
            for a in node.names:
                yield node.lineno, f"{base}.{a.name}"


def _module_files(dotted):
    path = ROOT.joinpath(*dotted.split("."))
    if path.is_dir():
        return sorted(path.rglob("*.py"))
    return [path.with_suffix(".py")]


def _within(name, package):
    return name == package or name.startswith(package + ".")


def violations(package):
    out = []
    for path in _module_files(package):
        rel = path.relative_to(ROOT)
        parts = list(rel.with_suffix("").parts)
        pkg = parts[:-1]          # the package a module sits in (an __init__'s is its own folder)
        for line, name in _imported(ast.parse(path.read_text(), str(rel)), pkg):
            for never in NEVER[package]:
                if _within(name, never) and not _within(package, never):
                    out.append(f"{rel}:{line} imports {name}")
    return sorted(set(out))


@pytest.mark.parametrize("package", sorted(NEVER))
def test_imports_point_one_way(package):
    assert _module_files(package), f"{package} does not exist: update NEVER with the layout"
    found = violations(package)
    assert not found, f"{package} must not import {NEVER[package]}:\n" + "\n".join(found)


def test_the_checker_sees_lazy_relative_and_from_imports():
    src = ("import numpy\nfrom . import network\n\ndef f():\n    import dem.analysis.stiffness\n"
           "    from studies.runner import run_cases\n    from .. import engine\n"
           "    from ..engine.packing import pack\n")
    found = [name for _, name in _imported(ast.parse(src), ["dem", "analysis"])]
    assert "dem.analysis.network" in found and "dem.analysis.stiffness" in found
    assert "studies.runner" in found and "dem.engine" in found and "dem.engine.packing" in found


def test_a_broken_never_fails(tmp_path, monkeypatch):
    """The checker is not vacuous: a lazy upward import planted in a copy is reported."""
    pkg = tmp_path / "dem" / "analysis"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "bad.py").write_text("def f():\n    from ..engine import packing\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert violations("dem.analysis") == ["dem/analysis/bad.py:2 imports dem.engine",
                                          "dem/analysis/bad.py:2 imports dem.engine.packing"]


@pytest.mark.parametrize("module, absent", [
    ("dem.analysis.stiffness", "dem.engine"),
    ("dem.analysis.analyse", "dem.engine"),
    ("microhom.hierarchy", "dem"),
    ("dem.io", "dem.engine"),
])
def test_importing_does_not_load(module, absent):
    """At run time too: importing the analysis loads no simulator module (a fresh interpreter)."""
    code = (f"import sys, importlib; importlib.import_module({module!r}); "
            f"bad = sorted(m for m in sys.modules if m == {absent!r} or m.startswith({absent!r} + '.')); "
            "print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "", f"importing {module} loaded {out}"
