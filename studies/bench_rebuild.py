"""Cost of one Verlet-list rebuild (:func:`dem.engine.neighbors.rebuild`) on the throughput benchmark's scene.

    python -m studies.bench_rebuild [--ns 10000 100000] [--repeats 5] [--against REV] [--base-n 10000]

Scene: the dense state of :mod:`studies.bench_throughput` (prepared at ``--base-n`` disks and tiled
to N), run 200 steps with the benchmark's law, skin and spatial sort every 50 builds, then stepped
until a rebuild is due. The rebuild's input is the state at that step: its old list and contact
history, the moved positions. Each timing rebuilds a fresh copy of that state, without the spatial
sort (the common build) and with it (every 50th build in the benchmark).

With ``--against REV`` the module ``dem/engine/neighbors.py`` of git revision REV is loaded as well; the
two are timed alternately in this process (REV, today, REV, today, ...), so that load from other
processes hits both alike, and their outputs are compared bit for bit. Prints, per repeat, the
median time of ``--inner`` rebuilds and the load average, then the median and the spread (min-max)
over the repeats. Figures are printed, never asserted.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import subprocess
import tempfile
import time

import numpy as np

from dem.engine import neighbors
from dem.engine.integrate import Guard, Loop, Simulation
from studies.bench_throughput import DT, SKIN, bench_law, dense_base, tile, tiling
from studies.common import add_out, cli_out_dir, report_to

LIST = ("x", "v", "radius", "ids", "omega", "nl_i", "nl_j", "nl_shift", "nl_ft", "x_ref", "h_ref")


def due_state(base, n):
    """The benchmark scene of n disks at the step its next list rebuild is due."""
    st = tile(base, *tiling(n, base.n))
    sim = Simulation(st, bench_law(), dt=DT, damping=0.0, guard=Guard(unsafe_dt=True),
                     loop=Loop(skin=SKIN, sort_every=50))
    sim.run(200)
    while not sim.need_rebuild:
        sim.step(False)
    return st


def module_at(rev):
    """``dem/engine/neighbors.py`` of git revision ``rev`` as a module of the ``dem`` package (numba's
    on-disk cache off: the file lives in a temporary directory)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = None
    for where in ("dem/engine/neighbors.py", "dem/neighbors.py"):   # after / before the layout move
        got = subprocess.run(["git", "show", f"{rev}:{where}"], capture_output=True, text=True, cwd=root)
        if got.returncode == 0:
            src = got.stdout
            break
    if src is None:
        raise SystemExit(f"--against {rev}: no dem/engine/neighbors.py (or dem/neighbors.py) at that revision")
    # its relative imports point into the engine package, wherever the file sat at that revision
    src = re.sub(r"^from \.(\w+) import", r"from dem.engine.\1 import", src, flags=re.M)
    path = os.path.join(tempfile.mkdtemp(), "neighbors_at_rev.py")
    with open(path, "w") as f:
        f.write(src.replace("cache=True", "cache=False"))
    spec = importlib.util.spec_from_file_location("dem.engine._neighbors_at_rev", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def time_rebuild(mod, st, sort, inner):
    """Median wall time [ms] of ``inner`` rebuilds of fresh copies of st, and the last result."""
    ts = []
    for _ in range(inner):
        s = st.copy()
        t = time.perf_counter()
        mod.rebuild(s, SKIN, sort=sort, history=bench_law().history_parity)
        ts.append(time.perf_counter() - t)
    return 1e3 * float(np.median(ts)), s


def same(a, b):
    return all(np.array_equal(getattr(a, k), getattr(b, k)) and getattr(a, k).dtype == getattr(b, k).dtype
               for k in LIST)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ns", type=int, nargs="+", default=[10000, 100000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--inner", type=int, default=9, help="rebuilds per repeat (median taken)")
    ap.add_argument("--against", default=None, help="git revision whose dem/engine/neighbors.py to compare")
    ap.add_argument("--base-n", type=int, default=10000, help="disks of the prepared state (tiled to N)")
    add_out(ap, "bench_rebuild")
    a = ap.parse_args(argv)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    mods = [("today", neighbors)]
    if a.against:
        mods.insert(0, (a.against, module_at(a.against)))
    base = dense_base(a.base_n)
    for n in a.ns:
        st = due_state(base, n)
        print(f"N = {n}: {st.nl_i.shape[0]} pairs in the old list")
        for sort in (False, True):
            outs = [time_rebuild(m, st, sort, 1)[1] for _, m in mods]  # compile, and compare
            ident = all(same(outs[0], o) for o in outs[1:])
            times = {name: [] for name, _ in mods}
            for r in range(a.repeats):
                row = []
                for name, m in mods:
                    t = time_rebuild(m, st, sort, a.inner)[0]
                    times[name].append(t)
                    row.append(f"{name} {t:.2f}")
                print(f"  sort={sort} repeat {r}: " + ", ".join(row) + f" ms  (load {os.getloadavg()[0]:.2f})")
            summary = ", ".join(f"{name} {np.median(t):.2f} [{min(t):.2f}-{max(t):.2f}]" for name, t in times.items())
            print(f"  sort={sort}: ms per rebuild, median [min-max]: {summary}"
                  + (f"; outputs bit-identical: {ident}" if len(mods) > 1 else ""))


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
