"""Cost of the relaxation hierarchy on sphere networks (3D) against the exact solve.

    python -m studies.bench_spheres [--n 10000 100000] [--keep 0.6] [--kt 0.5] [--tol 0.01] [--bound auto|dual|spectral]
                                    [--exact auto|yes|no] [--max-order 60] [--max-memory BYTES] [--phases]
                                    [--stop-after ORDERS]
                                    [--setup-options [NAME ...]] [--setup-only] [--dual-clusters SIZE]
                                    [--amg NAME]

A jittered, diluted, polydisperse FCC (``fcc_network``: 4 m^3 spheres, m the smallest giving at
least ``--n``; 8 % compression, jitter 0.03 D, radii 0.47-0.53 D, a fraction ``--keep`` of the
12 contacts per sphere kept at random), frictional (kt = ``--kt`` kn). For each size: the
assembly, the hierarchy (multilevel CG to ``--tol``, no soft-mode search; the certified lower
bound by the sparse inertia count up to ``microhom.spectral.CERTIFIED_MAX_DOF`` unknowns) and
the exact sparse solve (``dem.analysis.stiffness``) in the same run, with K and G of both,
wall times and the peak resident memory. The machine is shared: the load average is printed.
``--phases`` prints a line per phase of the hierarchy (assembly, particle blocks, the dual bound's
statics, the multilevel setup, each CG order, each dual bound): wall and CPU time and the peak
resident memory of the phase (``VmHWM`` of /proc/self/status, reset before each phase through
/proc/self/clear_refs where the kernel allows it), and ``plan_memory``'s prediction;
``--stop-after ORDERS`` stops it after that many CG orders (the setup's and the first orders' cost
at a size whose whole run would not fit the time; issue 26).
``--setup-options`` (issue 26) runs the hierarchy (dual bound) once per multilevel option of
``SETUP_OPTIONS`` (all by default) on the same network and prints, per option, the setup's CPU
time and peak per pyamg stage (``setup_stages``), the operator complexity and levels, the orders
to ``--tol`` and the interval, the hierarchy's CPU; the exact solve once where ``--exact`` asks.
"""
from __future__ import annotations

import argparse
import functools
import os
import resource
import time
import warnings

import numpy as np

from dem.analysis.stiffness import stiffness
from microhom import lattices
from microhom.hierarchy import plan_memory, relaxation_hierarchy
from microhom.network import from_overlaps, from_pairs


def fcc_network(n_min, keep=0.6, kt=0.5, seed=0, squeeze=0.92, jitter=0.03):
    """The benchmark's network of at least ``n_min`` spheres (module docstring)."""
    m = max(2, int(np.ceil((n_min / 4) ** (1 / 3))))
    rng = np.random.default_rng(seed)
    lat = lattices.fcc(m, diameter=1.0)
    pos = lat.positions * squeeze + rng.normal(scale=jitter, size=lat.positions.shape)
    radii = rng.uniform(0.47, 0.53, size=lat.n_particles)
    full = from_overlaps(pos, radii, lat.cell * squeeze, kn=1.0, tolerance=0.0)
    sel = rng.random(full.n_contacts) < keep
    return from_pairs(full.positions, full.radii, full.cell, full.pairs[sel],
                      shifts=full.image_shifts()[sel], kn=1.0, kt=kt, fn=full.overlaps[sel])


def _rss_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20


def _status_gb():
    """(VmHWM, VmRSS) of this process [GiB] (NaN where /proc is missing)."""
    out = {"VmHWM": float("nan"), "VmRSS": float("nan")}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                key = line.split(":")[0]
                if key in out:
                    out[key] = int(line.split()[1]) / 2 ** 20
    except OSError:
        pass
    return out["VmHWM"], out["VmRSS"]


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")                 # resets VmHWM to the current RSS (Linux >= 4.0)
    except OSError:
        pass


class StopAfter(Exception):
    """Raised by the instrumented CG step after ``--stop-after`` orders (a measurement of the
    setup and the first orders; the hierarchy returns no interval)."""


def instrument_phases(stop_after=None):
    """Wrap the hierarchy's phases (module docstring, ``--phases``) to print one line each;
    ``stop_after`` (int >= 1 or None): raise :class:`StopAfter` after that many CG orders.
    Returns a function that puts the originals back."""
    import microhom.hierarchy as hi
    if stop_after is not None and (int(stop_after) != stop_after or stop_after < 1):
        raise ValueError(f"stop_after must be an integer >= 1 (CG orders) or None, got {stop_after!r}")
    done = [0]
    saved = []

    def wrap(owner, name, label):
        f = getattr(owner, name)
        saved.append((owner, name, f))

        @functools.wraps(f)
        def timed(*a, **k):
            _reset_peak()
            t, c = time.perf_counter(), time.process_time()
            if len(a) == 1 and set(k) == {"release"} and k["release"] is not None:
                # amg_preconditioner(asm, release=...): the caller drops H in release(); this frame
                # must not keep the assembly alive through pyamg's setup (issue 26)
                box, rel = list(a), k["release"]
                del a, k

                def release(*args):
                    box.clear()
                    rel(*args)
                r = f(box.pop(), release=release)
            else:
                r = f(*a, **k)
            peak, rss = _status_gb()
            print(f"    phase {label:20s} wall {time.perf_counter() - t:8.2f} s  cpu {time.process_time() - c:8.2f} s  "
                  f"peak {peak:6.2f} GiB  rss {rss:6.2f} GiB  load {os.getloadavg()[0]:.1f}", flush=True)
            return r
        setattr(owner, name, timed)
    for name, label in (("assemble", "assembly"), ("block_preconditioner", "particle blocks"),
                        ("build_equilibrator", "dual statics"), ("amg_preconditioner", "multilevel setup"),
                        ("dual_lower_bound", "dual bound")):
        wrap(hi, name, label)
    wrap(hi._BlockPCG, "step", "CG order")
    if stop_after is not None:
        step = hi._BlockPCG.step

        @functools.wraps(step)
        def counted(self):
            step(self)
            done[0] += 1
            if done[0] >= stop_after:
                raise StopAfter(f"stopped after {done[0]} CG order(s) (--stop-after)")
        hi._BlockPCG.step = counted

    def restore():
        for owner, name, f in reversed(saved):
            setattr(owner, name, f)
    return restore


#: --bound: the lower-bound route of the hierarchy (relaxation_hierarchy's spectral_bound, dual_bound)
BOUNDS = {"auto": dict(), "dual": dict(spectral_bound="none", dual_bound=True),
          "spectral": dict(dual_bound=False)}


#: --setup-options: keyword arguments of microhom.multilevel.amg_preconditioner, one at a time
SETUP_OPTIONS = {
    "default": {},
    "rigid": dict(candidates="rigid"),             # 6 near-null vectors per sphere instead of 9
    "jacobi": dict(smooth="jacobi"),               # one Jacobi step instead of energy minimisation
    "jacobi+rigid": dict(smooth="jacobi", candidates="rigid"),   # both (issue 26: the setup's transient)
    "jacobi+rigid+f32": dict(smooth="jacobi", candidates="rigid", coarse_dtype=np.float32),  # coarse levels float32
    "plain": dict(smooth="none"),                  # plain aggregation
    "theta0.1": dict(theta=0.1),                   # strength threshold 0.1 instead of 0
    "theta0.25": dict(theta=0.25),
    "coarse2000": dict(max_coarse=2000),           # larger coarsest level
    "noimprove": dict(improve=False),              # candidates not relaxed before aggregation
    "float32": dict(dtype=np.float32),             # the hierarchy in single precision
    "jacobi+float32": dict(smooth="jacobi", dtype=np.float32),
    "plain+float32": dict(smooth="none", dtype=np.float32),
}

#: pyamg's stages, wrapped by name in pyamg.aggregation.aggregation (setup_stages)
_STAGES = (("symmetric_strength_of_connection", "strength"), ("standard_aggregation", "aggregation"),
           ("fit_candidates", "tentative P"), ("energy_prolongation_smoother", "smooth P"),
           ("jacobi_prolongation_smoother", "smooth P"))


def setup_stages(build, *args, **kwargs):
    """Call ``build(*args, **kwargs)`` (``amg_preconditioner``) and time its pyamg stages.

    Returns (build's result, {stage: [cpu s, peak GiB]}): CPU summed over the levels, peak the
    largest ``VmHWM`` of the stage (reset at each stage's start where the kernel allows it). The
    intervals between the wrapped calls are named by position: before the first strength, "copy
    of H" (permutation, shift, BSR); between aggregation and tentative P, "improve candidates";
    after a level's smoothing, "RAP" (Galerkin product; the last one also the coarse solver's
    and smoothers' setup)."""
    import pyamg.aggregation.aggregation as agg
    marks = []                                           # (label of the interval that ends here, cpu, peak)

    def mark(label):
        marks.append((label, time.process_time(), _status_gb()[0]))
        _reset_peak()

    def gap_label(name):
        if name == "strength":
            return "copy of H" if not any(m[0] == "strength" for m in marks) else "RAP"
        return "improve candidates" if name == "tentative P" else "other"

    saved = {}
    for fn, label in _STAGES:
        f = saved[fn] = getattr(agg, fn)

        def timed(*a, _f=f, _label=label, **k):
            mark(gap_label(_label))
            r = _f(*a, **k)
            mark(_label)
            return r
        setattr(agg, fn, timed)
    try:
        _reset_peak()
        marks.append(("start", time.process_time(), 0.0))
        out = build(*args, **kwargs)
        mark("RAP")
    finally:
        for fn, f in saved.items():
            setattr(agg, fn, f)
    stages = {}
    for (_, c0, _), (label, c1, peak) in zip(marks[:-1], marks[1:]):
        s = stages.setdefault(label, [0.0, 0.0])
        s[0] += c1 - c0
        s[1] = max(s[1], peak)
    return out, stages


def setups_only(n, keep, kt, names):
    """``--setup-options ... --setup-only``: the multilevel setup alone per option on one assembly
    (no CG): CPU, peak, levels and operator complexity, one row each."""
    from microhom.kinematics import assemble
    from microhom.multilevel import amg_preconditioner
    net = fcc_network(n, keep=keep, kt=kt)
    asm = assemble(net, pin=False)
    print(f"N = {net.n_particles}, contacts {net.n_contacts}, unknowns {asm.ndof}, H non-zeros {asm.H.nnz}; "
          f"RSS {_status_gb()[1]:.2f} GiB; load {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    for name in names:
        rss = _status_gb()[1]
        c = time.process_time()
        (op, info), stages = setup_stages(amg_preconditioner, asm, **SETUP_OPTIONS[name])
        row = dict(option=name, setup_cpu=time.process_time() - c, setup_peak=max(v[1] for v in stages.values()),
                   rss_before=rss, levels=info.levels, complexity=info.operator_complexity)
        del op
        rows.append(row)
        print(f"  {name:11s} setup {row['setup_cpu']:6.1f} s CPU, peak {row['setup_peak']:.2f} GiB (RSS before "
              f"{rss:.2f}), {info.levels} levels, complexity {info.operator_complexity:.3f}", flush=True)
        print("      stages: " + "  ".join(f"{k} {v[0]:.2f} s/{v[1]:.2f} GiB" for k, v in stages.items()), flush=True)
    return rows


def compare_setups(n, keep, kt, tol, exact, names, max_order=60):
    """``--setup-options``: one hierarchy (dual bound, no soft-mode search) per option; a row each."""
    import microhom.hierarchy as hi
    from microhom.multilevel import amg_preconditioner
    net = fcc_network(n, keep=keep, kt=kt)
    print(f"N = {net.n_particles}, contacts {net.n_contacts}; load {os.getloadavg()[0]:.1f}", flush=True)
    ex = None
    if exact == "yes" or (exact == "auto" and net.n_particles <= 20_000):
        c = time.process_time()
        ex = stiffness(net)
        print(f"  exact: K = {ex.K:.6g}, G = {ex.G:.6g} ({time.process_time() - c:.1f} s CPU)", flush=True)
    with warnings.catch_warnings():                      # compile the numba kernels outside the rows
        warnings.simplefilter("ignore")
        relaxation_hierarchy(fcc_network(100, keep=keep, kt=kt), tol=tol, soft_modes=0, **BOUNDS["dual"])
    rows = []
    for name in names:
        got = {"rss": _status_gb()[1]}

        def built(asm, _opts=SETUP_OPTIONS[name], **k):
            c = time.process_time()
            (op, info), got["stages"] = setup_stages(amg_preconditioner, asm, **{**k, **_opts})
            got.update(info=info, cpu=time.process_time() - c, peak=max(v[1] for v in got["stages"].values()))
            return op, info
        hi.amg_preconditioner = built
        try:
            c = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                h = relaxation_hierarchy(net, tol=tol, soft_modes=0, max_order=max_order, **BOUNDS["dual"])
            cpu = time.process_time() - c
        finally:
            hi.amg_preconditioner = amg_preconditioner
        inside = (None if ex is None else
                  bool(h.K.lower <= ex.K <= h.K.upper and h.G.lower <= ex.G <= h.G.upper))
        row = dict(option=name, setup_cpu=got["cpu"], setup_peak=got["peak"], rss_before=got["rss"], levels=got["info"].levels,
                   complexity=got["info"].operator_complexity, orders=h.order, certified=h.certified,
                   K=(h.K.lower, h.K.upper), G=(h.G.lower, h.G.upper), exact_inside=inside, cpu=cpu)
        rows.append(row)
        st = "  ".join(f"{k} {v[0]:.2f} s/{v[1]:.2f} GiB" for k, v in got["stages"].items())
        print(f"  {name:11s} setup {row['setup_cpu']:6.1f} s CPU, peak {row['setup_peak']:.2f} GiB (RSS before the run {got['rss']:.2f}), "
              f"{row['levels']} levels, complexity {row['complexity']:.3f}; orders {h.order} "
              f"(certified {h.certified}), K [{h.K.lower:.6f}, {h.K.upper:.6f}], G [{h.G.lower:.6f}, "
              f"{h.G.upper:.6f}], exact inside {inside}; hierarchy {cpu:.1f} s CPU; process peak RSS so far "
              f"{_rss_gb():.2f} GiB", flush=True)
        print(f"      stages: {st}", flush=True)
    return rows


def _hierarchy_amg(opts):
    """``--amg``: the hierarchy's ``amg_preconditioner`` with the options ``opts``; its wrapper
    keeps no reference to the assembly through the setup (the hierarchy may drop ``H`` in
    ``release``, issue 26). Returns a function that puts the original back."""
    import inspect

    import microhom.hierarchy as hi
    real = hi.amg_preconditioner
    d = {k: v.default for k, v in inspect.signature(real).parameters.items() if v.default is not inspect.Parameter.empty}
    d.update(opts)

    def amg(*a, release=None):
        box = list(a)
        del a
        # every keyword spelled out: a call with **kwargs would hold the assembly in its argument tuple
        return real(box.pop(), sweeps=d["sweeps"], candidates=d["candidates"], smooth=d["smooth"], theta=d["theta"],
                    max_coarse=d["max_coarse"], improve=d["improve"], dtype=d["dtype"],
                    coarse_dtype=d["coarse_dtype"], release=release)
    hi.amg_preconditioner = amg

    def undo():
        hi.amg_preconditioner = real
    return undo


def run_one(n, keep, kt, tol, exact, max_order=60, max_memory=None, bound="auto", hier_memory=None):
    t0 = time.perf_counter()
    net = fcc_network(n, keep=keep, kt=kt)
    t_build = time.perf_counter() - t0
    print(f"N = {net.n_particles}, contacts {net.n_contacts} (Z = {2 * net.n_contacts / net.n_particles:.2f}), "
          f"built in {t_build:.1f} s; load {os.getloadavg()[0]:.1f}", flush=True)
    plan = plan_memory(net.n_particles, net.n_contacts, max_order=max_order, full=False, soft_modes=0,
                       dense=False, dim=net.dim)
    print(f"  plan_memory: {plan.total / 2 ** 30:.2f} GiB (assembly {plan.assembly / 2 ** 30:.2f}, "
          f"preconditioner {plan.preconditioner / 2 ** 30:.2f}, basis {plan.basis / 2 ** 30:.2f})", flush=True)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            h = relaxation_hierarchy(net, tol=tol, soft_modes=0, max_order=max_order, max_memory=hier_memory,
                                     **BOUNDS[bound])
    except StopAfter as stop:
        print(f"  {stop}: {time.perf_counter() - t0:.1f} s wall, process CPU {time.process_time():.1f} s, "
              f"peak RSS {_rss_gb():.2f} GiB", flush=True)
        return dict(N=net.n_particles, Nc=net.n_contacts, stopped=True, cpu=time.process_time(), peak_gb=_rss_gb())
    t_h = time.perf_counter() - t0
    print(f"  hierarchy ({bound} bound: {h.spectral_bound_source}): {t_h:.1f} s total (assembly {h.assembly_time:.1f}, CG {h.solve_time:.1f}, "
          f"bound {h.bound_time:.1f}), ndof {h.n_dof}, order {h.order}; peak RSS {_rss_gb():.2f} GiB", flush=True)
    print("  " + h.summary(), flush=True)
    print(f"  preconditioner setup {h.preconditioner_time:.1f} s; upper bounds per order K "
          f"{np.array2string(h.K_orders, precision=6)}, G {np.array2string(h.G_orders, precision=6)}", flush=True)
    row = dict(bound=h.spectral_bound_source, cpu=time.process_time(), N=net.n_particles, Nc=net.n_contacts, ndof=h.n_dof, order=h.order, t_hierarchy=t_h,
               t_bound=h.bound_time, K_upper=h.K.upper, K_lower=h.K.lower, G_upper=h.G.upper,
               G_lower=h.G.lower, t_exact=np.nan, K_exact=np.nan, G_exact=np.nan)
    if exact == "yes" or (exact == "auto" and net.n_particles <= 20_000):
        t0 = time.perf_counter()
        ex = stiffness(net, max_memory=max_memory)
        row.update(t_exact=time.perf_counter() - t0, K_exact=ex.K, G_exact=ex.G)
        print(f"  exact ({ex.solver if hasattr(ex, 'solver') else 'auto'}): {row['t_exact']:.1f} s, "
              f"K = {ex.K:.6g}, G = {ex.G:.6g}; peak RSS {_rss_gb():.2f} GiB", flush=True)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--keep", type=float, default=0.6)
    ap.add_argument("--kt", type=float, default=0.5)
    ap.add_argument("--tol", type=float, default=0.01)
    ap.add_argument("--exact", choices=("auto", "yes", "no"), default="auto")
    ap.add_argument("--max-order", type=int, default=60)
    ap.add_argument("--max-memory", type=float, default=None, help="bytes, for the exact solve")
    ap.add_argument("--bound", choices=tuple(BOUNDS), default="auto",
                    help="lower bound: auto (spectral certificate where it applies, else dual), dual, spectral")
    ap.add_argument("--hier-memory", type=float, default=None, help="bytes, the hierarchy's max_memory")
    ap.add_argument("--phases", action="store_true", help="a line per phase: time and peak memory")
    ap.add_argument("--stop-after", type=int, default=None, metavar="ORDERS",
                    help="with --phases: stop the hierarchy after this many CG orders (>= 1; no interval)")
    ap.add_argument("--setup-options", nargs="*", choices=tuple(SETUP_OPTIONS), default=None,
                    help="compare the multilevel setup's options (all if none named)")
    ap.add_argument("--setup-only", action="store_true", help="with --setup-options: the setup alone, no CG")
    ap.add_argument("--dual-clusters", type=int, default=None, metavar="SIZE",
                    help="the dual bound's two-level statics with clusters of about SIZE spheres "
                         "(microhom.hierarchy.DUAL_CLUSTERS; default: the code's)")
    ap.add_argument("--amg", choices=tuple(SETUP_OPTIONS), default=None,
                    help="the hierarchy's own multilevel options (a --setup-options name) for a plain or --phases run")
    a = ap.parse_args(argv)
    if a.dual_clusters is not None:
        if a.dual_clusters < 8:
            ap.error(f"--dual-clusters must be an integer >= 8, got {a.dual_clusters}")
        import microhom.hierarchy as hi
        hi.DUAL_CLUSTERS = a.dual_clusters
    if a.setup_options is not None:
        names = a.setup_options or list(SETUP_OPTIONS)
        if a.setup_only:
            return [setups_only(n, a.keep, a.kt, names) for n in a.n]
        return [compare_setups(n, a.keep, a.kt, a.tol, a.exact, names, a.max_order) for n in a.n]
    if a.stop_after is not None and (not a.phases or a.stop_after < 1):
        ap.error(f"--stop-after needs --phases and an integer >= 1, got {a.stop_after}")
    undo = _hierarchy_amg(SETUP_OPTIONS[a.amg]) if a.amg else (lambda: None)
    restore = instrument_phases(a.stop_after) if a.phases else (lambda: None)
    try:
        rows = [run_one(n, a.keep, a.kt, a.tol, a.exact, a.max_order, a.max_memory, a.bound, a.hier_memory)
                for n in a.n]
    finally:
        restore()
        undo()
    for r in rows:
        print(r)
    return rows


if __name__ == "__main__":
    main()
