"""Throughput of the numba disk DEM against LAMMPS (GRANULAR, serial) on the same dense scene.

    python -m studies.bench_throughput [--quick] [--no-lammps] [--ns 10000 100000] [--no-pack]

Scene (copy of /work/shared/bench/lammps, LJ-like units: mean diameter d = 1, a d = 1 disk has
mass 1): N disks, diameters uniform in [0.9, 1.1], periodic square cell at solid fraction 0.84,
linear kn = 1e4, kt = kn with history, Coulomb mu = 0.5, viscous normal and tangential contact
damping with damping ratio 0.05 (``LinearFriction(restitution=e(0.05), tangential_damping=True)``),
no local damping, dt = 0.1 * 2 sqrt(m/kn) = 0.002, skin 0.1 d.

Our dense state: random gas at phi 0.3, compression at constant strain rate to phi = 0.84 in
20000 steps with local damping, relaxation, tiled 5 x 2 for N = 1e5 (as LAMMPS' in.bench does).
The LAMMPS side (if ``lmp`` is on PATH) prepares its own packing with in.prep and runs in.bench
with the same step count; one line per N contains ``ratio`` = ours / LAMMPS particle-steps/s.
Also times :func:`dem.packing.pack` for a 1e4-disk packing at p/kn = 1e-4 (1e3 with --quick).
Figures are printed, never asserted.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

from dem.cell import StrainRate
from dem.contact_laws import LinearFriction
from dem.integrate import Simulation
from dem.state import State

LAMMPS_DIR = "/work/shared/bench/lammps"
KN = 1e4
DT = 0.1 * 2.0 * math.sqrt(1.0 / KN)
ZETA = 0.05
E_REST = math.exp(-ZETA * math.pi / math.sqrt(1 - ZETA ** 2))
RHO = 4.0 / math.pi


def bench_law():
    return LinearFriction(kn=KN, kt=KN, mu=0.5, restitution=E_REST, tangential_damping=True)


def dense_base(n=10000, seed=4242, ncomp=20000, nrelax=3000):
    """Our copy of in.prep: gas at phi 0.3 -> phi 0.84 at constant strain rate, then relaxation."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.9, 1.1, n)
    r = d / 2
    phi0, phi1 = 0.30, 0.84
    L0 = math.sqrt(np.pi * np.sum(r ** 2) / phi0)
    x = rng.uniform(0, L0, (n, 2))
    st = State.from_disks(x, r, np.diag([L0, L0]), rho=RHO, spins=True)
    e_tot = 0.5 * math.log(phi0 / phi1)  # log strain per direction (negative)
    rate = e_tot / (ncomp * DT)
    sim = Simulation(st, bench_law(), dt=DT, damping=0.7, skin=0.1,
                     control=StrainRate([[rate, 0], [0, rate]]))
    sim.run(ncomp)
    sim.control = StrainRate(np.zeros((2, 2)))
    st.L[:] = 0.0
    sim.run(nrelax)
    st.v[:] = 0.0
    st.omega[:] = 0.0
    return st


def tile(st, rx, ry):
    """Replicate a periodic state rx x ry times (history dropped, list rebuilt on the first step)."""
    h = st.h
    xs, rs = [], []
    for a in range(rx):
        for b in range(ry):
            xs.append(st.x + h @ np.array([a, b]))
            rs.append(st.radius)
    H = h @ np.diag([rx, ry])
    return State.from_disks(np.concatenate(xs), np.concatenate(rs), H, rho=RHO, spins=True)


def tiling(n, nbase=10000):
    k = n // nbase
    ry = max(j for j in range(1, int(math.isqrt(k)) + 1) if k % j == 0)
    return k // ry, ry


def run_ours(base, n, steps, warm=200):
    rx, ry = tiling(n)
    st = tile(base, rx, ry)
    sim = Simulation(st, bench_law(), dt=DT, damping=0.0, skin=0.1, sort_every=50)
    sim.run(warm)
    rep = sim.run(steps)
    m = sim.measure()
    return rep, m, sim


def lammps_available():
    return shutil.which("lmp") is not None


def run_lammps(ns, steps_of, work):
    os.makedirs(work, exist_ok=True)
    out = {}
    data = os.path.join(work, "dense_10000.data")
    t0 = time.perf_counter()
    if not os.path.exists(data):
        subprocess.run(["lmp", "-in", f"{LAMMPS_DIR}/in.prep", "-var", "N", "10000", "-var", "out", data,
                        "-log", os.path.join(work, "prep.log"), "-screen", "none"], check=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
        out["prep_wall_s"] = time.perf_counter() - t0
    for n in ns:
        log = os.path.join(work, f"bench_{n}.log")
        subprocess.run(["lmp", "-in", f"{LAMMPS_DIR}/in.bench", "-var", "N", str(n), "-var", "steps",
                        str(steps_of[n]), "-var", "base", data, "-log", log, "-screen", "none"],
                       check=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
        loops = []
        for line in open(log, errors="replace"):
            m = re.match(r"Loop time of (\S+) on \d+ procs for (\d+) steps with (\d+) atoms", line)
            if m:
                loops.append((float(m.group(1)), int(m.group(2)), int(m.group(3))))
        loop, steps, atoms = loops[1]  # run 0: warm-up, run 1: timed
        out[n] = atoms * steps / loop
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (about a minute)")
    ap.add_argument("--ns", type=int, nargs="*", default=[10000, 100000])
    ap.add_argument("--no-lammps", action="store_true")
    ap.add_argument("--no-pack", action="store_true")
    ap.add_argument("--work", default=os.path.join(os.environ.get("TMPDIR", "/tmp"), "dem-bench-lammps"))
    a = ap.parse_args(argv)
    steps_of = {n: (max(100, int(1.5e7 / n)) if a.quick else max(150, int(1.5e8 / n))) for n in a.ns}

    t0 = time.perf_counter()
    base = dense_base(ncomp=5000 if a.quick else 20000, nrelax=1000 if a.quick else 3000)
    t_prep = time.perf_counter() - t0
    print(f"ours-prep N=10000 wall_s={t_prep:.2f} phi={base.solid_fraction:.4f} (constant-rate "
          f"compression, {'quick' if a.quick else 'full'})", flush=True)
    ours = {}
    for n in a.ns:
        rep, m, sim = run_ours(base, n, steps_of[n])
        ours[n] = rep["particle_steps_per_s"]
        print(f"ours N={n} steps={rep['steps']} particle_steps_per_s={ours[n]:.4e} Z={2 * m['n_contacts'] / n:.3f} "
              f"p={m['pressure']:.4g} dt/dt_crit={sim.dt / sim.dt_crit:.3f} builds={sim.n_rebuilds}", flush=True)
        print("  " + rep["table"].replace("\n", "\n  "), flush=True)

    if not a.no_lammps:
        if lammps_available():
            lm = run_lammps(a.ns, steps_of, a.work)
            if "prep_wall_s" in lm:
                print(f"lammps-prep N=10000 wall_s={lm['prep_wall_s']:.2f}", flush=True)
            for n in a.ns:
                print(f"N={n} ours={ours[n]:.4e} lammps={lm[n]:.4e} ratio={ours[n] / lm[n]:.3f} "
                      f"(particle-steps/s, ours/LAMMPS gran/hooke/history, serial)", flush=True)
        else:
            print("lmp not on PATH: LAMMPS side skipped (Debian: apt-get install -y lammps)")

    if not a.no_pack:
        from dem.packing import pack
        npk = 1000 if a.quick else 10000
        t0 = time.perf_counter()
        res = pack(npk, p_over_kn=1e-4, seed=0)
        r = res.report
        print(f"pack N={npk} p/kn=1e-4 mu=0.5 wall_s={time.perf_counter() - t0:.1f} steps={r['steps']} "
              f"converged={r['converged']} phi={r['phi']:.4f} Z={r['Z']:.3f} Nc={r['n_contacts']} "
              f"psi6={r['psi6']:.3f} psi6_local={r['psi6_local']:.3f} unbalanced={r['unbalanced']:.2e} "
              f"rel_p_err={r['rel_p_err']:.1e} particle_steps_per_s={r['particle_steps_per_s']:.3e}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
