"""Benchmark of the mine scene: the paper's scene through a 10 ms excavation ramp and 100 ms of
dynamics (target < 30 s), steps/s, and scaling with a 4x finer lattice (r_in / 2).

    python -m studies.bench_mine [--skip-fine]
"""
from __future__ import annotations

import argparse
import time

from dem.scenes.mine import MineParams, build_scene, run_scene


def one(p, label):
    t0 = time.perf_counter()
    sc = build_scene(p)
    tb = time.perf_counter() - t0
    r = run_scene(sc)
    tm = r.timings
    print(f"{label:28s} cells={sc.model.n_cells:6d} interfaces={sc.model.n_ifc:6d} dt={r.dt * 1e6:6.2f} us "
          f"steps={r.indicators['steps']:6d} build={tb:5.2f}s dynamics={tm['dynamics_s']:6.2f}s "
          f"sampling={tm['sampling_s']:5.2f}s total={r.wall_time:6.2f}s steps/s={tm['steps_per_s']:8.0f} "
          f"cell-steps/s={tm['cell_steps_per_s']:.3g}", flush=True)
    return r


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-fine", action="store_true")
    a = ap.parse_args(argv)
    run_scene(MineParams(duration=0.001, ramp_time=0.001))          # numba cache warm-up
    base = one(MineParams(ramp_time=0.01, duration=0.1), "paper scene r_in=0.25")
    side = one(MineParams(lattice="side", ramp_time=0.01, duration=0.1), "side 0.25 (r_in=0.2165)")
    if not a.skip_fine:
        fine = one(MineParams(cell_size=0.125, ramp_time=0.01, duration=0.1), "4x finer r_in=0.125")
        cost = fine.timings["dynamics_s"] / base.timings["dynamics_s"]
        print(f"finer/base dynamics time ratio = {cost:.1f} (expected ~8: 4x cells, 2x steps)")
    print(f"target: paper scene < 30 s -> {'OK' if base.wall_time < 30 else 'MISSED'} ({base.wall_time:.1f} s)")


if __name__ == "__main__":
    main()
