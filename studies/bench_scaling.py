"""Scaling of the disk engine: time per step against N from 10^3 to 10^6, and memory per particle.

    python -m studies.bench_scaling [--quick]

The dense frictional benchmark scene of ``studies.bench_throughput`` (phi 0.84, kt = kn, mu = 0.5,
same dt) is prepared once at N = 1000 and tiled to larger N. For each N: wall time per step,
particle-steps per second, and the bytes per particle held by the state and the simulation's
buffers (every numpy array they own, Verlet list and contact history included). Prints a table and
a least-squares slope of log(time per step) against log(N) (1 = linear). The peak resident memory
of the process (``getrusage``) is printed beside the bytes the arrays own: the second method for
the bytes per particle that ``dem.engine.packing.check_memory`` uses.
"""
from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

from dem.engine.integrate import Loop, Simulation
from studies.bench_throughput import DT, bench_law, dense_base, tile
from studies.common import add_out, cli_out_dir, report_to


def owned_bytes(*objs) -> int:
    """Bytes of the numpy arrays held by the objects' attributes (directly or in a tuple, such as
    the simulation's compact copy of the Verlet list), each array counted once."""
    seen, total = set(), 0
    for o in objs:
        for v in vars(o).values():
            for a in (v if isinstance(v, tuple) else (v,)):
                if isinstance(a, np.ndarray) and id(a) not in seen:
                    seen.add(id(a))
                    total += a.nbytes
    return total


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="up to 64 000 disks")
    add_out(ap, "bench_scaling")
    args = ap.parse_args(argv)
    report_to(cli_out_dir(args.out, cache=False))   # the printed figures, also in OUT/report.txt
    base = dense_base(n=1000, ncomp=20000, nrelax=3000)
    tiles = [(1, 1), (2, 2), (4, 4), (8, 8)] + ([] if args.quick else [(16, 16), (32, 32)])
    rows = []
    for rx, ry in tiles:
        st = tile(base, rx, ry)
        n = st.n
        sim = Simulation(st, bench_law(), dt=DT, damping=0.0, loop=Loop(skin=0.1, sort_every=50))
        sim.run(20)  # compile, first list build and spatial sort
        steps = max(20, int(2e7 / n))
        t0 = time.perf_counter()
        sim.run(steps)
        wall = time.perf_counter() - t0
        per_step = wall / steps
        rows.append((n, steps, per_step, n * steps / wall, owned_bytes(st, sim) / n))
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        print(f"N = {n:>8d}: {steps:>6d} steps, {per_step * 1e3:9.3f} ms/step, {n * steps / wall:.3g} particle-steps/s, "
              f"{owned_bytes(st, sim) / n:.0f} bytes/particle owned, peak RSS of the process "
              f"{rss / 1e9:.2f} GB; load {os.getloadavg()[0]:.2f}", flush=True)
        del sim, st
    ns = np.array([r[0] for r in rows], float)
    ts = np.array([r[2] for r in rows])
    slope = np.polyfit(np.log(ns), np.log(ts), 1)[0]
    print(f"slope of log(time per step) vs log(N): {slope:.3f} (1 = linear); "
          f"memory {min(r[4] for r in rows):.0f}-{max(r[4] for r in rows):.0f} bytes per particle (target < 1000)")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
