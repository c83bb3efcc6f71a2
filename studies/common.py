"""Shared helpers of the studies: output folder, timing, tables as CSV and markdown."""
from __future__ import annotations

import os
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

#: exit code of a study whose --out folder cannot be written (sysexits' EX_CANTCREAT)
EXIT_NO_OUTPUT = 73
_CACHE_ENV = "MICROHOM_CACHE"
_cache_set_here = [None]  # the value this module put in MICROHOM_CACHE, if any


def out_dir(path) -> Path:
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
    return p


def cli_out_dir(path, *, cache=True) -> Path:
    """The ``--out`` folder of a study's ``main()``, checked *before* any computing.

    Creates the folder and writes (then removes) a probe file in it. If that fails (read-only
    folder, a path under a regular file, a full disk), prints one line naming the folder and the
    reason and exits with :data:`EXIT_NO_OUTPUT` (73): for command-line entry points only.
    With ``cache=True`` the packing cache follows the folder (``OUT/cache/packings``) unless the
    user set ``MICROHOM_CACHE``.
    """
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=p, prefix=".probe_"):
            pass
        if cache:
            cache_dir = p / "cache" / "packings"
            if os.environ.get(_CACHE_ENV) in (None, _cache_set_here[0]):  # not the user's
                os.environ[_CACHE_ENV] = str(cache_dir)
                _cache_set_here[0] = str(cache_dir)
            c = Path(os.environ[_CACHE_ENV])
            c.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=c, prefix=".probe_"):
                pass
    except OSError as exc:
        where = exc.filename or p
        print(f"error: --out {p}: cannot write to {where} ({exc.strerror or exc}); nothing was "
              f"computed", file=sys.stderr)
        raise SystemExit(EXIT_NO_OUTPUT) from None
    return p


@contextmanager
def timer():
    """``with timer() as t: ...`` then ``t()`` is the elapsed wall time [s]."""
    t0 = time.perf_counter()
    box = [None]
    yield lambda: box[0] if box[0] is not None else time.perf_counter() - t0
    box[0] = time.perf_counter() - t0


def markdown_table(df: pd.DataFrame, floatfmt="{:.4g}") -> str:
    """A GitHub markdown table without the optional tabulate dependency."""
    def cell(v):
        if isinstance(v, float):
            return floatfmt.format(v)
        return str(v).replace("|", "\\|")
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    sep = "|" + "|".join("---" for _ in df.columns) + "|"
    rows = ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join([head, sep, *rows])


def write_table(df: pd.DataFrame, folder, name: str, title: str = "", notes: str = "") -> Path:
    """Write ``name.csv`` and ``name.md`` (title, table, notes) into ``folder``; return the md path."""
    folder = out_dir(folder)
    df.to_csv(folder / f"{name}.csv", index=False)
    md = folder / f"{name}.md"
    md.write_text((f"# {title}\n\n" if title else "") + markdown_table(df) + ("\n\n" + notes if notes else "") + "\n")
    return md
