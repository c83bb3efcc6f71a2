"""Shared helpers of the studies: output folder, the command-line convention, timing, tables as
CSV and markdown.

Every study's ``python -m studies.NAME`` runs through :func:`run_study`, which applies the
convention of :mod:`microhom.cli` (the same exit codes as ``python -m microhom`` and
``python -m dem``): 1 for an output that cannot be written or a full disk (one line naming the
path, no traceback), 130 on Ctrl-C with the partial results kept under ``--out``, 141 for a closed
output pipe; every study takes ``--out`` (default ``out/NAME``).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from microhom.cli import EXIT_MACHINE, run_cli

#: exit code of a study whose --out folder cannot be written: the machine's state, the same code
#: as ``python -m dem`` and ``python -m microhom`` give (it was sysexits' 73 before issue 27)
EXIT_NO_OUTPUT = EXIT_MACHINE
_last_out = [None]  # the --out folder of the running study (for the Ctrl-C message)
_under_cli = [False]  # True while run_study runs a main() (report_to tees only then)
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
    reason and exits with :data:`EXIT_NO_OUTPUT` (1): for command-line entry points only.
    With ``cache=True`` the packing cache follows the folder (``OUT/cache/packings``) unless the
    user set ``MICROHOM_CACHE``.
    """
    p = Path(path)
    _last_out[0] = p
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


def run_study(main, argv=None) -> int:
    """``main(argv)`` of a study under the command-line convention (:func:`microhom.cli.run_cli`);
    use as ``raise SystemExit(run_study(main))`` under ``if __name__ == "__main__"``."""
    def kept():
        where = _last_out[0]
        return (f"the finished results and cached packings are kept under {where}; the same "
                "command resumes from them" if where is not None else None)
    _under_cli[0] = True
    old = sys.stdout
    try:
        return run_cli(main, argv, partial=kept)
    finally:
        _under_cli[0] = False
        if sys.stdout is not old:   # a report_to tee: flushed and undone
            try:
                sys.stdout.flush()
            except OSError:
                pass
            sys.stdout = old


def add_out(ap, name: str):
    """Add ``--out`` (default ``out/NAME``) to a study's argument parser."""
    ap.add_argument("--out", default=f"out/{name}",
                    help=f"output folder (default out/{name}); checked before computing")
    return ap


@contextmanager
def tee(folder, name="report.txt"):
    """``with tee(out): ...`` copies what the block prints to ``out/name`` as well (benchmarks
    that print figures keep them under ``--out``)."""
    path = Path(folder) / name
    old = sys.stdout

    class _Tee:
        def __init__(self, fh):
            self.fh = fh

        def write(self, text):
            old.write(text)
            self.fh.write(text)
            return len(text)

        def flush(self):
            old.flush()
            self.fh.flush()

    with open(path, "w") as fh:
        sys.stdout = _Tee(fh)
        try:
            yield path
        finally:
            sys.stdout = old


def report_to(folder, name="report.txt"):
    """Under :func:`run_study` (the command line), copy what the study prints to ``folder/name``
    as well, until the study ends (benchmarks whose result is the figures they print); returns
    the report's path. A ``main()`` called from Python (the tests) prints as usual: None."""
    if not _under_cli[0]:
        return None
    path = Path(folder) / name
    fh = open(path, "w")
    old = sys.stdout

    class _Tee:
        encoding = getattr(old, "encoding", "utf-8")

        def write(self, text):
            old.write(text)
            fh.write(text)
            return len(text)

        def flush(self):
            old.flush()
            fh.flush()

        def isatty(self):
            return False

    sys.stdout = _Tee()
    return path


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
