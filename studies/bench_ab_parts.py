"""The step's components, this code against a revision, in one process on the same arrays (not
meant to be run by hand: ``python -m studies.bench_throughput --against REV --parts``).

    python studies/bench_ab_parts.py REVDIR STATE.npz LAW.json ROUNDS CALLS

Run from this checkout (``PYTHONPATH`` on it). The revision's ``dem`` package (``REVDIR/dem``, the
layout before or after ``dem.engine``) is imported a second time under the name ``dem_rev`` (its
imports are relative), so both codes' kernels run in one process on *the same arrays*: the same
memory, the same caches, the load of the machine the same for both at every instant. Only the
compiled code differs; a process-to-process spread of ±15 % (the shared machine) drops out.

After 200 steps of this code's ``Simulation`` on ``STATE.npz`` (``LAW.json``: see
:mod:`studies.bench_ab_worker`), the arguments that it passes to its pair-force kernel and to its
kick are recorded, and the revision's arguments are made from the same arrays (its own law's
sub-models and per-pair constants). Checked first: one call of each code's kernel from the same
inputs gives the same forces, torques, history, velocities and positions bit for bit. Then
``ROUNDS`` rounds, each with ``CALLS`` calls of every component by each code in turn (the order
alternating from round to round), the inputs restored before every call (untimed):

* ``forces``: the pair-force kernel (``pair_forces_chunked`` or ``pair_forces_serial``), no tally
  (as on nine steps of ten);
* ``kick``: ``kick_all``;
* ``rebuild``: ``neighbors.rebuild`` of the same positions, no sort: the same source in both
  codes, the control (its ratio is the harness's bias).

(The Python side of a step, numba's dispatch included, is not timed here: the revision's
``Simulation`` imported a second time dispatches ten times slower than in its own process. The
separate processes of :mod:`studies.bench_ab_worker` time it, on a 100-disk system. The same
slow dispatch is inside every timed call of the revision: about 2e6 instructions per call, most
of the revision's extra time in the pair-force kernel; ``--instructions --parts`` separates the
compiled code's count from it, see ``docs/dem.md``.)

Under ``valgrind --tool=callgrind --instr-atstart=no`` (``python -m studies.bench_throughput
--against REV --parts --instructions``) it counts instead of timing: each component of each code
runs twice from the same inputs, callgrind's counters zeroed before and dumped after every call
(dumps named ``COMPONENT-this-K``, ``COMPONENT-rev-K``; the caller reads the instructions retired).

Prints one JSON line: per component and code the minimum and median over calls of the wall time
[µs] (``perf_counter``: the minimum of a call is its uninterrupted time), the ratios this/revision
of the minima and the median over rounds of the per-round ratio of minima, the load average.
"""
import importlib
import importlib.util
import json
import os
import statistics
import sys
import time

import numpy as np


def _import_revision(revdir):
    """The revision's (contact_models, contact_laws, neighbors, integrate) imported as ``dem_rev``."""
    spec = importlib.util.spec_from_file_location("dem_rev", os.path.join(revdir, "dem", "__init__.py"),
                                                  submodule_search_locations=[os.path.join(revdir, "dem")])
    pkg = importlib.util.module_from_spec(spec)
    sys.modules["dem_rev"] = pkg
    spec.loader.exec_module(pkg)
    base = "dem_rev.engine" if os.path.isdir(os.path.join(revdir, "dem", "engine")) else "dem_rev"
    return tuple(importlib.import_module(f"{base}.{m}")
                 for m in ("contact_models", "contact_laws", "neighbors", "integrate"))


def _this():
    from dem.engine import contact_laws, contact_models, integrate, neighbors
    return contact_models, contact_laws, neighbors, integrate


def _record(mod, names, sim):
    """The last arguments of ``mod.name`` (for each name) during one step of ``sim``."""
    rec = {}
    orig = {n: getattr(mod, n) for n in names}

    def wrap(n, fn):
        def rec_call(*args):
            rec[n] = args
            return fn(*args)
        return rec_call
    for n, fn in orig.items():
        setattr(mod, n, wrap(n, fn))
    try:
        sim.step(tally=False)
    finally:
        for n, fn in orig.items():
            setattr(mod, n, fn)
    return rec


def _lattice(State):
    """100 disks of radius 0.5 on a square lattice of spacing 0.99 in a periodic cell."""
    a = 0.99
    g = np.arange(10) * a
    x = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2) + 0.3
    return State.from_disks(x, np.full(100, 0.5), np.diag([10 * a, 10 * a]), rho=4 / np.pi, spins=True)


def _simulation(mods, st, spec):
    law = getattr(mods[1], spec["law"])(**spec["kwargs"])
    loop, guard = dict(skin=spec["skin"], sort_every=50), dict(unsafe_dt=True)
    integ = mods[3]
    if hasattr(integ, "Loop"):    # the bundles (issue 23); older revisions take the keywords flat
        sim = integ.Simulation(st, law, dt=spec["dt"], damping=0.0, startup=spec["startup"],
                               guard=integ.Guard(**guard), loop=integ.Loop(**loop))
    else:
        sim = integ.Simulation(st, law, dt=spec["dt"], damping=0.0, startup=spec["startup"], **loop, **guard)
    return sim, law


def _revision_calls(rcm, rlaw, args_f, args_k, st, bundles):
    """The revision's force and kick calls on this code's recorded arrays."""
    bodies, pairs, cell, _, kick, dt, tally, forces = args_f
    pc = rlaw.pair_constants(st.mass, st.nl_i, st.nl_j)
    loop = rcm.pair_forces_chunked if rcm.vectorises(rlaw.models) else rcm.pair_forces_serial
    if bundles:
        models = getattr(rcm, "with_arm_types", lambda m: m)(rlaw.models)
        fa = (bodies, (pairs[0], pairs[1], pairs[2], pc), cell, models, kick, dt, tally, forces)
        return (loop, fa), (rcm.kick_all, args_k)
    x, v, om, th, rad, mass, inert, xref = bodies
    f, torque, out, acc = forces
    normal, damping, tangential, rolling = rlaw.models
    fa = (x, v, om, th, rad, mass, inert, xref, pairs[0], pairs[1], pairs[2], pc, rcm.Cell(*cell), normal,
          damping, tangential, rolling, tangential.HISTORY, rcm.Kick(*kick), dt, tally, f, torque, out, acc)
    b, fo, k = args_k
    ka = (b[0], b[1], fo[0], b[7], b[5], b[2], b[3], fo[1], b[6], rcm.Kick(*k))
    return (loop, fa), (rcm.kick_all, ka)


class _Restore:
    """Copies of the arrays a kernel writes, written back before each call."""

    def __init__(self, arrays):
        self.saved = [(a, a.copy()) for a in arrays if a is not None and a.size]

    def __call__(self):
        for a, c in self.saved:
            a[...] = c


def _check_same(calls, restore, outputs):
    """One call of each code from the same inputs: the outputs equal bit for bit."""
    res = []
    for fn, args in calls:
        restore()
        fn(*args)
        res.append([o.copy() for o in outputs])
    return all(np.array_equal(a, b) for a, b in zip(*res))


def _count(cg, parts, restore, parity):
    """Instructions instead of time: every component of each code twice, callgrind's counters
    zeroed before and dumped after each call (dump ``NAME-this-K`` / ``NAME-rev-K``)."""
    for k in range(2):
        for name, pair in parts.items():
            for side, (fn, args) in zip(("this", "rev"), pair):
                restore()
                cg.cg_zero()
                fn(*args) if name != "rebuild" else fn(*args, sort=False, history=parity)
                cg.cg_dump(f"{name}-{side}-{k}".encode())


def main(argv):
    revdir, path, spec_path, rounds, calls = argv[0], argv[1], argv[2], int(argv[3]), int(argv[4])
    this = _this()
    rev = _import_revision(revdir)
    d = np.load(path)
    spec = json.loads(open(spec_path).read())
    State = this[3].State
    sim, _ = _simulation(this, State.from_disks(d["x"], d["r"], d["h"], rho=float(d["rho"]), spins=True), spec)
    sim.run(200)
    st = sim.state
    loop_name = "pair_forces_chunked" if this[0].vectorises(sim.law.models) else "pair_forces_serial"
    rec = _record(this[0], (loop_name, "kick_all"), sim)
    args_f, args_k = rec[loop_name], rec["kick_all"]
    bundles = rev[0].pair_forces_chunked.py_func.__code__.co_argcount == 8
    _, rlaw = _simulation(rev, _lattice(State), spec)
    rf, rk = _revision_calls(rev[0], rlaw, args_f, args_k, st, bundles)
    ours_f = (getattr(this[0], loop_name), args_f)
    ours_k = (this[0].kick_all, args_k)
    restore = _Restore([st.x, st.v, st.omega, st.theta, args_f[1][2], sim.f, sim.torque])
    same_f = _check_same([ours_f, rf], restore, [sim.f, sim.torque, args_f[1][2]])
    same_k = _check_same([ours_k, rk], restore, [st.x, st.v] + ([st.omega, st.theta] if st.omega is not None else []))
    rb = [(m[2].rebuild, (st, sim.skin)) for m in (this, rev)]
    parts = {"forces": [ours_f, rf], "kick": [ours_k, rk], "rebuild": rb}
    from bench_ab_worker import callgrind   # this folder is sys.path[0]
    cg = callgrind()
    if cg is not None:
        _count(cg, parts, restore, sim.law.history_parity)
        print(json.dumps({"same_forces": bool(same_f), "same_kick": bool(same_k), "counted": sorted(parts)}))
        return 0
    times = {k: ([], []) for k in parts}
    ratios = {k: [] for k in parts}
    for r in range(rounds):
        for name, pair in parts.items():
            n = calls
            mins = []
            for side in ((0, 1) if r % 2 == 0 else (1, 0)):
                fn, args = pair[side]
                ts = []
                for _ in range(n):
                    restore()
                    w0 = time.perf_counter_ns()
                    fn(*args) if name != "rebuild" else fn(*args, sort=False, history=sim.law.history_parity)
                    ts.append(1e-3 * (time.perf_counter_ns() - w0))
                times[name][side].extend(ts)
                mins.append((side, min(ts)))
            m = dict(mins)
            ratios[name].append(m[0] / m[1])
    out = {"same_forces": bool(same_f), "same_kick": bool(same_k), "load": os.getloadavg()[0],
           "contacts": int(sim.measure()["n_contacts"])}
    for name, (a, b) in times.items():
        out[name] = {"this_min_us": min(a), "rev_min_us": min(b), "this_median_us": statistics.median(a),
                     "rev_median_us": statistics.median(b), "ratio_of_min": min(a) / min(b),
                     "median_round_ratio": statistics.median(ratios[name]),
                     "round_ratio_range": [min(ratios[name]), max(ratios[name])]}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
