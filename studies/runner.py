"""Run independent study cases serially or on Dask, resumably, into one pandas table.

A *case* is a dict of JSON-serialisable parameters (including its seed). Its key ``case_id`` is a
hash of the canonical JSON of the dict, so a re-run recognises finished cases and skips them: an
interrupted sweep resumes where it stopped. Each finished case is written to the CSV at once
(atomically, through :func:`dem.runtime.atomic_write`). A case that raises is recorded with
``status="error"`` and its message, and does not stop the others (it is retried on the next run).

The returned table is ordered like the case list, whatever order the cases finished in, so a run on
a Dask cluster gives the same table as a serial run (apart from ``wall_time_s``).

Dask is optional (extra ``dist``): ``scheduler="local"`` starts a ``LocalCluster`` sized to the
machine (or ``workers``), ``scheduler="tcp://host:port"`` uses an existing cluster of any size,
``scheduler=None`` runs serially in this process.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
import traceback
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from dem.runtime import atomic_write
from microhom.moduli import predict_from_network
from microhom.network import from_overlaps

TIMING_COLUMNS = ("wall_time_s",)


def case_id(case: dict) -> str:
    """Stable 16-hex-digit key of a case (canonical JSON, sorted keys)."""
    text = json.dumps(case, sort_keys=True, default=float)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _run_one(fn, case):
    t0 = time.perf_counter()
    row = {"case_id": case_id(case), **case}
    try:
        res = fn(dict(case))
        row.update({k: (v.item() if isinstance(v, np.generic) else v) for k, v in res.items()})
        row["status"], row["error"] = "ok", ""
    except Exception as exc:  # recorded, never fatal to the sweep
        row["status"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=5)
    row["wall_time_s"] = time.perf_counter() - t0
    return row


def _write(rows: dict, order: list, path: Path):
    df = _table(rows, order)
    atomic_write(path, lambda fh: df.to_csv(fh, index=False), binary=False)


def _table(rows: dict, order: list) -> pd.DataFrame:
    known = [k for k in order if k in rows] + [k for k in rows if k not in set(order)]
    return pd.DataFrame([rows[k] for k in known])


def _client(scheduler, workers):
    from dask.distributed import Client, LocalCluster

    if scheduler == "local":
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
        return Client(cluster), cluster
    return Client(scheduler), None


def run_cases(fn: Callable[[dict], dict], cases: list[dict], out_csv, *, scheduler=None, workers=None,
              progress=True, retry_failed=True) -> pd.DataFrame:
    """Run ``fn(case) -> dict of results`` for every case; resume from ``out_csv`` if it exists.

    Parameters
    ----------
    fn : a picklable top-level function (Dask sends it to the workers).
    cases : list of parameter dicts (must be JSON-serialisable; include the seed).
    out_csv : path of the results table, written after every finished case.
    scheduler : None (serial), "local" (LocalCluster), or a Dask scheduler address.
    workers : number of local workers for ``scheduler="local"`` (default: CPU count).
    retry_failed : re-run cases recorded with status "error".
    """
    out_csv = Path(out_csv)
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    ids = [case_id(c) for c in cases]
    if len(set(ids)) != len(ids):
        raise ValueError("cases contains duplicates (identical parameter dicts)")
    rows = {}
    if out_csv.exists():
        old = _read(out_csv)
        for rec in old.to_dict("records"):
            if rec.get("status") == "ok" or not retry_failed:
                rows[rec["case_id"]] = rec
    todo = [c for c, k in zip(cases, ids) if k not in rows]
    bar = None
    if progress and todo:
        bar = tqdm(total=len(todo), desc=f"cases ({len(cases) - len(todo)} already done)", unit="case")
    if scheduler is None:
        for c in todo:
            row = _run_one(fn, c)
            rows[row["case_id"]] = row
            _write(rows, ids, out_csv)
            if bar:
                bar.update()
    else:
        from dask.distributed import as_completed

        client, cluster = _client(scheduler, workers)
        try:
            futures = client.map(_run_one, [fn] * len(todo), todo, pure=False)
            for fut in as_completed(futures):
                row = fut.result()
                rows[row["case_id"]] = row
                _write(rows, ids, out_csv)
                if bar:
                    bar.update()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    if bar:
        bar.close()
    _write(rows, ids, out_csv)
    return _read(out_csv)


def _read(path) -> pd.DataFrame:
    """Read a results table so that fresh and resumed runs give identically typed tables."""
    df = pd.read_csv(path, keep_default_na=False, na_values=[""])
    for col in ("status", "error", "traceback"):
        if col in df:
            df[col] = df[col].astype(object).where(df[col].notna(), "")
    return df


def demo_case(case: dict) -> dict:
    """A small deterministic case for tests and overhead benchmarks: theory moduli of a random network.

    case: {"seed": int, "n": int (particles), "kt_over_kn": float, optional "fail": bool}.
    """
    if case.get("fail"):
        raise RuntimeError(f"case with seed {case['seed']} asked to fail")
    rng = np.random.default_rng(case["seed"])
    n = int(case.get("n", 400))
    L = float(np.sqrt(n * np.pi * 0.25 / 0.80))  # solid fraction 0.8 (random, overlapping points)
    net = from_overlaps(rng.uniform(0, L, (n, 2)), 0.5, np.diag([L, L]), kn=1.0,
                        kt=case.get("kt_over_kn", 1.0))
    p = predict_from_network(net, warn=False)
    return {"nc": float(np.mean(net.contact_counts())), "K_mf": float(p.K_mf), "G_mf": float(p.G_mf),
            "K": float(p.K), "G": float(p.G), "rho": float(p.rho)}
