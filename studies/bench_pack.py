"""A full `dem.engine.packing.pack` of 1e4 disks against LAMMPS' preparation of 1e4 disks, in the same run.

    python -m studies.bench_pack [--n 10000] [--repeats 2] [--seed 0] [--old] [--case cli|mu05]

Ours: :func:`dem.engine.packing.pack` with the defaults of ``python -m dem pack`` (``--case cli``: p/kn =
1e-4, mu_prep = 0.1, mu = 0.488, unbalanced force ratio < 1e-5, |p - p_t|/p_t < 1e-3, kinetic
energy of the particles in contact < 1e-8 x elastic energy): gas -> compaction -> equilibrium at
mu_prep -> equilibrium at mu, each phase with its own stop criterion (the step at which each ended
is printed). ``--case mu05``: ``PackingProtocol(n=n, seed=seed, mu=0.5, mu_prep=0.5)`` (the
friction of ``in.prep``, and the case of issue 12 and ``studies.bench_throughput``), same
criteria.

LAMMPS: ``studies/lammps_bench/in.prep`` (carried in the repository, shared with bench_throughput): random insertion,
soft push-off, isotropic compression at a constant rate to phi = 0.84 with GRANULAR
gran/hooke/history, relaxation until the translational kinetic energy per particle is below
1e-12 kn d^2; serial, one thread. Its stop criterion is its own; the comparison is the wall time
of a complete preparation of a jammed, relaxed 1e4-disk packing on each side.

The two sides alternate (ours, LAMMPS, ours, LAMMPS ...) so that load from other processes hits
both alike; the spread over the repeats (wall time, CPU time, steps) and the load average are
printed. ``--old`` adds a third side in the same rotation: ours with the protocol before issue
12.3 (compaction damping 0.1, dt = 0.8 dt_crit, no FIRE). Says so and runs ours
alone when ``lmp`` is not on PATH (Debian: ``apt-get install -y lammps``).
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import statistics
import subprocess
import tempfile
import time

from dem.analysis.measure import coordination
from dem.engine.packing import PackingProtocol, pack
from studies.common import add_out, cli_out_dir, report_to

PREP_IN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "lammps_bench", "in.prep")
#: the defaults of ``python -m dem pack``: the PackingProtocol's own (p/kn = 1e-4, kt = kn,
#: mu = 0.488, mu_prep = 0.1, identical disks, tol_unbalanced = 1e-5)
CLI_DEFAULTS = {}
#: the protocol options before issue 12.3 (same stop criteria)
OLD_PROTOCOL = dict(damping_compaction=0.1, dt_over_dtcrit=0.8, fire=False)


#: ``--case``: the physics parameters of ours
CASES = {"cli": CLI_DEFAULTS, "mu05": dict(p_over_kn=1e-4, mu=0.5, mu_prep=0.5)}


def run_ours(n, seed, old=False, case="cli"):
    t0, c0 = time.perf_counter(), time.process_time()
    r = pack(PackingProtocol(n=n, seed=seed, **CASES[case], **(OLD_PROTOCOL if old else {})))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rep = r.report
    c = coordination(r.to_network())      # after the timing: Z without rattlers
    return dict(wall=wall, cpu=cpu, steps=rep["steps"], converged=rep["converged"],
                phases=rep["phase_steps"], phi=rep["phi"], Z=rep["Z"], Zc=c.z,
                rattlers=c.rattler_fraction, psi6=rep["psi6"], ps=rep["particle_steps_per_s"])


def run_lammps(n, seed, work):
    log = os.path.join(work, "prep.log")
    t0, c0 = time.perf_counter(), _children_cpu()
    subprocess.run(["lmp", "-in", PREP_IN, "-var", "N", str(n), "-var", "seed", str(4242 + seed),
                    "-var", "out", os.path.join(work, "dense.data"), "-log", log, "-screen", "none"],
                   check=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    steps, res = 0, ""
    for line in open(log, errors="replace"):
        m = re.match(r"Loop time of \S+ on \d+ procs for (\d+) steps", line)
        if m:
            steps += int(m.group(1))
        if line.startswith("PREP_RESULT"):
            res = line.strip()
    return dict(wall=wall, cpu=cpu, steps=steps, result=res)


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _spread(name, runs):
    """One line: median [min, max] of wall, CPU and steps over the repeats."""
    def f(key, fmt):
        v = [r[key] for r in runs]
        return f"{key} {format(statistics.median(v), fmt)} [{format(min(v), fmt)}, {format(max(v), fmt)}]"
    return f"{name:14s} " + ", ".join([f("wall", ".2f"), f("cpu", ".2f"), f("steps", ".0f")])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--old", action="store_true", help="also run the protocol before issue 12.3")
    ap.add_argument("--case", choices=sorted(CASES), default="cli",
                    help="cli: the defaults of python -m dem pack; mu05: mu = mu_prep = 0.5")
    add_out(ap, "bench_pack")
    a = ap.parse_args(argv)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    have_lmp = shutil.which("lmp") is not None
    if not have_lmp:
        print("lmp not on PATH: the LAMMPS side is skipped (Debian: apt-get install -y lammps)")
    print(f"N = {a.n}, case {a.case} {CASES[a.case]}, load average {os.getloadavg()} on "
          f"{os.cpu_count()} cores")
    sides = {"ours": [], "ours (old)": [], "LAMMPS": []}
    with tempfile.TemporaryDirectory(prefix="bench_pack_") as work:
        for k in range(a.repeats):
            for old in ([False, True] if a.old else [False]):
                o = run_ours(a.n, a.seed + k, old=old, case=a.case)
                name = "ours (old)" if old else "ours"
                sides[name].append(o)
                print(f"{name:10s} seed {a.seed + k}: {o['wall']:7.2f} s wall, {o['cpu']:7.2f} s CPU, "
                      f"{o['steps']} steps, converged {o['converged']}, phases "
                      f"{[(p['phase'], p['step']) for p in o['phases']]}, phi {o['phi']:.4f}, "
                      f"Z {o['Z']:.3f}, Z without rattlers {o['Zc']:.3f}, rattlers "
                      f"{100 * o['rattlers']:.1f} %, psi6 {o['psi6']:.3f}, {o['ps']:.3g} particle-steps/s; "
                      f"load {os.getloadavg()[0]:.2f}",
                      flush=True)
            if have_lmp:
                t = run_lammps(a.n, a.seed + k, work)
                sides["LAMMPS"].append(t)
                print(f"LAMMPS     seed {4242 + a.seed + k}: {t['wall']:7.2f} s wall, {t['cpu']:7.2f} s "
                      f"CPU, {t['steps']} steps; {t['result']}; load {os.getloadavg()[0]:.2f}", flush=True)
    for name, runs in sides.items():
        if runs:
            print(_spread(name, runs))
    ours, theirs = sides["ours"], sides["LAMMPS"]
    if theirs:
        mean = statistics.mean
        print(f"ratio of means ours / LAMMPS: wall {mean(r['wall'] for r in ours) / mean(r['wall'] for r in theirs):.2f}, "
              f"CPU {mean(r['cpu'] for r in ours) / mean(r['cpu'] for r in theirs):.2f}; per pair (wall): "
              + ", ".join(f"{o['wall'] / t['wall']:.2f}" for o, t in zip(ours, theirs)))


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
