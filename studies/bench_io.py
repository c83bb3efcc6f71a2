"""Timing of dem.io on a 1e6-particle LAMMPS text dump: write, parse, read, build the network.

    python -m studies.bench_io [--n 1000000] [--keep DIR]

Generates a jittered, slightly polydisperse triangular packing (about 6 contacts per disk) in an
orthogonal and in a sheared periodic cell, writes it as a LAMMPS dump in a temporary directory,
and prints the wall-clock figures:

* the candidate text parsers on the dump's atom block (pandas ``read_csv(sep=r"\\s+")``,
  ``numpy.loadtxt``, ``numpy.fromstring``) — ``dem.io`` uses the fastest, pandas;
* ``dem.io.read`` of the whole dump, ``Configuration.network`` and their sum (target < 5 s);
* the same for a LAMMPS data file and for npz.
"""
from __future__ import annotations

import argparse
import io as _io
import os
import tempfile
import time
import warnings

import numpy as np

from dem import io
from dem.io import Configuration
from studies.common import add_out, cli_out_dir, report_to


def packing(n, sheared, seed=0):
    nx = int(round(np.sqrt(n / (np.sqrt(3) / 2)) / 2)) * 2  # near-square cell
    ny = max(2, (n // nx) // 2 * 2)
    rng = np.random.default_rng(seed)
    k, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    pos = np.stack([(i + 0.5 * (k % 2)), k * np.sqrt(3) / 2], axis=-1).reshape(-1, 2)
    pos += rng.normal(scale=0.002, size=pos.shape)
    rad = 0.5 * (1.01 + 0.004 * rng.random(pos.shape[0]))  # ~1 % overlaps: Z = 6
    cell = np.diag([float(nx), ny * np.sqrt(3) / 2])
    if sheared:  # same lattice, cell vector b shifted by ny/2 columns (a lattice vector)
        cell[0, 1] = ny / 2.0
    return Configuration(positions=pos, radii=rad, cell=cell)


def timed(fn, *args, **kw):
    t = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t


def parser_candidates(path):
    import pandas as pd  # heavy import, only for the parser comparison

    data = open(path, "rb").read()
    start = data.index(b"ITEM: ATOMS")
    start = data.index(b"\n", start) + 1
    block = data[start:]
    res = {}
    _, res["pandas read_csv sep=\\s+"] = timed(
        lambda: pd.read_csv(_io.BytesIO(block), sep=r"\s+", header=None,
                            dtype=np.float64).to_numpy())
    _, res["numpy.loadtxt"] = timed(lambda: np.loadtxt(_io.BytesIO(block)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, res["numpy.fromstring sep=' '"] = timed(
            lambda: np.fromstring(block.decode(), sep=" "))
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--keep", default=None, help="directory to keep the generated files in")
    ap.add_argument("--skip-parsers", action="store_true")
    add_out(ap, "bench_io")
    args = ap.parse_args(argv)
    report_to(cli_out_dir(args.out, cache=False))   # the printed figures, also in OUT/report.txt
    tmp = args.keep or tempfile.mkdtemp(prefix="bench_io_")
    os.makedirs(tmp, exist_ok=True)
    print(f"dem.io benchmark, N ~ {args.n:,}, files in {tmp}, {os.cpu_count()} CPUs")
    rows = []
    for sheared in (False, True):
        cfg = packing(args.n, sheared)
        tag = "sheared" if sheared else "orthogonal"
        dump = os.path.join(tmp, f"{tag}.dump")
        _, t_w = timed(io.write, dump, cfg)
        size = os.path.getsize(dump) / 1e6
        print(f"\n[{tag} cell] N = {cfg.n_particles:,}, dump {size:.0f} MB, write {t_w:.2f} s")
        if not args.skip_parsers and not sheared:
            for name, t in parser_candidates(dump).items():
                print(f"  parse atom block with {name:28s} {t:6.2f} s")
        back, t_r = timed(io.read, dump)
        net, t_n = timed(back.network, kn=1.0)
        z = 2 * net.n_contacts / net.n_particles
        print(f"  dem.io.read(dump)            {t_r:6.2f} s")
        print(f"  Configuration.network()      {t_n:6.2f} s   (Z = {z:.3f})")
        print(f"  read + network               {t_r + t_n:6.2f} s   (target < 5 s)")
        rows.append((tag, "dump", t_w, t_r, t_n))
        for ext in ("data", "npz"):
            p = os.path.join(tmp, f"{tag}.{ext}")
            _, tw = timed(io.write, p, cfg)
            _, tr = timed(io.read, p)
            print(f"  {ext:5s}: write {tw:6.2f} s, read {tr:6.2f} s")
            rows.append((tag, ext, tw, tr, float("nan")))
    return rows


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
