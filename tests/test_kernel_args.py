"""Issue 23: no numba kernel in ``dem`` and ``microhom`` takes more than 10 arguments.

A kernel is a function decorated with numba's ``njit`` or ``jit`` (``@njit``, ``@njit(cache=True)``,
``@numba.njit``, ``@nb.jit(...)``), found by ``ast`` in the source. Its arguments are counted as
Python counts them (positional, keyword-only, ``*args`` and ``**kwargs`` one each). A longer list
should become named bundles (the disk engine's kernels read ``Bodies``, ``Pairs``, ``Models`` and
``Forces`` tuples, ``dem.engine.contact_models``). One passes only if the line just above its first
decorator is a comment ``# many args: <why>`` (e.g. a hot loop where bundling was measured slower),
or if it is in ``ALLOWED`` below: kernels another branch is bundling.
``tests/test_contact_laws.py`` checks the pair loop and the kick by their signatures as well.
"""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGES = ("dem", "microhom")
MAX_ARGS = 10
DECORATORS = ("njit", "jit")

#: (path relative to the repository, kernel name) -> why it is allowed for now; the entries go when
#: the kernel is bundled (the test below fails on an entry that no longer needs it). Empty since the
#: dual bound's statics kernels read _Graph/_Order/_Tree bundles.
ALLOWED = {}


def _decorator_name(d):
    """``njit`` for ``@njit``, ``@njit(...)``, ``@numba.njit``, ``@nb.njit(...)``; else None."""
    if isinstance(d, ast.Call):
        d = d.func
    if isinstance(d, ast.Name):
        return d.id
    if isinstance(d, ast.Attribute):
        return d.attr
    return None


def n_args(node) -> int:
    """Number of arguments of the function ``node`` (``*args``, ``**kwargs`` one each)."""
    a = node.args
    return (len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None)
            + (a.kwarg is not None))


def kernels(text):
    """(name, lineno, n_args, has_many_args_comment) of every njit/jit function in ``text``."""
    lines = text.splitlines()
    out = []
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        if not any(_decorator_name(d) in DECORATORS for d in node.decorator_list):
            continue
        above = min(d.lineno for d in node.decorator_list) - 2       # 0-based index of the line above
        mark = lines[above].strip() if above >= 0 else ""
        marked = mark.startswith("# many args:") and len(mark) > len("# many args:")
        out.append((node.name, node.lineno, n_args(node), marked))
    return out


def long_kernels(text, max_args=MAX_ARGS):
    """The entries of :func:`kernels` with more than ``max_args`` arguments."""
    return [k for k in kernels(text) if k[2] > max_args]


def _sources():
    for pkg in PACKAGES:
        yield from sorted((ROOT / pkg).rglob("*.py"))


def test_no_kernel_over_10_arguments_unless_marked_or_allowed():
    offenders = []
    for path in _sources():
        rel = path.relative_to(ROOT).as_posix()
        for name, lineno, n, marked in long_kernels(path.read_text(encoding="utf-8")):
            if marked or (rel, name) in ALLOWED:
                continue
            offenders.append(f"{rel}:{lineno} {name} ({n} arguments > {MAX_ARGS})")
    assert not offenders, ("bundle these kernels' arguments into named tuples, or mark a hot loop "
                           "where bundling was measured slower with '# many args: <why>' on the line "
                           "above its first decorator:\n" + "\n".join(offenders))


def test_the_walk_finds_the_known_kernels():
    """The walk sees numba kernels at all: the engine's pair loop and kick, a neighbour search."""
    found = {(p.relative_to(ROOT).as_posix(), k[0]) for p in _sources()
             for k in kernels(p.read_text(encoding="utf-8"))}
    assert {("dem/engine/contact_models.py", "kick_range"), ("dem/engine/neighbors.py", "_find_pairs"),
            ("dem/engine/contact_models.py", "_chunked")} <= found
    assert len(found) > 50


def test_allow_list_entries_exist_and_are_still_long():
    """A stale entry (kernel gone or already bundled) hides nothing and misleads: remove it."""
    for (rel, name), why in ALLOWED.items():
        assert why
        found = [k for k in long_kernels((ROOT / rel).read_text(encoding="utf-8")) if k[0] == name]
        assert found, f"{rel} {name} takes at most {MAX_ARGS} arguments now: remove it from ALLOWED"


def _args(n):
    return ", ".join(f"a{i}" for i in range(n))


@pytest.mark.parametrize("src, expected", [
    (f"@njit\ndef f({_args(10)}):\n    pass\n", []),                                         # at the limit
    (f"@njit\ndef f({_args(11)}):\n    pass\n", [("f", 2, 11, False)]),                      # one over
    (f"@njit(cache=True)\ndef f({_args(11)}):\n    pass\n", [("f", 2, 11, False)]),          # called
    (f"@numba.njit\ndef f({_args(11)}):\n    pass\n", [("f", 2, 11, False)]),                # attribute
    (f"@nb.jit(nopython=True)\ndef f({_args(11)}):\n    pass\n", [("f", 2, 11, False)]),     # jit
    (f"def f({_args(11)}):\n    pass\n", []),                                                # not a kernel
    (f"@njit\ndef f({_args(8)}, *a, k=1, **kw):\n    pass\n", [("f", 2, 11, False)]),        # every kind
    (f"# many args: measured\n@njit\ndef f({_args(11)}):\n    pass\n", [("f", 3, 11, True)]),
    (f"# many args:\n@njit\ndef f({_args(11)}):\n    pass\n", [("f", 3, 11, False)]),        # no reason
    (f"# many args: x\n@njit\n@other\ndef f({_args(11)}):\n    pass\n", [("f", 4, 11, True)]),
    (f"@other\n# many args: x\n@njit\ndef f({_args(11)}):\n    pass\n", [("f", 4, 11, False)]),  # not above the first
])
def test_the_counter_on_known_cases(src, expected):
    """Exact cases of what counts as a kernel, how arguments count, and where the mark must be."""
    assert long_kernels(src) == expected
