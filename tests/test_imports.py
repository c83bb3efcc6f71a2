"""Imports point one way: studies -> dem -> microhom. ``microhom`` never imports ``dem`` or
``studies`` and ``dem`` never imports ``studies`` - anywhere in the source, imports inside
functions included (every ``import``/``from`` node of the parsed module, not only the top level).
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {"microhom": ("dem", "studies"), "dem": ("studies",)}


def _imported(tree, module_parts):
    """Absolute top-level package of every import in ``tree`` (relative imports resolved)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                yield node.lineno, (node.module or "").split(".")[0]
            else:
                base = module_parts[:len(module_parts) - node.level]
                yield node.lineno, (base + [node.module or ""])[0] if base else ""


def violations(package):
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = path.relative_to(ROOT)
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        parts = parts + ["_"]          # a module's own package is one level up
        for line, top in _imported(ast.parse(path.read_text(), str(rel)), parts):
            if top in FORBIDDEN[package]:
                out.append(f"{rel}:{line} imports {top}")
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_one_way(package):
    found = violations(package)
    assert not found, f"{package} must not import {FORBIDDEN[package]}:\n" + "\n".join(found)


def test_the_checker_sees_lazy_and_relative_imports(tmp_path):
    src = ("import numpy\nfrom . import network\n\ndef f():\n    import dem.stiffness\n"
           "    from studies.runner import run_cases\n    from .. import studies\n")
    found = [top for _, top in _imported(ast.parse(src), ["microhom", "sub", "_"])]
    assert found == ["numpy", "microhom", "dem", "studies", "microhom"]
