"""The README's snippets run verbatim (issue 27 (f)): every ``python`` block defines or imports
each name it uses (fast, by its syntax tree), runs in a fresh interpreter from the repository root
(slow: each makes a small packing), and the ``python -m microhom`` lines of its ``bash`` blocks
exit as documented."""
import ast
import builtins
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
BLOCKS = re.findall(r"```(\w+)\n(.*?)```", README, flags=re.S)
PYTHON = [code for lang, code in BLOCKS if lang == "python"]
BASH = [code for lang, code in BLOCKS if lang == "bash"]


def undefined_names(code: str) -> set:
    """Names a snippet reads that it neither assigns, imports nor gets from builtins (in the order
    of the statements: a name used before its assignment counts as undefined)."""
    tree = ast.parse(code)
    defined, missing = set(dir(builtins)), set()
    for stmt in tree.body:
        local = set()
        for node in ast.walk(stmt):
            if isinstance(node, ast.Lambda):
                local |= {a.arg for a in node.args.args}
        for node in ast.walk(stmt):
            if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load):
                if node.id not in defined and node.id not in local:
                    missing.add(node.id)
        for node in ast.walk(stmt):
            if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                defined.add(node.id)
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                defined |= {(a.asname or a.name).split(".")[0] for a in node.names}
    return missing


def test_readme_has_snippets():
    assert len(PYTHON) >= 4 and BASH


def test_the_checker_finds_a_nameerror():
    """The check can fail: the old snippet 2 used positions, radii and cell from nowhere."""
    old = "from microhom.network import from_overlaps\nnet = from_overlaps(positions, radii, cell)\n"
    assert undefined_names(old) == {"positions", "radii", "cell"}


@pytest.mark.parametrize("k", range(len(PYTHON)))
def test_python_snippet_defines_what_it_uses(k):
    assert undefined_names(PYTHON[k]) == set(), PYTHON[k]


@pytest.mark.slow
@pytest.mark.parametrize("k", range(len(PYTHON)))
def test_python_snippet_runs_verbatim(k, tmp_path):
    """Each block in a fresh interpreter, from the repository root (where ``python -m`` finds the
    packages without installation), with a private packing cache."""
    env = {"PYTHONPATH": str(ROOT), "MICROHOM_CACHE": str(tmp_path / "cache"),
           "NUMBA_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    p = subprocess.run([sys.executable, "-c", PYTHON[k]], cwd=ROOT, capture_output=True,
                       text=True, timeout=900, env=env)
    assert p.returncode == 0, p.stderr[-3000:]


def microhom_lines():
    for block in BASH:
        for line in block.splitlines():
            cmd = line.split("#", 1)[0].strip()
            if cmd.startswith("python -m microhom "):
                yield cmd


@pytest.mark.parametrize("cmd", list(microhom_lines()))
def test_microhom_command_lines_run(cmd):
    args = shlex.split(cmd)[1:]
    p = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
