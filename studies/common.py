"""Shared helpers of the studies: output folder, timing, tables as CSV and markdown."""
from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd


def out_dir(path) -> Path:
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
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
