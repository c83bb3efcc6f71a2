"""Benchmark of the mine scene: one case of the paper's scene (10 ms excavation ramp + 100 ms of
dynamics; target < 5 s), repeated, with the machine's load printed; the 1527-cell lattice and a 4x
finer lattice for scaling.

    python -m studies.bench_mine [--repeats 3] [--skip-fine]

The whole decisive study is timed by ``python -m studies.mine_bumps`` itself (its verdict.md head).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from dem.scenes.mine import MineParams, build_scene, run_scene
from studies.common import add_out, cli_out_dir, report_to


def one(p):
    t0 = time.perf_counter()
    sc = build_scene(p)
    tb = time.perf_counter() - t0
    r = run_scene(sc)
    return sc, r, tb, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.bench_mine")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-fine", action="store_true")
    add_out(ap, "bench_mine")
    a = ap.parse_args(argv)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    run_scene(MineParams(duration=0.001, ramp_time=0.001))          # numba cache warm-up
    cases = [("paper scene, 1117 cells (inner radius 0.25 m)", MineParams()),
             ("paper-closest reading (eigenstrain gas)", MineParams(gas="eigenstrain")),
             ("1527 cells (side 0.25 m)", MineParams(lattice="side"))]
    if not a.skip_fine:
        cases.append(("4x finer (inner radius 0.125 m)", MineParams(cell_size=0.125)))
    res = {lab: [] for lab, _ in cases}
    for rep in range(a.repeats):                                     # interleaved repeats
        for lab, p in cases:
            if rep and "finer" in lab:
                continue
            sc, r, tb, tt = one(p)
            res[lab].append(tt)
            tm = r.timings
            print(f"{lab:48s} cells={sc.model.n_cells:5d} dt={r.dt * 1e6:5.2f} us steps={r.indicators.steps:6d} "
                  f"build={tb:5.2f}s dynamics={tm['dynamics_s']:6.2f}s total={tt:6.2f}s "
                  f"cell-steps/s={tm['cell_steps_per_s']:.3g}  load={os.getloadavg()[0]:.2f}", flush=True)
    print("\nsummary (wall seconds per case: min / median / max over repeats; load average now "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)")
    for lab, ts in res.items():
        print(f"  {lab:48s} {min(ts):6.2f} / {np.median(ts):6.2f} / {max(ts):6.2f}")
    best = min(res[cases[0][0]])
    print(f"target: one paper case (ramp + 100 ms) < 5 s -> {'OK' if best < 5 else 'MISSED'} (best {best:.2f} s)")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
