"""Dask overhead benchmark of :func:`studies.runner.run_cases`: serial vs a 2-worker LocalCluster.

    python -m studies.bench_dask [--cases 32] [--n 150000] [--workers 2] [--trivial 200] [--quick]

Prints (no timed asserts; figures are machine-dependent):

1. the start-up and shut-down time of a LocalCluster (``workers`` processes, 1 thread each);
2. ``cases`` cases of :func:`studies.runner.demo_case` with ``n`` particles each (about a second per
   case here) run serially and on the cluster, both through ``run_cases`` (resumable CSV written
   after every case): wall times, the speed-up (with and without the start-up) and the parallel
   efficiency;
3. ``trivial`` cases with 20 particles (milliseconds each): the per-task overhead of the runner on
   Dask, ``(dask wall - start-up) / cases - serial per-case time``, and of a bare
   ``client.map``/``gather`` of a no-op on an already running cluster (the scheduler's own cost).

A serial warm-up case is run first, so numba/numpy import and first-call costs are not counted on
either side (each Dask worker pays its own imports on its first task: that is part of the
overhead measured).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from studies.runner import demo_case, run_cases
from studies.common import add_out, cli_out_dir, report_to


def _noop(x):
    return x


def _cluster_startup(workers):
    from dask.distributed import Client, LocalCluster  # optional dependency (extra "dist")
    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    t1 = time.perf_counter()
    # bare scheduler overhead per task on a running cluster
    client.submit(_noop, 0).result()                       # first task: connection warm-up
    m = 2000
    t2 = time.perf_counter()
    client.gather(client.map(_noop, range(m), pure=False))
    t3 = time.perf_counter()
    client.close()
    cluster.close()
    t4 = time.perf_counter()
    return {"startup_s": t1 - t0, "shutdown_s": t4 - t3, "bare_tasks": m, "bare_per_task_ms": 1e3 * (t3 - t2) / m}


def _timed(cases, out, scheduler, workers):
    if out.exists():
        out.unlink()
    t0 = time.perf_counter()
    df = run_cases(demo_case, cases, out, scheduler=scheduler, workers=workers, progress=False)
    wall = time.perf_counter() - t0
    assert (df["status"] == "ok").all(), df[df["status"] != "ok"]
    return wall, df


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m studies.bench_dask", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=32, help="number of heavy cases")
    ap.add_argument("--n", type=int, default=150_000, help="particles per heavy case (demo_case)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster workers")
    ap.add_argument("--trivial", type=int, default=200, help="number of trivial (20-particle) cases")
    ap.add_argument("--quick", action="store_true", help="8 cases of 20,000 particles, 40 trivial cases")
    add_out(ap, "bench_dask")
    args = ap.parse_args(argv)
    report_to(cli_out_dir(args.out, cache=False))   # the printed figures, also in OUT/report.txt
    if args.quick:
        args.cases, args.n, args.trivial = 8, 20_000, 40
    print(f"# bench_dask: {args.cases} cases x demo_case(n={args.n}), {args.trivial} trivial cases, "
          f"LocalCluster {args.workers} workers x 1 thread; cpus {os.cpu_count()}; "
          f"loadavg {os.getloadavg()[0]:.2f}")
    demo_case({"seed": 10**6, "n": 1000})  # warm-up in this process

    cl = _cluster_startup(args.workers)
    print(f"cluster: start-up {cl['startup_s']:.2f} s, shut-down {cl['shutdown_s']:.2f} s; bare client.map of a "
          f"no-op on a running cluster: {cl['bare_per_task_ms']:.3f} ms/task ({cl['bare_tasks']} tasks)")

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        heavy = [{"seed": s, "n": args.n, "kt_over_kn": 1.0} for s in range(args.cases)]
        ws, dfs = _timed(heavy, tmp / "serial.csv", None, None)
        wd, dfd = _timed(heavy, tmp / "dask.csv", "local", args.workers)
        same = dfs.drop(columns=["wall_time_s"]).equals(dfd.drop(columns=["wall_time_s"]))
        per_case = dfs["wall_time_s"].mean()
        eff_wd = wd - cl["startup_s"] - cl["shutdown_s"]
        print(f"heavy: serial {ws:.2f} s ({per_case:.3f} s/case), dask {wd:.2f} s "
              f"(~{eff_wd:.2f} s without cluster start/stop); speed-up {ws / wd:.2f}x "
              f"(without start/stop {ws / eff_wd:.2f}x, ideal {args.workers}x, efficiency "
              f"{ws / eff_wd / args.workers:.0%}); identical tables: {same}")

        # trivial cases at two counts: the slope is the per-task cost, the intercept the fixed cost
        # (cluster start/stop, each worker's first imports); serial per-case cost subtracted
        counts = sorted({max(2, args.trivial // 4), args.trivial})
        walls = {}
        for m in counts:
            trivial = [{"seed": s, "n": 20, "kt_over_kn": 1.0} for s in range(m)]
            ts, _ = _timed(trivial, tmp / f"t_serial_{m}.csv", None, None)
            td, _ = _timed(trivial, tmp / f"t_dask_{m}.csv", "local", args.workers)
            walls[m] = (ts, td)
            print(f"trivial x {m}: serial {ts:.2f} s ({1e3 * ts / m:.2f} ms/case incl. the CSV rewrite), "
                  f"dask {td:.2f} s")
        if len(counts) == 2:
            m1, m2 = counts
            slope_d = (walls[m2][1] - walls[m1][1]) / (m2 - m1)
            slope_s = (walls[m2][0] - walls[m1][0]) / (m2 - m1)
            fixed = walls[m2][1] - slope_d * m2
            print(f"runner on Dask: {1e3 * slope_d:.2f} ms per trivial task (serial {1e3 * slope_s:.2f} ms): "
                  f"overhead {1e3 * (slope_d - slope_s / args.workers):.2f} ms/task of wall time; fixed cost "
                  f"{fixed:.2f} s per sweep (cluster start/stop {cl['startup_s'] + cl['shutdown_s']:.2f} s + "
                  f"workers' first imports)")
        # resume: a second call finds every case done and runs nothing
        t0 = time.perf_counter()
        run_cases(demo_case, heavy, tmp / "dask.csv", scheduler=None, progress=False)
        print(f"resume: re-running the finished heavy sweep took {time.perf_counter() - t0:.3f} s (0 cases run)")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
