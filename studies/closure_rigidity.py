"""Rigid-cluster statistics of the closure corpus by the pebble game (issue 25, item 2), and the
check of its floppy-mode count against the exact solver's on every corpus row.

    python -m studies.closure_rigidity [--cache DIR] [--out DIR] [--bench]

For every packing of the corpus cache (``studies.corpus``) and every kt/kn of the corpus, the game
(:func:`microhom.rigidity.pebble_game`) is played on the network in the state the closure uses:
kt = 0, frictionless (one bar per contact, 2 dof per disk); kt > 0, sticking contacts two bars,
sliding contacts one (``pack_frictionless`` packings with no contact sliding, as
``studies.corpus.measure_network`` analyses them). Columns added per row (:func:`rigidity_columns`):

* ``rigid_largest``: fraction of the particles in the largest rigid cluster;
* ``rigid_redundant``: redundant (overconstrained) bars per particle;
* ``rigid_floppy``: floppy modes per particle;
* ``rigid_maxwell``: the control without the game, Maxwell's global count
  ``(n_constraints - n_dof + n_trivial) / N`` (= ``rigid_redundant - rigid_floppy`` exactly);
* ``rigid_n_floppy``: the count, compared with ``n_floppy`` of the exact solver
  (``dem.analysis.stiffness``: zero modes of the reduced Hessian, a second method).

``--bench`` times the game on the corpus packings (N = 1000, 4000) and on noisy periodic triangular
lattices of 6400 and 25600 disks (the cost on rigid networks grows about as N^1.9).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from microhom.rigidity import pebble_game
from studies.common import cli_out_dir, write_table

#: the candidate columns this module adds to the corpus summary
RIGIDITY_COLUMNS = ("rigid_largest", "rigid_redundant", "rigid_floppy", "rigid_maxwell")


def _state(net, protocol, kt_over_kn):
    """The network in the state ``studies.corpus.measure_network`` analyses at this kt/kn."""
    if protocol == "pack_frictionless":
        net = net.with_stiffness(sliding=False)
    return net.with_stiffness(kt=kt_over_kn * np.asarray(net.kn))


def rigidity_columns(df: pd.DataFrame, cache) -> pd.DataFrame:
    """``df`` (rows of the corpus summary: ``protocol``, ``key``, ``kt_over_kn``) with the
    rigidity columns (module docstring) of the packings found in ``cache``; rows whose packing
    is not cached get NaN. The game depends on kt/kn only through kt = 0 or kt > 0."""
    from studies.corpus import _load_network
    out = []
    for (prot, key), g in df.groupby(["protocol", "key"], sort=False):
        path = Path(cache) / f"{key}.npz"
        if not path.exists():
            continue
        net, _ = _load_network(path)
        res = {}
        for kt in sorted(set(g.kt_over_kn.astype(float))):
            if (kt > 0) not in res:
                res[kt > 0] = pebble_game(_state(net, prot, kt))
            r = res[kt > 0]
            out.append(dict(key=key, kt_over_kn=kt, rigid_largest=r.largest_cluster_fraction,
                            rigid_redundant=r.redundant_density, rigid_floppy=r.floppy_density,
                            rigid_maxwell=(r.n_constraints - r.n_dof + r.n_trivial) / r.n_particles,
                            rigid_n_floppy=r.n_floppy, rigid_n_clusters=r.n_clusters))
    cols = pd.DataFrame(out, columns=["key", "kt_over_kn", *RIGIDITY_COLUMNS, "rigid_n_floppy", "rigid_n_clusters"])
    drop = [c for c in cols.columns if c in df.columns and c not in ("key", "kt_over_kn")]
    return df.drop(columns=drop).merge(cols, on=["key", "kt_over_kn"], how="left")


def check_against_exact(df: pd.DataFrame) -> pd.DataFrame:
    """Rows where the exact solver counted its zero modes: game's floppy count against it."""
    m = df[df.n_floppy.notna() & df.rigid_n_floppy.notna()].copy()
    m["agree"] = m.n_floppy.astype(int) == m.rigid_n_floppy.astype(int)
    return m


def plot(df, path):
    """Largest rigid cluster against Z - Z_iso (every corpus row: the rigidity transition), and the
    redundant bars per particle against Maxwell's count (the game's excess is the floppy modes)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.3))
    prots = sorted(df.protocol.unique())
    for p, m in zip(prots, "osD^v<>"):
        for fr, col in ((False, "k"), (True, "tab:orange")):
            g = df[(df.protocol == p) & ((df.kt_over_kn > 0) == fr)]
            lab = f"{p}, {'kt > 0' if fr else 'kt = 0'}"
            ax[0].scatter(g.dZ, g.rigid_largest, marker=m, s=14, facecolors="none" if not fr else col,
                          edgecolors=col, label=lab)
            ax[1].scatter(g.rigid_maxwell, g.rigid_redundant, marker=m, s=14, facecolors="none" if not fr else col,
                          edgecolors=col)
    ax[0].axvline(0, color="0.6", lw=0.8)
    ax[0].set_xlim(-0.8, 2.1)   # rows whose every particle is a rattler (Z = 0) are off the left edge
    ax[0].set_xlabel("Z - Z_iso (Z_iso = 4 at kt = 0, 6 / (2 - s) at kt > 0)")
    ax[0].set_ylabel("largest rigid cluster / N")
    ax[0].legend(fontsize=6, ncol=2, loc="center")
    lim = [min(df.rigid_maxwell.min(), 0), df.rigid_redundant.max() * 1.05]
    ax[1].plot(lim, lim, "k-", lw=0.6)
    ax[1].set_xlabel("Maxwell count (constraints - dof + trivial) / N")
    ax[1].set_ylabel("redundant bars / N (pebble game)")
    ax[1].set_title("above the diagonal: floppy modes", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def bench(cache, n_big=25_600):
    """Seconds per game (after compilation) on the cached N = 1000 and 4000 packings and on
    noisy periodic triangular lattices of ``n_big / 4`` and ``n_big`` disks."""
    from microhom.lattices import triangular
    from microhom.network import from_pairs
    from studies.corpus import _load_network
    files = sorted(Path(cache).glob("*_n4000_*.npz")) + sorted(Path(cache).glob("*_n1000_*.npz"))[:4]
    pebble_game(triangular(6, 6))
    for f in files:
        net, _ = _load_network(f)
        for kt in (0.0, 1.0):
            nk = net.with_stiffness(kt=kt * np.asarray(net.kn))
            t0 = time.process_time()
            r = pebble_game(nk)
            print(f"{f.stem}: N = {net.n_particles}, kt/kn = {kt}: {time.process_time() - t0:.3f} s CPU "
                  f"(floppy {r.n_floppy}, redundant {r.n_redundant}, largest {r.largest_cluster_fraction:.3f})")
    for side in (int(round(np.sqrt(n_big))) // 2, int(round(np.sqrt(n_big)))):
        side += side % 2
        lat = triangular(side, side, kt=0.0)
        rng = np.random.default_rng(0)
        pos = lat.positions + rng.normal(0, 1e-3, lat.positions.shape)
        net = from_pairs(pos, lat.radii, lat.cell, lat.pairs, shifts=lat.image_shifts(), kn=1.0, kt=0.0)
        _bench_lattice(net)


def _bench_lattice(net):
    """CPU seconds of the game on ``net`` at kt = 0 and kt = kn, printed."""
    for kt in (0.0, 1.0):
        nk = net.with_stiffness(kt=kt)
        t0 = time.process_time()
        r = pebble_game(nk)
        print(f"noisy triangular lattice, N = {net.n_particles}, kt/kn = {kt}: {time.process_time() - t0:.2f} s CPU "
              f"(floppy {r.n_floppy}, redundant {r.n_redundant}, largest {r.largest_cluster_fraction:.3f})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="out/closure/cache")
    ap.add_argument("--out", default="out/closure")
    ap.add_argument("--bench", action="store_true")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out)
    from studies.closure_fit import SUMMARY
    raw = pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""])
    df = rigidity_columns(raw, args.cache)
    chk = check_against_exact(df)
    bad = chk[~chk.agree]
    print(f"floppy modes, pebble game against the exact solver's zero modes: {int(chk.agree.sum())} of {len(chk)} "
          f"rows agree")
    if len(bad):
        print(bad[["key", "kt_over_kn", "sliding_fraction", "n_floppy", "rigid_n_floppy"]].to_string(index=False))
    summ = df.groupby(["protocol", df.kt_over_kn > 0])[list(RIGIDITY_COLUMNS)].agg(["min", "max"])
    print(summ.to_string(float_format=lambda x: f"{x:.4f}"))
    df.to_csv(out / "closure_rigidity.csv", index=False)
    write_table(chk[["key", "kt_over_kn", "n_floppy", "rigid_n_floppy", "agree"]], out, "rigidity_check",
                "Pebble game against the exact solver's floppy modes")
    plot(df, out / "closure_rigidity.png")
    if args.bench:
        bench(args.cache)
    return df


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
