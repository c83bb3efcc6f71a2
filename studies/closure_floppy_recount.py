"""Recount the ``n_floppy`` column of ``studies/closure_corpus.csv`` with the current exact solver.

    python -m studies.closure_floppy_recount --cache DIR [DIR ...] [--csv studies/closure_corpus.csv]
                                             [--out DIR] [--write]

The column predates the floppy-count fix (issue 22: the SuperLU rescaling rule and the rigidity
check of ``dem.analysis.stiffness``). For every corpus row whose packing (``KEY.npz``) is in one of
the caches (read only), the network as ``studies.corpus.measure_network`` analyses it (kt = kt/kn
kn; ``pack_frictionless`` with no contact sliding) is solved again without pre-stress
(``stiffness(prestress=False)``) and its ``n_floppy``, ``flags``, K and G are compared with the
row's, and with the pebble game's floppy count (``microhom.rigidity.pebble_game``, a second
method, on the state ``studies.closure_rigidity`` plays it on). Writes ``floppy_recount.csv`` (every recounted row: old and new) under ``--out``; with
``--write`` also replaces ``n_floppy`` of the recounted rows in ``--csv`` (and, on the rows whose
count changed, ``flags``, whose message quotes the count; K, G and every other column are kept).
Rows whose packing is in no cache keep their value and are counted as such.
"""
from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from dem.analysis.stiffness import stiffness
from studies.closure_fit import SUMMARY
from microhom.rigidity import pebble_game
from studies.closure_rigidity import _state
from studies.corpus import _load_network


def recount(df, caches, verbose=True) -> pd.DataFrame:
    """One row per corpus row with a cached packing: key, kt/kn, old and new n_floppy, flags, K, G."""
    out = []
    for key, g in df.groupby("key", sort=True):
        path = next((Path(c) / f"{key}.npz" for c in caches if (Path(c) / f"{key}.npz").exists()), None)
        if path is None:
            continue
        net, _ = _load_network(path)
        if g.protocol.iloc[0] == "pack_frictionless":
            net = net.with_stiffness(sliding=False)
        t0 = time.process_time()
        game = {}
        for i, r in g.iterrows():
            if (r.kt_over_kn > 0) not in game:    # the second method: the pebble game's count
                game[r.kt_over_kn > 0] = pebble_game(_state(net, r.protocol, float(r.kt_over_kn))).n_floppy
            nk = net.with_stiffness(kt=float(r.kt_over_kn) * np.asarray(net.kn))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    ex = stiffness(nk, prestress=False)
                except (ValueError, RuntimeError) as exc:
                    out.append(dict(row=i, key=key, kt_over_kn=r.kt_over_kn, n_floppy_old=r.n_floppy,
                                    n_floppy_new=np.nan, note=str(exc)[:120]))
                    continue
            out.append(dict(row=i, key=key, protocol=r.protocol, kt_over_kn=r.kt_over_kn,
                            n_floppy_old=r.n_floppy, n_floppy_new=ex.n_floppy, game_n_floppy=game[r.kt_over_kn > 0],
                            flags_old=r["flags"], flags_new=";".join(sorted(ex.flags)) if ex.flags else "",
                            K_old=r.K, K_new=ex.K, G_old=r.G, G_new=ex.G, solver=ex.solver))
        if verbose:
            print(f"{key}: {len(g)} rows, {time.process_time() - t0:.1f} s CPU", flush=True)
    return pd.DataFrame(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", nargs="+", required=True)
    ap.add_argument("--csv", default=str(SUMMARY))
    ap.add_argument("--out", default="out/closure")
    ap.add_argument("--write", action="store_true", help="replace n_floppy of the recounted rows in --csv")
    a = ap.parse_args(argv)
    df = pd.read_csv(a.csv, keep_default_na=False, na_values=[""])
    rc = recount(df, a.cache)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    rc.to_csv(Path(a.out) / "floppy_recount.csv", index=False)
    ch = rc[rc.n_floppy_new.notna() & (rc.n_floppy_new != rc.n_floppy_old)]
    print(f"{len(rc)} of {len(df)} rows recounted ({df.key.nunique() - rc.key.nunique()} packings not cached); "
          f"{len(ch)} changed")
    if len(ch):
        print(ch[["key", "kt_over_kn", "n_floppy_old", "n_floppy_new", "game_n_floppy"]].to_string())
    for name, col in (("before", "n_floppy_old"), ("after", "n_floppy_new")):
        print(f"{name}: the exact count equals the pebble game's on {int((rc[col] == rc.game_n_floppy).sum())} "
              f"of {len(rc)} rows")
    print(f"flags changed on {int((rc.flags_old.fillna('') != rc.flags_new).sum())} rows; largest K, G change "
          f"(absolute): {np.nanmax(np.abs(rc.K_new - rc.K_old)):.2e}, "
          f"{np.nanmax(np.abs(rc.G_new - rc.G_old)):.2e}")
    if a.write:
        ok = rc[rc.n_floppy_new.notna()]
        df.loc[ok.row.to_numpy(), "n_floppy"] = ok.n_floppy_new.astype(int).to_numpy()
        # the flag message quotes the count: rewritten on the changed rows (flagged before and after)
        df.loc[ch.row.to_numpy(), "flags"] = ch.flags_new.to_numpy()
        df.to_csv(a.csv, index=False)
        print(f"written: {a.csv} (n_floppy of {len(ok)} rows; {len(ch)} changed, their flags' message too)")
    return 0


if __name__ == "__main__":
    main()
