"""The relaxation hierarchy on our own packings: validation against the exact solve, and speed.

    python -m studies.bench_hierarchy validate [--quick] [--out DIR]
    python -m studies.bench_hierarchy speed [--n 100000] [--repeats 3] [--order 8] [--solver auto]
    python -m studies.bench_hierarchy certify [--sizes 1e3,1e4,1e5] [--repeats 2] [--packing FILE.npz]

``validate``: 10 packings (N = 3000; identical and polydisperse disks; Z from near isostatic to
5.1; kt/kn in {0, 0.1, 0.25, 0.5, 1}; pre-stress included). On each: the exact solve
(``dem.analysis.stiffness``), the hierarchy up to 64 CG steps, and a certified spectral bound of the pencil
(H, M) from a shift-invert eigen-solve (a factorisation: the cost of certifying, reported) so that
the rigorous lower bounds can be checked too. Reports, per packing, the errors of the upper
bounds and of the extrapolated values at 8 and 16 steps (16 and 32 moments), whether the stated
errors hold, whether the exact value lies in every interval, and the step counts needed for
K within 2 % and G within 5 %.

``speed``: order k on one large packing against the exact solve of the same packing, in the same
run, interleaved (ours, exact, ours, exact...), spread over repeats; and statistics-only
predictions per second (``microhom.moduli.predict_moduli`` and ``microhom.closure.predict_closure``
on 1e6 parameter sets). The machine is shared: the load average is printed with the figures.

``certify`` (issue 22): time to a certified interval (relative width <= 1e-2 and 1e-3 for K and
G, the default ``relaxation_hierarchy`` and the variants of ``VARIANTS``) beside the exact solve,
interleaved (exact, tol 1e-2, tol 1e-3, exact, ...), wall and CPU time (``time.process_time``, all
threads of this process; the comparable figure on a shared machine), on the
benchmark network ``studies.bench_stiffness.diluted_triangular`` at each size and on a DEM packing
(``--packing``, a ``PackingResult`` file). Prints where the time goes (assembly, certificate and
soft modes, CG), the steps (multilevel + factorised) and whether the exact value lies inside.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
import pandas as pd
import scipy.sparse.linalg as sla

from dem.analysis.stiffness import stiffness
from microhom.hierarchy import _extrapolate, block_preconditioner, relaxation_hierarchy
from microhom.kinematics import assemble
from studies.cases import get_packing
from studies.common import out_dir, write_table

MU = 0.4877
CASES = [  # (dispersity, mu_prep, p/kn, kt/kn, seed)
    (0.0, 0.05, 1e-4, 1.0, 1), (0.0, 0.05, 1e-4, 0.1, 2), (0.2, 1.0, 1e-4, 0.25, 3),
    (0.0, 0.4, 1e-4, 0.5, 4), (0.2, 0.0, 1e-3, 1.0, 5), (0.2, 0.0, 1e-2, 0.5, 6),
    (0.2, 0.0, 5e-2, 1.0, 7), (0.2, 0.2, 1e-4, 0.1, 8), (0.2, 0.0, 1e-4, 0.0, 9),
    (0.0, 0.1, 1e-2, 0.25, 10),
]


def case_dict(disp, mu_prep, p, kt, seed, n=3000):
    mu = 0.0 if kt == 0 else MU
    return dict(n=n, p_over_kn=p, kt_over_kn=kt, mu=mu, mu_prep=mu_prep, dispersity=disp, seed=seed)


def certified_bound(net, prestress=True):
    """Smallest non-zero eigenvalue of the pencil (H, M) by shift-invert Lanczos (factorises H),
    minus 1e-6 relative for the solver tolerance; (lam, seconds)."""
    t0 = time.perf_counter()
    asm = assemble(net, prestress=prestress, pin=False)
    M = block_preconditioner(asm)[0]
    w = sla.eigsh(asm.H.tocsc(), k=8, M=M.tocsc(), sigma=-1e-9, which="LM",
                  return_eigenvectors=False, tol=1e-10)
    w = np.sort(w)
    pos = w[w > 1e-9 * np.abs(w).max()]
    lam = float(pos.min()) * (1 - 1e-6) if pos.size and (w >= -1e-9 * np.abs(w).max()).all() else None
    return lam, time.perf_counter() - t0


def steps_to(seq, exact, rel):
    """First CG step k at which |extrapolated value / exact - 1| <= rel and stays so (or -1)."""
    ok = []
    for k in range(1, len(seq)):
        v, _ = _extrapolate(seq[1:k + 1])
        ok.append(abs(v / exact - 1) <= rel)
    for k in range(len(ok)):
        if all(ok[k:]):
            return k + 1
    return -1


PRECONDITIONERS = ("amg", "block")


def up_steps_to(seq, exact, rel):
    """First CG step k whose upper bound is within rel of the exact value (or -1)."""
    ok = np.flatnonzero(seq[1:] / exact - 1 <= rel)
    return int(ok[0]) + 1 if ok.size else -1


def summary_table(df):
    """Compact per-packing table for docs/results/hierarchy.md: the multilevel hierarchy at 4 and
    8 CG steps (8 and 16 moments), its lower bound, and block Jacobi at 8 steps for comparison."""
    def pm(v, e):
        return f"{100 * v:+.2f} ± {100 * e:.2f}"
    rows = []
    for _, r in df.iterrows():
        row = {"packing": f"disp {r.dispersity:g}, mu_prep {r.mu_prep:g}, p/kn {r.p_over_kn:g}",
               "kt/kn": r.kt_over_kn, "Z": round(r.Z, 2), "G/G_aff": round(r.G_over_affine, 3)}
        for m in ("K", "G"):
            row[f"{m} up 4 [%]"] = f"{100 * r[f'{m}_up4_err']:+.2f}"
            row[f"{m} up 8 [%]"] = f"{100 * r[f'{m}_up8_err']:+.2f}"
            row[f"{m} ext 8 [%]"] = pm(r[f"{m}_ext8_err"], r[f"{m}_ext8_stated"])
            low = r[f"{m}_low8_err"]
            row[f"{m} low 8 [%]"] = "n/a" if not np.isfinite(low) else f"{100 * low:+.2f}"
            row[f"{m} block up 8 [%]"] = f"{100 * r[f'blk_{m}_up8_err']:+.2f}"
        row["steps K 2 % (block)"] = f"{int(r.K_up_steps_to)} ({int(r.blk_K_up_steps_to)})"
        row["steps G 5 % (block)"] = f"{int(r.G_up_steps_to)} ({int(r.blk_G_up_steps_to)})"
        row["exact inside"] = bool(r.exact_inside_all_intervals)
        row["neg. modes (flagged)"] = f"{int(r.n_unstable)} ({'yes' if r.flagged_unstable else 'no'})"
        row["exact s"] = round(r.exact_s, 2)
        row["8 steps s (block)"] = f"{r.hier8_s:.2f} ({r.blk_hier8_s:.2f})"
        rows.append(row)
    return pd.DataFrame(rows)


def validate(args):
    out = out_dir(args.out)
    rows = []
    cases = CASES[:3] if args.quick else CASES
    n = 400 if args.quick else 3000
    for disp, mu_prep, p, kt, seed in cases:
        case = case_dict(disp, mu_prep, p, kt, seed, n)
        res, t_pack, _ = get_packing(case)
        net = res.to_network()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            t0 = time.perf_counter()
            ex = stiffness(net, prestress=True)
            t_ex = time.perf_counter() - t0
        lam, t_lam = certified_bound(net)
        row = dict(dispersity=disp, mu_prep=mu_prep, p_over_kn=p, kt_over_kn=kt, seed=seed,
                   exact_K=ex.K, exact_G=ex.G, G_over_affine=ex.G / ex.G_affine,
                   n_unstable=ex.n_unstable, exact_s=t_ex, certify_s=t_lam, lam=lam)
        inside = True
        for prec in PRECONDITIONERS:
            pre = "" if prec == "amg" else "blk_"
            t0 = time.perf_counter()
            h = relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=64, certify_max_order=1,
                                     spectral_bound=lam if lam else "none", preconditioner=prec,
                                     soft_modes="auto" if prec == "amg" else 0)
            row[pre + "hier64_s"] = time.perf_counter() - t0
            row[pre + "flagged_unstable"] = h.unstable
            t0 = time.perf_counter()
            relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=8, spectral_bound="none",
                                 preconditioner=prec, soft_modes="auto" if prec == "amg" else 0)
            row[pre + "hier8_s"] = time.perf_counter() - t0
            row["Z"] = 2 * h.n_contacts / max(h.n_particles - h.n_rattlers, 1)
            for m, seq, lows, exact in (("K", h.K_orders, h.K_lower_orders, ex.K),
                                        ("G", h.G_orders, h.G_lower_orders, ex.G)):
                tolm = 1e-9 * max(abs(ex.K), 1e-300)
                if prec == "amg":
                    inside &= bool(np.all(seq >= exact - tolm))
                    fin = np.isfinite(lows)
                    inside &= bool(np.all(lows[fin] <= exact + tolm))
                    row[f"{m}_min_up_err"] = float(seq.min() / exact - 1)
                for k in (4, 8, 16):
                    kk = min(k, seq.size - 1)          # converged earlier: the last order holds
                    v, e = _extrapolate(seq[1:kk + 1])
                    row[f"{pre}{m}_up{k}_err"] = seq[kk] / exact - 1
                    row[f"{pre}{m}_ext{k}_err"] = v / exact - 1
                    row[f"{pre}{m}_ext{k}_stated"] = e / abs(exact)
                    row[f"{pre}{m}_ext{k}_holds"] = bool(abs(v - exact) <= e)
                    row[f"{pre}{m}_low{k}_err"] = lows[kk] / exact - 1 if np.isfinite(lows[kk]) else np.nan
                row[f"{pre}{m}_steps_to"] = steps_to(seq, exact, 0.02 if m == "K" else 0.05)
                row[f"{pre}{m}_up_steps_to"] = up_steps_to(seq, exact, 0.02 if m == "K" else 0.05)
        row["exact_inside_all_intervals"] = inside
        rows.append(row)
        print(f"disp {disp} mu_prep {mu_prep} p {p:g} kt {kt}: Z {row['Z']:.2f}, G/Gaff {row['G_over_affine']:.3f}; "
              f"8 steps: K up {row['K_up8_err']:+.4f} ext {row['K_ext8_err']:+.4f} (stated {row['K_ext8_stated']:.4f}), "
              f"G up {row['G_up8_err']:+.4f} ext {row['G_ext8_err']:+.4f} (stated {row['G_ext8_stated']:.4f}); "
              f"block 8: K up {row['blk_K_up8_err']:+.3f} G up {row['blk_G_up8_err']:+.3f}; inside {inside} "
              f"(min up err K {row['K_min_up_err']:.1e} G {row['G_min_up_err']:.1e}, negative modes {ex.n_unstable}); "
              f"times exact {t_ex:.2f} s, 8 steps {row['hier8_s']:.2f} s (block {row['blk_hier8_s']:.2f}), "
              f"certify {t_lam:.2f} s", flush=True)
    df = pd.DataFrame(rows)
    write_table(df, out, "validation", "Relaxation hierarchy against the exact solve",
                f"N = {n}, pre-stress included; load average {os.getloadavg()[0]:.1f}.")
    write_table(summary_table(df), out, "summary", "Relaxation hierarchy: errors against the exact solve",
                "Errors relative to the exact value; 'up k' the upper bound after k CG steps (2k moments), "
                "'ext +- stated' the extrapolated value's error and its stated error, 'low' the rigorous lower "
                "bound (n/a: no certified spectral bound); steps = first CG step whose upper bound is within "
                "2 % (K) / 5 % (G), -1 = not within 64 steps; neg. modes: negative eigenvalues of H found by "
                "the exact solver (then the bound theorem, which needs H >= 0, does not apply); flagged: the "
                "hierarchy (default soft_modes='auto': 3 soft modes searched) flags the network unstable.")
    print(f"written {out / 'validation.md'}")
    return df


def speed(args):
    case = case_dict(0.2, 0.1, 1e-3, 1.0, 1, args.n)
    res, t_pack, _ = get_packing(case)
    net = res.to_network()
    print(f"packing N = {args.n}: {net.n_contacts} contacts (built in {t_pack:.0f} s)")
    times = {p: [] for p in PRECONDITIONERS}
    t_e = []
    hs = {}
    for rep in range(args.repeats):
        for prec in PRECONDITIONERS:
            t0 = time.perf_counter()
            hs[prec] = relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=args.order,
                                            spectral_bound="none", preconditioner=prec)
            times[prec].append(time.perf_counter() - t0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            t0 = time.perf_counter()
            ex = stiffness(net, prestress=True, solver=args.solver)
            t_e.append(time.perf_counter() - t0)
        print(f"repeat {rep}: " + ", ".join(
            f"{p} ({args.order} steps) {times[p][-1]:.2f} s (assembly {hs[p].assembly_time:.2f}, "
            f"setup {hs[p].preconditioner_time:.2f})" for p in PRECONDITIONERS)
            + f", exact ({ex.solver}) {t_e[-1]:.2f} s; load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"exact ({ex.solver}) {np.median(t_e):.2f} s [{min(t_e):.2f}, {max(t_e):.2f}]")
    for prec in PRECONDITIONERS:
        t, h = times[prec], hs[prec]
        print(f"{prec}: {np.median(t):.2f} s [{min(t):.2f}, {max(t):.2f}]; ratio to exact "
              f"{np.median(t) / np.median(t_e):.3f} (per repeat "
              f"{min(a / b for a, b in zip(t, t_e)):.3f}-{max(a / b for a, b in zip(t, t_e)):.3f})")
        print(f"  K: exact {ex.K:.5f}, upper {h.K.upper:.5f} ({h.K.upper / ex.K - 1:+.2e}), extrapolated "
              f"{h.K.value:.5f} +- {h.K.error:.5f}")
        print(f"  G: exact {ex.G:.5f}, upper {h.G.upper:.5f} ({h.G.upper / ex.G - 1:+.2e}), extrapolated "
              f"{h.G.value:.5f} +- {h.G.error:.5f}")
    stats_speed()


#: certify variants: the default (max_order="auto": one block-Jacobi step then the certificate's
#: factorisation wherever the sparse certificate applies); the former default (16 multilevel steps
#: first); the multilevel CG alone (up to certify_max_order = 200 steps); 2 multilevel steps then
#: the factorisation; one block-Jacobi step then the factorisation (explicitly)
VARIANTS = {"default": {}, "amg16": {"max_order": 16, "preconditioner": "amg"},
            "multilevel": {"max_order": 16, "preconditioner": "amg", "factor_steps": 0},
            "fast": {"max_order": 2, "preconditioner": "amg"},
            "lean": {"max_order": 1, "preconditioner": "block"}}


def _timed(f):
    w, c = time.perf_counter(), time.process_time()
    out = f()
    return out, time.perf_counter() - w, time.process_time() - c


def certify(args):
    """Time to a certified interval (tol 1e-2, 1e-3) beside the exact solve; a markdown table."""
    from studies.bench_stiffness import diluted_triangular
    nets = [(f"diluted triangular {float(n):.0e}", lambda n=n: diluted_triangular(int(float(n))))
            for n in args.sizes.split(",")]
    if args.packing:
        from dem.engine.packing import PackingResult
        nets.insert(0, (f"DEM packing {os.path.basename(args.packing)}",
                        lambda: PackingResult.load(args.packing).to_network()))
    rows = []
    for name, make in nets:
        net = make()
        for rep in range(args.repeats):
            loads = [os.getloadavg()[0]]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                ex, we, ce = _timed(lambda: stiffness(net, prestress=False))
            for tol, fs in [(t, v) for t in (1e-2, 1e-3) for v in args.variants.split(",")]:
                if fs == "multilevel" and net.n_particles > args.multilevel_max_n:
                    continue
                h, wh, ch = _timed(lambda: relaxation_hierarchy(net, tol=tol, **VARIANTS[fs]))
                loads.append(os.getloadavg()[0])
                inside = bool(h.K.lower is not None and h.K.lower <= ex.K <= h.K.upper
                              and h.G.lower <= ex.G <= h.G.upper)
                row = dict(network=name, N=net.n_particles, ndof=h.n_dof, repeat=rep, tol=tol, variant=fs,
                           exact_wall=we, exact_cpu=ce, wall=wh, cpu=ch, wall_ratio=wh / we, cpu_ratio=ch / ce,
                           assembly=h.assembly_time, bound=h.bound_time, cg=h.solve_time, lam=h.spectral_bound,
                           steps=h.order, factor_steps=h.n_factor_steps, certified=h.certified,
                           factorisations=h.certificate_factorisations, preconditioner=h.preconditioner,
                           K_width=h.K.rel_width, G_width=h.G.rel_width, inside=inside,
                           K_up_err=h.K.upper / ex.K - 1, load=max(loads))
                rows.append(row)
                print(f"{name} (N {net.n_particles}, repeat {rep}) tol {tol:g}, {fs}: exact {we:.2f} s wall / "
                      f"{ce:.2f} s cpu; certified interval {wh:.2f} s wall / {ch:.2f} s cpu (ratio "
                      f"{wh / we:.1f} wall, {ch / ce:.1f} cpu; assembly {h.assembly_time:.2f}, certificate + "
                      f"soft modes {h.bound_time:.2f}, CG {h.solve_time:.2f}); lam {h.spectral_bound}, "
                      f"{h.order} steps ({h.n_factor_steps} factorised, {h.preconditioner}), "
                      f"{h.certificate_factorisations} numeric factorisation(s), certified {h.certified}, widths "
                      f"K {h.K.rel_width:.2e} G {h.G.rel_width:.2e}, exact inside {inside}; load "
                      f"{max(loads):.1f}", flush=True)
    df = pd.DataFrame(rows)
    write_table(df, out_dir(args.out), "certify", "Time to a certified interval beside the exact solve",
                f"relaxation_hierarchy variants {args.variants} ({VARIANTS}), no pre-stress; "
                f"load average at the end {os.getloadavg()[0]:.1f}.")
    return df


def stats_speed(n=1_000_000, repeats=3):
    from microhom.moduli import predict_moduli
    rng = np.random.default_rng(0)
    nc = rng.uniform(3.2, 5.2, n)
    r = rng.uniform(0.0, 0.2, n)
    kt = rng.uniform(0.1, 1.0, n)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        predict_moduli(1.0, kt, nc, 0.84, r, rho=0.7, nbar=5.3, warn=False)
        ts.append(time.perf_counter() - t0)
    print(f"predict_moduli (seed formula): {n / min(ts):.3g} parameter sets/s (best of {repeats})")
    try:
        from microhom.closure import predict_closure
    except ImportError:
        return
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        predict_closure(nc=nc, r=r, kt_over_kn=kt, phi=0.84, dispersity=0.1)
        ts.append(time.perf_counter() - t0)
    print(f"predict_closure (statistics-only closure): {n / min(ts):.3g} parameter sets/s (best of {repeats})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["validate", "speed", "stats", "certify"])
    ap.add_argument("--sizes", default="1e3,1e4,1e5", help="certify: sizes of the benchmark network")
    ap.add_argument("--packing", default=None, help="certify: also this DEM packing (PackingResult .npz)")
    ap.add_argument("--variants", default="default,amg16",
                    help=f"certify: comma-separated among {list(VARIANTS)}")
    ap.add_argument("--multilevel-max-n", type=int, default=20_000,
                    help="certify: the multilevel-only variant up to this many disks (at 1e5 it did not reach "
                         "1 %% in 150 steps, about 20 min)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--order", type=int, default=8, help="CG steps (2 moments each)")
    ap.add_argument("--solver", default="auto", choices=["auto", "cholmod", "splu"],
                    help="back end of the exact solve (dem.analysis.stiffness)")
    ap.add_argument("--out", default="out/hierarchy")
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()}")
    {"validate": validate, "speed": speed, "stats": lambda a: stats_speed(), "certify": certify}[args.what](args)


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
