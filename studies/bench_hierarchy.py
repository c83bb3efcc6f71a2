"""The relaxation hierarchy on our own packings: validation against the exact solve, and speed.

    python -m studies.bench_hierarchy validate [--quick] [--out DIR]
    python -m studies.bench_hierarchy speed [--n 100000] [--repeats 3] [--order 16]

``validate``: 10 packings (N = 3000; identical and polydisperse disks; Z from near isostatic to
5.1; kt/kn in {0, 0.1, 0.25, 0.5, 1}; pre-stress included). On each: the exact solve
(``dem.stiffness``), the hierarchy up to 64 CG steps, and a certified spectral bound of the pencil
(H, M) from a shift-invert eigen-solve (a factorisation: the cost of certifying, reported) so that
the rigorous lower bounds can be checked too. Reports, per packing, the errors of the upper
bounds and of the extrapolated values at 8 and 16 steps (16 and 32 moments), whether the stated
errors hold, whether the exact value lies in every interval, and the step counts needed for
K within 2 % and G within 5 %.

``speed``: order k on one large packing against the exact solve of the same packing, in the same
run, interleaved (ours, exact, ours, exact...), spread over repeats; and statistics-only
predictions per second (``microhom.moduli.predict_moduli`` and ``microhom.closure.predict_closure``
on 1e6 parameter sets). The machine is shared: the load average is printed with the figures.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
import pandas as pd
import scipy.sparse.linalg as sla

from dem.stiffness import stiffness
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


def summary_table(df):
    """Compact per-packing table for docs/results/hierarchy.md."""
    def pm(v, e):
        return f"{100 * v:+.2f} ± {100 * e:.2f}"
    rows = []
    for _, r in df.iterrows():
        row = {"packing": f"disp {r.dispersity:g}, mu_prep {r.mu_prep:g}, p/kn {r.p_over_kn:g}",
               "kt/kn": r.kt_over_kn, "Z": round(r.Z, 2), "G/G_aff": round(r.G_over_affine, 3)}
        for m in ("K", "G"):
            for k in (8, 16):
                row[f"{m} up {k} [%]"] = f"{100 * r[f'{m}_up{k}_err']:+.2f}"
                row[f"{m} ext {k} [%]"] = pm(r[f"{m}_ext{k}_err"], r[f"{m}_ext{k}_stated"])
            low = r[f"{m}_low16_err"]
            row[f"{m} low 16 [%]"] = "n/a" if not np.isfinite(low) else f"{100 * low:+.1f}"
        row["steps K 2 %"], row["steps G 5 %"] = int(r.K_steps_to), int(r.G_steps_to)
        row["exact inside"] = bool(r.exact_inside_all_intervals)
        row["exact s"], row["16 steps s"] = round(r.exact_s, 2), round(r.hier16_s, 2)
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
        t0 = time.perf_counter()
        h = relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=64,
                                 spectral_bound=lam if lam else "none")
        t_h = time.perf_counter() - t0
        t0 = time.perf_counter()
        h16 = relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=16, spectral_bound="none")
        t16 = time.perf_counter() - t0
        row = dict(dispersity=disp, mu_prep=mu_prep, p_over_kn=p, kt_over_kn=kt, seed=seed,
                   Z=2 * h.n_contacts / max(h.n_particles - h.n_rattlers, 1), exact_K=ex.K, exact_G=ex.G,
                   G_over_affine=ex.G / ex.G_affine, n_unstable=ex.n_unstable, exact_s=t_ex,
                   hier16_s=t16, hier64_s=t_h, certify_s=t_lam, lam=lam)
        inside = True
        for m, seq, lows, exact in (("K", h.K_orders, h.K_lower_orders, ex.K),
                                    ("G", h.G_orders, h.G_lower_orders, ex.G)):
            tolm = 1e-9 * max(abs(ex.K), 1e-300)
            inside &= bool(np.all(seq >= exact - tolm))
            fin = np.isfinite(lows)
            inside &= bool(np.all(lows[fin] <= exact + tolm))
            for k in (8, 16):
                v, e = _extrapolate(seq[1:k + 1])
                row[f"{m}_up{k}_err"] = seq[k] / exact - 1
                row[f"{m}_ext{k}_err"] = v / exact - 1
                row[f"{m}_ext{k}_stated"] = e / abs(exact)
                row[f"{m}_ext{k}_holds"] = bool(abs(v - exact) <= e)
                row[f"{m}_low{k}_err"] = lows[k] / exact - 1 if np.isfinite(lows[k]) else np.nan
            row[f"{m}_steps_to"] = steps_to(seq, exact, 0.02 if m == "K" else 0.05)
        row["exact_inside_all_intervals"] = inside
        rows.append(row)
        print(f"disp {disp} mu_prep {mu_prep} p {p:g} kt {kt}: Z {row['Z']:.2f}, G/Gaff {row['G_over_affine']:.3f}; "
              f"16 steps: K up {row['K_up16_err']:+.3f} ext {row['K_ext16_err']:+.4f} (stated {row['K_ext16_stated']:.4f}), "
              f"G up {row['G_up16_err']:+.3f} ext {row['G_ext16_err']:+.4f} (stated {row['G_ext16_stated']:.4f}); "
              f"steps K2% {row['K_steps_to']} G5% {row['G_steps_to']}; inside {inside}; "
              f"times exact {t_ex:.2f} s, 16 steps {t16:.2f} s, certify {t_lam:.2f} s", flush=True)
    df = pd.DataFrame(rows)
    write_table(df, out, "validation", "Relaxation hierarchy against the exact solve",
                f"N = {n}, pre-stress included; load average {os.getloadavg()[0]:.1f}.")
    write_table(summary_table(df), out, "summary", "Relaxation hierarchy: errors against the exact solve",
                "Errors relative to the exact value; 'ext +- stated' is the extrapolated value's error and "
                "its stated error; steps = CG steps (each uses 2 moments) after which the extrapolated value "
                "stays within 2 % (K) / 5 % (G), -1 = not within 64 steps.")
    print(f"written {out / 'validation.md'}")
    return df


def speed(args):
    case = case_dict(0.2, 0.1, 1e-3, 1.0, 1, args.n)
    res, t_pack, _ = get_packing(case)
    net = res.to_network()
    print(f"packing N = {args.n}: {net.n_contacts} contacts (built in {t_pack:.0f} s)")
    t_h, t_e = [], []
    for rep in range(args.repeats):
        t0 = time.perf_counter()
        h = relaxation_hierarchy(net, prestress=True, tol=1e-9, max_order=args.order, spectral_bound="none")
        t_h.append(time.perf_counter() - t0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            t0 = time.perf_counter()
            ex = stiffness(net, prestress=True)
            t_e.append(time.perf_counter() - t0)
        print(f"repeat {rep}: hierarchy ({args.order} steps) {t_h[-1]:.2f} s (assembly {h.assembly_time:.2f}), "
              f"exact {t_e[-1]:.2f} s; load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"hierarchy {np.median(t_h):.2f} s [{min(t_h):.2f}, {max(t_h):.2f}], exact {np.median(t_e):.2f} s "
          f"[{min(t_e):.2f}, {max(t_e):.2f}]; ratio {np.median(t_h) / np.median(t_e):.3f}")
    print(f"  K: exact {ex.K:.5f}, upper {h.K.upper:.5f}, extrapolated {h.K.value:.5f} +- {h.K.error:.5f}")
    print(f"  G: exact {ex.G:.5f}, upper {h.G.upper:.5f}, extrapolated {h.G.value:.5f} +- {h.G.error:.5f}")
    stats_speed()


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
    ap.add_argument("what", choices=["validate", "speed", "stats"])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--order", type=int, default=16)
    ap.add_argument("--out", default="out/hierarchy")
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()}")
    {"validate": validate, "speed": speed, "stats": lambda a: stats_speed()}[args.what](args)


if __name__ == "__main__":
    main()
