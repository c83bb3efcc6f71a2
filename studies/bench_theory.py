"""Benchmark of the theory half: prediction rate, import time, structural sums at 10^5 particles.

    python -m studies.bench_theory [--quick] [--out out/bench_theory]

Prints figures (also written to ``OUT/report.txt``); repeat runs give the spread (timings on shared machines are noisy).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np

from studies.common import add_out, cli_out_dir, tee


def _best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller sizes, fewer repeats")
    add_out(ap, "bench_theory")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out, cache=False)
    with tee(out):
        _run(args)


def _run(args):
    repeat = 3 if args.quick else 7

    from microhom.moduli import predict_moduli

    n = 10 ** 5 if args.quick else 10 ** 6
    rng = np.random.default_rng(0)
    kn = 10 ** rng.uniform(0, 10, n)
    kt = kn * rng.uniform(0, 2, n)
    nc = rng.uniform(3.5, 5.5, n)
    phi = rng.uniform(0.8, 0.88, n)
    r = rng.uniform(0, 0.3, n)
    alpha = rng.uniform(1.0, 2.0, n)
    best, med = _best(lambda: predict_moduli(kn, kt, nc, phi, r, alpha=alpha, warn=False), repeat)
    print(f"predict_moduli: {n} parameter sets, best {best*1e3:.1f} ms, median {med*1e3:.1f} ms "
          f"-> {n/best:.3g} sets/s (best), {n/med:.3g} sets/s (median); target >= 1e6 sets/s")

    code = "import time; t=time.perf_counter(); import microhom, microhom.moduli, microhom.structural_sums; " \
           "print(time.perf_counter()-t)"
    imp = sorted(float(subprocess.run([sys.executable, "-c", code], capture_output=True,
                                      text=True, check=True).stdout) for _ in range(repeat))
    print(f"import microhom (+moduli, structural_sums, fresh interpreter): best {imp[0]:.3f} s, "
          f"median {imp[len(imp)//2]:.3f} s; target < 0.5 s")

    from microhom.lattices import triangular
    from microhom.network import from_overlaps
    from microhom.structural_sums import network_statistics

    side = 100 if args.quick else 316  # 10^4 or ~10^5 disks
    lat = triangular(side, side if side % 2 == 0 else side + 1)
    pos = lat.positions + rng.normal(scale=0.03, size=lat.positions.shape)
    t0 = time.perf_counter()
    net = from_overlaps(pos, 0.5 * 1.01, lat.cell, kn=1.0, kt=1.0)
    t_build = time.perf_counter() - t0
    best, med = _best(lambda: network_statistics(net), repeat)
    print(f"ContactNetwork of {net.n_particles} disks ({net.n_contacts} contacts) from positions: {t_build:.3f} s; "
          f"network_statistics (all per-particle sums, rattlers, rho): best {best:.3f} s, median {med:.3f} s")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
