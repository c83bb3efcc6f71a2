"""Throughput of the numba disk DEM against LAMMPS (GRANULAR, serial) on the same dense state.

    python -m studies.bench_throughput [--quick] [--repeats 3] [--ns 10000 100000]
                                       [--no-lammps] [--no-pack] [--work DIR] [--threads N]
    python -m studies.bench_throughput --against REV [--laws default lammps] [--ab-n 100000]
                                       [--repeats 4] [--chunks 200] [--chunk-steps 10]

Scene (LJ-like units: mean diameter d = 1, a d = 1 disk has mass 1): 10 000 disks, diameters
uniform in [0.9, 1.1], periodic square cell at solid fraction 0.84, prepared here (random gas at
phi 0.3, compression at constant strain rate to phi 0.84 in 20 000 steps with local damping,
relaxation, velocities zeroed) and tiled rx x ry to N. The *same* state is written for LAMMPS
(``dem.io.write_lammps_data``), which tiles it the same way (``replicate``): both codes start from
identical positions. Contact law: linear kn = 1e4, kt = kn with history, Coulomb mu = 0.5,
contact dashpots of damping ratio 0.05 for a pair of d = 1 disks, dt = 0.1 * 2 sqrt(m/kn) = 0.002,
skin 0.1 d, no local damping; 200 untimed warm-up steps, then the timed run.

Laws run on our side (both timed, both reported against the same LAMMPS runs):

* ``lammps-law``: :class:`dem.engine.contact_laws.LammpsHookeHistory` with LAMMPS' numbers (dashpots
  ``m_eff gamma``, ``gamma = 2 zeta sqrt(kn / (m1/2))``, cap ``mu |fn|``, projected shear history,
  LAMMPS start-up) - the same physics as LAMMPS' ``gran/hooke/history`` to round-off;
* ``default``: the engine's own :class:`~dem.engine.contact_laws.LinearFriction` (damping ratio 0.05 per
  pair, tangential dashpot, cap ``mu max(fn, 0)``, scalar history).

The LAMMPS inputs are in ``studies/lammps_bench/`` (``in.bench``; ``in.prep`` for the preparation
peer). The runs are interleaved (ours, LAMMPS, ours, LAMMPS, ...) so that load from other
processes hits both alike; every repeat is printed with the load average, then the median, the
spread (min-max) and the ratio of medians. Times are wall clock (LAMMPS: its "Loop time"); the CPU
time of the same runs (ours: process time; LAMMPS: loop time x its "CPU use") is printed too,
since on a loaded machine it is the steadier of the two. Also times :func:`dem.engine.packing.pack` of
1e4 disks at p/kn = 1e-4 against LAMMPS' ``in.prep`` of 1e4 disks, interleaved (1e3 and no
``in.prep`` with --quick). Figures are printed, never asserted.

``--against REV`` compares this code with a git revision of this repository instead (no LAMMPS):
the revision is extracted with ``git archive`` into the work folder (``--against-dir DIR`` takes
a checkout instead), the same tiled state (``--ab-n`` disks) is written once, and
``studies/bench_ab_worker.py`` times each law in separate processes, one per code and repeat,
interleaved (this code, the revision, the revision, this code, ...: the order alternates so that a
drift in the machine's load hits both alike), each code with its own numba cache. Per process: the
CPU time per step of the fastest and of the median of ``--chunks`` chunks of ``--chunk-steps``
steps (the fastest chunk is the steadier figure under load), and the CPU rates of the whole run
(particle-steps/s and contact-steps/s). Printed per law: every process, the medians with their
spread, the median of the paired ratios (this code over the revision), and whether the two codes
ended on the same positions and velocities bit for bit.

``--instructions`` (with ``--against``; needs ``valgrind`` and ``cc``) counts instead of timing,
independent of the machine's load: each code's worker runs under ``valgrind --tool=callgrind``
and reports the instructions retired per step (``--count-steps`` steps after the warm-up; with
``--parts``, per call of each component, both codes in one process). Valgrind 3.19 runs no
AVX-512, so both codes are compiled for ``haswell`` (AVX2, FMA; ``NUMBA_CPU_NAME`` and
``NUMBA_CPU_FEATURES``, the numba cache filled by a short native run first): the counts are of
that build, not of the one a run on this machine's CPU uses. An instruction count is not a time
(an atomic reference-count update or a cache miss costs many cycles per instruction); it is the
load-independent half of the comparison.

``--parts`` (with ``--against``) times the step's components instead, each code's kernels on the
same arrays in one process (``studies/bench_ab_parts.py``: the pair-force kernel, the kick, the
neighbour rebuild as the control; the revision's package imported a second time as ``dem_rev``),
``--repeats`` processes per law; printed per component: the minima, the ratio of minima and the
median of the per-round ratios (this code over the revision, > 1 slower).
"""
from __future__ import annotations

import argparse
import glob
import io as _io
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from dem import io
from dem.engine.cell import StrainRate
from dem.engine.contact_laws import LammpsHookeHistory, LinearFriction
from dem.engine.integrate import Guard, Loop, Simulation
from dem.engine.lammps import lammps_available
from dem.engine.packing import PackingProtocol, pack
from dem.engine.state import State
from studies.common import add_out, cli_out_dir, report_to

INPUTS = Path(__file__).resolve().parent / "lammps_bench"
ROOT = Path(__file__).resolve().parent.parent
WORKER = Path(__file__).resolve().parent / "bench_ab_worker.py"
PARTS = Path(__file__).resolve().parent / "bench_ab_parts.py"
KN = 1e4
DT = 0.1 * 2.0 * math.sqrt(1.0 / KN)
ZETA = 0.05
E_REST = math.exp(-ZETA * math.pi / math.sqrt(1 - ZETA ** 2))
GAMMA = 2.0 * ZETA * math.sqrt(KN / 0.5)
RHO = 4.0 / math.pi
SKIN = 0.1
WARM = 200


def bench_law():
    """The engine's own law of the benchmark (damping ratio 0.05 per pair)."""
    return LinearFriction(kn=KN, kt=KN, mu=0.5, restitution=E_REST, tangential_damping=True)


def lammps_law():
    """LAMMPS' ``gran/hooke/history 1e4 1e4 gamma gamma 0.5 1`` of ``in.bench``."""
    return LammpsHookeHistory(kn=KN, kt=KN, gamma_n=GAMMA, gamma_t=GAMMA, mu=0.5)


#: the laws of ``--against``: (class name, keywords, start-up); ``arms`` is the default law with
#: contact-point spin arms
AB_LAWS = {
    "default": ("LinearFriction", dict(kn=KN, kt=KN, mu=0.5, restitution=E_REST, tangential_damping=True),
                "leapfrog"),
    "arms": ("LinearFriction", dict(kn=KN, kt=KN, mu=0.5, restitution=E_REST, tangential_damping=True,
                                    contact_arms=True), "leapfrog"),
    "lammps": ("LammpsHookeHistory", dict(kn=KN, kt=KN, gamma_n=GAMMA, gamma_t=GAMMA, mu=0.5), "lammps"),
}


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
    sim = Simulation(st, bench_law(), dt=DT, damping=0.7, control=StrainRate([[rate, 0], [0, rate]]),
                     loop=Loop(skin=SKIN))
    sim.run(ncomp)
    sim.control = StrainRate(np.zeros((2, 2)))
    st.L[:] = 0.0
    sim.run(nrelax)
    st.v[:] = 0.0
    st.omega[:] = 0.0
    return st


def tile(st, rx, ry):
    """Replicate a periodic state rx x ry times (history dropped, list rebuilt on the first step),
    in LAMMPS ``replicate`` order."""
    h = st.h
    xs, rs = [], []
    for a in range(rx):
        for b in range(ry):
            xs.append(st.x + h @ np.array([a, b]))
            rs.append(st.radius)
    H = h @ np.diag([rx, ry])
    return State.from_disks(np.concatenate(xs), np.concatenate(rs), H, rho=RHO, spins=True)


def tiling(n, nbase=10000):
    if n % nbase:
        raise ValueError(f"N must be a multiple of {nbase}, got {n}")
    k = n // nbase
    ry = max(j for j in range(1, int(math.isqrt(k)) + 1) if k % j == 0)
    return k // ry, ry


def run_ours(base, n, steps, law, startup="leapfrog", threads=1):
    """Warm-up then a timed run; returns (wall particle-steps/s, CPU particle-steps/s, sim)."""
    st = tile(base, *tiling(n, base.n))
    sim = Simulation(st, law, dt=DT, damping=0.0, startup=startup, guard=Guard(unsafe_dt=True),
                     loop=Loop(skin=SKIN, sort_every=50, threads=threads))
    sim.run(WARM)
    c0 = time.process_time()
    rep = sim.run(steps)
    cpu = time.process_time() - c0
    return rep["particle_steps_per_s"], n * steps / cpu, sim


def write_base(base, path):
    cfg = io.Configuration(positions=base.x, radii=base.radius, cell=base.h, ids=np.arange(1, base.n + 1),
                           fields={"density": np.full(base.n, base.rho)})
    io.write_lammps_data(path, cfg, velocities=False, title="studies.bench_throughput dense state")


def _loops(log):
    """(loop time [s], CPU use [%], steps, atoms) of every run in a LAMMPS log."""
    out, cur = [], None
    for line in open(log, errors="replace"):
        m = re.match(r"Loop time of (\S+) on \d+ procs for (\d+) steps with (\d+) atoms", line)
        if m:
            cur = [float(m.group(1)), float("nan"), int(m.group(2)), int(m.group(3))]
            out.append(cur)
        m = re.match(r"\s*([\d.]+)% CPU use", line)
        if m and cur is not None:
            cur[1] = float(m.group(1))
    return out


def run_lammps_bench(data, n, nbase, steps, work):
    """One in.bench run; returns (wall particle-steps/s, CPU particle-steps/s, log path)."""
    rx, ry = tiling(n, nbase)
    log = os.path.join(work, f"bench_{n}_{time.time_ns()}.log")
    subprocess.run(["lmp", "-in", str(INPUTS / "in.bench"), "-var", "base", data, "-var", "rx", str(rx),
                    "-var", "ry", str(ry), "-var", "steps", str(steps), "-var", "warm", str(WARM),
                    "-var", "skin", str(SKIN), "-log", log, "-screen", "none"],
                   check=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
    loop, cpu_pct, st, atoms = _loops(log)[1]   # run 0: warm-up, run 1: timed
    return atoms * st / loop, atoms * st / (loop * cpu_pct / 100.0), log


def _stats(vals):
    return statistics.median(vals), min(vals), max(vals)


def checkout_revision(rev, folder):
    """Extract git revision ``rev`` of this repository into ``folder`` (``git archive``: the
    repository's own state is not touched). Returns the folder."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev], check=True,
                         capture_output=True).stdout
    os.makedirs(folder, exist_ok=True)
    with tarfile.open(fileobj=_io.BytesIO(tar)) as t:
        t.extractall(folder, filter="data")
    return folder


def run_worker(checkout, state, spec, chunks, chunk_steps, cache):
    """One :mod:`studies.bench_ab_worker` process on ``checkout`` (its numba cache in ``cache``,
    one thread); returns its JSON line as a dict."""
    env = dict(os.environ, PYTHONPATH=str(checkout), NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS="1",
               OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, str(WORKER), str(state), str(spec), str(WARM), str(chunks),
                        str(chunk_steps)], cwd=str(checkout), env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"benchmark worker failed on {checkout}:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


#: the build counted under valgrind (no AVX-512 in valgrind 3.19): NUMBA_CPU_NAME, NUMBA_CPU_FEATURES
CG_CPU = ("haswell", "+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+cx8,+f16c,+fma,+fxsr,+lzcnt,+mmx,+movbe,+popcnt,"
                     "+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave")


def callgrind_counts(out):
    """{dump name: instructions retired} of the callgrind dumps ``out.1``, ``out.2``, ... written
    at the client requests of :func:`studies.bench_ab_worker.callgrind` (``out`` itself, the
    total at exit, is left out)."""
    res = {}
    for f in glob.glob(glob.escape(out) + ".*"):
        name = total = None
        for line in open(f, errors="replace"):
            if line.startswith("desc: Trigger: Client Request: "):
                name = line.split("Client Request: ", 1)[1].strip()
            elif line.startswith("summary:"):
                total = int(line.split()[1])
        if name is not None and total is not None:
            res[name] = total
            res[name + ":jit"] = _jit_instructions(f)
    return res


def _jit_instructions(dump):
    """The instructions of a callgrind dump in code without a symbol file: numba's compiled
    kernels (the rest is CPython, numpy, numba's dispatch, libc)."""
    r = subprocess.run(["callgrind_annotate", "--inclusive=no", "--threshold=100", dump], capture_output=True,
                       text=True)
    return sum(int(m.group(1).replace(",", "")) for m in re.finditer(r"^\s*([\d,]+) \([^)]*\)\s+\?\?\?:", r.stdout,
                                                                        re.M))


def run_counted(checkout, script, args, cache, out):
    """``script args`` on ``checkout`` under callgrind (the haswell build of :data:`CG_CPU`, its
    numba cache in ``cache`` filled by a native run first); returns (its JSON line, its counts)."""
    env = dict(os.environ, PYTHONPATH=str(checkout), NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS="1",
               OMP_NUM_THREADS="1", NUMBA_CPU_NAME=CG_CPU[0], NUMBA_CPU_FEATURES=CG_CPU[1])
    for cmd, extra in (([sys.executable], {}), (["valgrind", "--tool=callgrind", "--instr-atstart=no",
                                                  f"--callgrind-out-file={out}", sys.executable],
                                                 {"DEM_CALLGRIND": "1"})):
        r = subprocess.run(cmd + [str(script)] + [str(x) for x in args], cwd=str(checkout), env=dict(env, **extra),
                           capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"{script} failed on {checkout} ({cmd[0]}):\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1]), callgrind_counts(out)


def compare_counted(a, sides, state, work):
    """``--instructions``: instructions retired per step (or per component call with ``--parts``)."""
    other = sides["revision"][0]
    for name in a.laws:
        cls, kw, startup = AB_LAWS[name]
        spec = os.path.join(work, f"law_{name}.json")
        with open(spec, "w") as fh:
            json.dump({"law": cls, "kwargs": kw, "startup": startup, "dt": DT, "skin": SKIN}, fh)
        if a.parts:
            res, counts = run_counted(ROOT, PARTS, [other, state, spec, 1, 1], os.path.join(work, "cg_parts"),
                                      os.path.join(work, f"cg_parts_{name}.out"))
            same = "bit-identical" if res["same_forces"] and res["same_kick"] else "DIFFER"
            print(f"  {name:8s} outputs {same}; instructions per call (haswell build), this code / revision:")
            for part in res["counted"]:
                t = [counts[f"{part}-this-{k}"] for k in range(2)]
                r = [counts[f"{part}-rev-{k}"] for k in range(2)]
                tj, rj = counts[f"{part}-this-1:jit"], counts[f"{part}-rev-1:jit"]
                print(f"    {part:8s} {t[0]:.6e} / {r[0]:.6e} = {t[0] / r[0]:.4f} (second call {t[1] / r[1]:.4f}); "
                      f"compiled code only (second call) {tj:.6e} / {rj:.6e} = {tj / rj:.4f}", flush=True)
            continue
        per = {}
        for side, (path, _) in sides.items():
            res, counts = run_counted(path, WORKER, [state, spec, WARM, 1, a.count_steps],
                                      os.path.join(work, f"cg_{side.replace(' ', '_')}"),
                                      os.path.join(work, f"cg_{name}_{side.replace(' ', '_')}.out"))
            per[side] = (counts["steps"] / res["steps"], res["hash"], counts["steps:jit"] / res["steps"])
            print(f"  {name:8s} {side:9s} {per[side][0]:.6e} instructions per step ({res['steps']} steps, "
                  f"N={res['n']}, contacts={res['contacts']}, hash={res['hash']})", flush=True)
        same = "bit-identical" if per["this code"][1] == per["revision"][1] else "DIFFER"
        print(f"  {name:8s} this code / revision: {per['this code'][0] / per['revision'][0]:.4f} "
              f"(instructions per step, haswell build; compiled code only "
              f"{per['this code'][2] / per['revision'][2]:.4f}); trajectories {same}", flush=True)


def _ab_summary(name, runs):
    """Print the medians, spreads and paired ratios of one law's runs ({side: [dict, ...]})."""
    ours, old = runs["this code"], runs["revision"]
    for key, unit in (("cpu_ps", "particle-steps/s"), ("cpu_cs", "contact-steps/s"), ("min_ms", "ms/step"),
                      ("median_ms", "ms/step")):
        parts = []
        for side in ("revision", "this code"):
            m, lo, hi = _stats([r[key] for r in runs[side]])
            parts.append(f"{side} {m:.4g} [{lo:.4g}, {hi:.4g}]")
        print(f"  {name:8s} {key:9s} median [min, max] {unit}: " + "; ".join(parts), flush=True)
    pr = [a["cpu_ps"] / b["cpu_ps"] for a, b in zip(ours, old)]
    fast = [b["min_ms"] / a["min_ms"] for a, b in zip(ours, old)]
    best = min(r["min_ms"] for r in old) / min(r["min_ms"] for r in ours)
    same = len({r["hash"] for r in ours + old}) == 1
    print(f"  {name:8s} this code / revision (speed, > 1 faster): CPU rate, median of paired ratios "
          f"{statistics.median(pr):.3f} [{min(pr):.3f}, {max(pr):.3f}]; fastest chunk, median of paired "
          f"ratios {statistics.median(fast):.3f} [{min(fast):.3f}, {max(fast):.3f}], fastest of all {best:.3f}; "
          f"trajectories {'bit-identical' if same else 'DIFFER'} ({len(ours) + len(old)} runs)", flush=True)


def compare_parts(a, other, state, work):
    """``--parts``: the components of a step, both codes in one process per repeat and law."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=os.path.join(work, "numba_parts"),
               NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    for name in a.laws:
        cls, kw, startup = AB_LAWS[name]
        spec = os.path.join(work, f"law_{name}.json")
        with open(spec, "w") as fh:
            json.dump({"law": cls, "kwargs": kw, "startup": startup, "dt": DT, "skin": SKIN}, fh)
        for rep in range(a.repeats):
            r = subprocess.run([sys.executable, str(PARTS), str(other), state, spec, str(a.parts_rounds),
                                str(a.parts_calls)], cwd=str(ROOT), env=env, capture_output=True, text=True)
            if r.returncode != 0:
                raise RuntimeError(f"parts worker failed:\n{r.stderr[-3000:]}")
            res = json.loads(r.stdout.strip().splitlines()[-1])
            same = "bit-identical" if res["same_forces"] and res["same_kick"] else "DIFFER"
            print(f"  rep {rep + 1} {name:8s} load={res['load']:.1f} outputs {same}", flush=True)
            for part in ("forces", "kick", "rebuild"):
                q = res[part]
                lo, hi = q["round_ratio_range"]
                print(f"    {part:8s} min this {q['this_min_us']:.1f} us, revision {q['rev_min_us']:.1f} us: "
                      f"ratio of minima {q['ratio_of_min']:.3f}, median of round ratios "
                      f"{q['median_round_ratio']:.3f} [{lo:.3f}, {hi:.3f}] (> 1: this code slower)", flush=True)


def compare_revision(a, base, work):
    """``--against``: this code against a git revision (or a checkout), interleaved processes."""
    other = Path(a.against_dir) if a.against_dir else Path(checkout_revision(a.against, os.path.join(work, "rev")))
    label = a.against_dir or a.against
    st = tile(base, *tiling(a.ab_n, base.n))
    state = os.path.join(work, "ab_state.npz")
    np.savez(state, x=st.x, r=st.radius, h=st.h, rho=RHO)
    sides = {"this code": (ROOT, os.path.join(work, "numba_this")), "revision": (other, os.path.join(work, "numba_rev"))}
    if a.instructions:
        print(f"\n--against {label} --instructions{' --parts' if a.parts else ''}: N={a.ab_n}, callgrind, "
              f"build {CG_CPU[0]}", flush=True)
        compare_counted(a, sides, state, work)
        return None
    if a.parts:
        print(f"\n--against {label} --parts: N={a.ab_n}, {a.parts_rounds} rounds of {a.parts_calls} calls "
              f"per component and code (wall time, one thread, both codes in one process)", flush=True)
        compare_parts(a, other, state, work)
        return None
    print(f"\n--against {label}: N={a.ab_n}, {a.chunks} chunks of {a.chunk_steps} steps after {WARM} "
          f"(CPU time, one thread, separate processes, order alternating)", flush=True)
    runs = {name: {side: [] for side in sides} for name in a.laws}
    for rep in range(a.repeats):
        for name in a.laws:
            cls, kw, startup = AB_LAWS[name]
            spec = os.path.join(work, f"law_{name}.json")
            with open(spec, "w") as fh:
                json.dump({"law": cls, "kwargs": kw, "startup": startup, "dt": DT, "skin": SKIN}, fh)
            order = list(sides) if rep % 2 == 0 else list(sides)[::-1]
            for side in order:
                path, cache = sides[side]
                res = run_worker(path, state, spec, a.chunks, a.chunk_steps, cache)
                runs[name][side].append(res)
                print(f"  rep {rep + 1} {name:8s} {side:9s} fastest {res['min_ms']:.3f} median {res['median_ms']:.3f} "
                      f"ms/step, cpu {res['cpu_ps']:.4e} particle-steps/s {res['cpu_cs']:.4e} contact-steps/s "
                      f"contacts={res['contacts']} hash={res['hash']} load={res['load']:.1f}", flush=True)
    print(f"\nsummary, this code against {label}:")
    for name in a.laws:
        _ab_summary(name, runs[name])
    return runs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (a few minutes)")
    ap.add_argument("--ns", type=int, nargs="*", default=[10000, 100000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-lammps", action="store_true")
    ap.add_argument("--no-pack", action="store_true")
    ap.add_argument("--work", default=None, help="folder for LAMMPS logs and data (default: a temporary one)")
    ap.add_argument("--threads", type=int, default=1,
                    help="also time the default law with this many threads (multi-core; reported apart from "
                         "the per-core ratios, against the same serial LAMMPS runs)")
    ap.add_argument("--against", default=None, metavar="REV",
                    help="compare this code with git revision REV instead of LAMMPS (see the module doc)")
    ap.add_argument("--against-dir", default=None, metavar="DIR", help="as --against, with a checkout DIR")
    ap.add_argument("--laws", nargs="+", default=["default", "lammps"], choices=sorted(AB_LAWS),
                    help="laws of --against")
    ap.add_argument("--ab-n", type=int, default=100000, help="disks of --against (a multiple of 10000)")
    ap.add_argument("--chunks", type=int, default=200, help="timed chunks per process of --against")
    ap.add_argument("--chunk-steps", type=int, default=10, help="steps per chunk of --against")
    ap.add_argument("--parts", action="store_true",
                    help="with --against: time the pair-force kernel, the kick and the rebuild of both codes "
                         "in one process on the same arrays (studies/bench_ab_parts.py)")
    ap.add_argument("--instructions", action="store_true",
                    help="with --against: count the instructions retired (callgrind) instead of timing")
    ap.add_argument("--count-steps", type=int, default=50, help="counted steps per process of --instructions")
    ap.add_argument("--parts-rounds", type=int, default=30, help="rounds of --parts")
    ap.add_argument("--parts-calls", type=int, default=20, help="calls per component, code and round of --parts")
    add_out(ap, "bench_throughput")
    a = ap.parse_args(argv)
    if a.against or a.against_dir:
        return _main_against(a)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    steps_of = {n: (max(100, int(3e6 / n)) if a.quick else max(150, int(3e7 / n))) for n in a.ns}
    print(f"loadavg at start {os.getloadavg()} (2-core machine shared with other jobs: see the spread)")

    t0 = time.perf_counter()
    base = dense_base(ncomp=5000 if a.quick else 20000, nrelax=1000 if a.quick else 3000)
    print(f"ours-prep N=10000 wall_s={time.perf_counter() - t0:.2f} phi={base.solid_fraction:.4f} "
          f"(constant-rate compression, {'quick' if a.quick else 'full'})", flush=True)
    use_lammps = not a.no_lammps and lammps_available()
    if not a.no_lammps and not use_lammps:
        print("lmp not on PATH: LAMMPS side skipped (Debian: apt-get install -y lammps)")
    tmp = tempfile.TemporaryDirectory(prefix="dem-bench-lammps-")
    work = a.work or tmp.name
    os.makedirs(work, exist_ok=True)
    data = os.path.join(work, "dense.data")
    write_base(base, data)

    laws = {"lammps-law": (lammps_law(), "lammps", 1), "default": (bench_law(), "leapfrog", 1)}
    if a.threads > 1:
        laws[f"default-{a.threads}t"] = (bench_law(), "leapfrog", a.threads)
    for n in a.ns:
        steps = steps_of[n]
        res = {k: ([], []) for k in (*laws, "LAMMPS")}
        print(f"\nN={n} steps={steps} (interleaved repeats: {', '.join(res)})", flush=True)
        for rep in range(a.repeats):
            for name, (law, startup, threads) in laws.items():
                load = os.getloadavg()[0]
                w, c, sim = run_ours(base, n, steps, law, startup, threads)
                res[name][0].append(w)
                res[name][1].append(c)
                m = sim.measure()
                print(f"  rep {rep + 1} ours {name:10s} wall {w:.4e} cpu {c:.4e} particle-steps/s "
                      f"builds={sim.n_rebuilds} Z={2 * m['n_contacts'] / n:.3f} loadavg={load:.1f}", flush=True)
            if use_lammps:
                load = os.getloadavg()[0]
                w, c, log = run_lammps_bench(data, n, base.n, steps, work)
                res["LAMMPS"][0].append(w)
                res["LAMMPS"][1].append(c)
                print(f"  rep {rep + 1} LAMMPS gran/hooke/history wall {w:.4e} cpu {c:.4e} particle-steps/s "
                      f"loadavg={load:.1f}", flush=True)
        for name, (wall, cpu) in res.items():
            if not wall:
                continue
            mw, lw, hw = _stats(wall)
            mc, lc, hc = _stats(cpu)
            print(f"N={n} {name:10s} wall median {mw:.4e} [{lw:.3e}, {hw:.3e}]  cpu median {mc:.4e} "
                  f"[{lc:.3e}, {hc:.3e}] particle-steps/s", flush=True)
        if use_lammps:
            lm_w, lm_c = statistics.median(res["LAMMPS"][0]), statistics.median(res["LAMMPS"][1])
            for name, (_, _, threads) in laws.items():
                pair_ratios = [o / lm for o, lm in zip(res[name][0], res["LAMMPS"][0])]
                kind = "(serial, per core)" if threads == 1 else f"(MULTI-CORE, {threads} threads against serial LAMMPS)"
                print(f"N={n} ratio ours({name})/LAMMPS: wall {statistics.median(res[name][0]) / lm_w:.3f} "
                      f"(per repeat {min(pair_ratios):.2f}-{max(pair_ratios):.2f}), "
                      f"cpu {statistics.median(res[name][1]) / lm_c:.3f} {kind}", flush=True)

    if not a.no_pack:
        npk = 1000 if a.quick else 10000
        t0 = time.perf_counter()
        res = pack(PackingProtocol(n=npk, p_over_kn=1e-4, mu=0.5, mu_prep=0.5, seed=0))
        r = res.report
        print(f"\npack N={npk} p/kn=1e-4 mu=0.5 wall_s={time.perf_counter() - t0:.1f} steps={r['steps']} "
              f"converged={r['converged']} phi={r['phi']:.4f} Z={r['Z']:.3f} "
              f"particle_steps_per_s={r['particle_steps_per_s']:.3e} loadavg={os.getloadavg()[0]:.1f}", flush=True)
        if use_lammps and not a.quick:
            t0 = time.perf_counter()
            subprocess.run(["lmp", "-in", str(INPUTS / "in.prep"), "-var", "N", "10000", "-var", "out",
                            os.path.join(work, "prep_10000.data"), "-log", os.path.join(work, "prep.log"),
                            "-screen", "none"], check=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
            print(f"lammps-prep N=10000 wall_s={time.perf_counter() - t0:.1f} loadavg={os.getloadavg()[0]:.1f}",
                  flush=True)
    tmp.cleanup()
    return 0


def _main_against(a):
    report_to(cli_out_dir(a.out, cache=False))
    tiling(a.ab_n)   # a clear error before the preparation
    print(f"loadavg at start {os.getloadavg()}")
    base = dense_base(ncomp=5000 if a.quick else 20000, nrelax=1000 if a.quick else 3000)
    tmp = tempfile.TemporaryDirectory(prefix="dem-bench-ab-")
    work = a.work or tmp.name
    os.makedirs(work, exist_ok=True)
    compare_revision(a, base, work)
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
