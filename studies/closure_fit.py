"""Refit the statistics-only closure (``microhom.closure``) and measure its error on packings it
was not built from.

    python -m studies.closure_fit [--out DIR] [--quick]

Training set: 16 DEM packings of N = 500 disks (identical and polydisperse 0.2; preparation
friction 0, 0.05, 0.2, 1; p/kn = 1e-4 and 1e-2; seed 11; kt = kn, mu = 0.488), each analysed with
kt/kn in {0.1, 0.25, 0.5, 1} (the geometry and sliding flags of the packing, only the tangent
stiffness changes, as ``studies.sweep`` does): 64 rows. Validation set: the 10 packings of
``studies.bench_hierarchy`` (N = 3000, other seeds and protocols), each at its own kt/kn; the
frictionless one lies outside the closure's range and must come out flagged.

For each row: the statistics a user can know (load-bearing coordination Z, solid fraction phi,
contact-number fluctuation r, rho, dispersity, kt/kn, p/kn), the exact moduli (``dem.stiffness``,
without pre-stress, as the theory), and the normalised moments of the relaxation
(``mu_1/mu_0``, ``mu_2/mu_0``, ``mu_3/mu_0`` of the bulk load, in units of the block-preconditioned
spectrum) for the record. The closure is a least-squares fit of ``log(K/K_mf)`` and
``log(G/G_mf)`` on the features of ``microhom.closure.features``; the coefficients printed here are
the ones stored in ``microhom/closure.py``.
"""
from __future__ import annotations

import argparse
import itertools
import os
import time
import warnings

import numpy as np
import pandas as pd

from dem.stiffness import stiffness
from microhom.closure import COEF_G, COEF_K, FEATURES, RANGES, features, predict_closure
from microhom.hierarchy import moments
from microhom.kinematics import assemble
from microhom.structural_sums import network_statistics
from studies.bench_hierarchy import CASES, case_dict
from studies.cases import get_packing
from studies.common import cli_out_dir, write_table

TRAIN = [dict(n=500, p_over_kn=p, kt_over_kn=1.0, mu=0.4877, mu_prep=mp, dispersity=d, seed=11)
         for d, mp, p in itertools.product((0.0, 0.2), (0.0, 0.05, 0.2, 1.0), (1e-4, 1e-2))]
KT_RATIOS = (0.1, 0.25, 0.5, 1.0)


def measure(net, case, kt_ratio):
    """One row: statistics, exact moduli (no pre-stress), normalised moments."""
    if kt_ratio is not None:
        net = net.with_stiffness(kt=kt_ratio)
    st = network_statistics(net).as_dict()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ex = stiffness(net)
    kt = float(np.mean(net.kt)) if kt_ratio is None else kt_ratio
    row = dict(n=case["n"], dispersity=case["dispersity"], mu_prep=case["mu_prep"],
               p_over_kn=case["p_over_kn"], seed=case["seed"], kt_over_kn=kt, nc=st["nc"], r=st["r"],
               rho=st["rho"], phi=st["phi"], rattler_fraction=st["rattler_fraction"],
               sliding_fraction=st["sliding_fraction"], exact_K=ex.K, exact_G=ex.G,
               affine_K=ex.K_affine, affine_G=ex.G_affine, n_floppy=ex.n_floppy)
    if ex.n_dof:
        asm = assemble(net, pin=False)
        mu = moments(asm, [0.5, 0.5, 0.0], j_max=3)
        row.update({f"mK{j}": mu[j] / mu[0] for j in (1, 2, 3)})
        row["mu0_over_KA"] = mu[0] / (ex.K_affine * net.area)
    return row


def collect(cases, kt_ratios):
    rows = []
    for case in cases:
        res, _, _ = get_packing(case)
        net = res.to_network()
        for kr in kt_ratios:
            try:
                rows.append(measure(net, case, kr))
            except ValueError as exc:      # e.g. no load-bearing backbone at this kt
                print(f"skipped {case} kt {kr}: {exc}")
    return pd.DataFrame(rows)


def fit(df):
    """Least squares of log(modulus / mean field) on the closure's features."""
    X = features(df.nc.to_numpy(), df.kt_over_kn.to_numpy(), df.dispersity.to_numpy(), df.r.to_numpy())
    mf_K = df.nc * df.phi / (2 * np.pi)
    mf_G = df.nc * df.phi * (1 + df.kt_over_kn) / (4 * np.pi)
    cK, *_ = np.linalg.lstsq(X, np.log(df.exact_K / mf_K), rcond=None)
    cG, *_ = np.linalg.lstsq(X, np.log(df.exact_G / mf_G), rcond=None)
    return cK, cG


def errors(df, cK=None, cG=None):
    p = predict_closure(nc=df.nc.to_numpy(), r=df.r.to_numpy(), phi=df.phi.to_numpy(), kt_over_kn=df.kt_over_kn.to_numpy(),
                        dispersity=df.dispersity.to_numpy(), coef_K=cK, coef_G=cG)
    out = df.copy()
    out["closure_K"], out["closure_G"] = p.K, p.G
    out["err_K"], out["err_G"] = p.K / df.exact_K - 1, p.G / df.exact_G - 1
    out["closure_valid"], out["closure_reason"] = p.valid, p.reason
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/closure")
    ap.add_argument("--quick", action="store_true", help="4 training packings, 2 validation packings")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out)  # checked before computing (one line and exit 1 otherwise)
    t0 = time.perf_counter()
    train = collect(TRAIN[:4] if args.quick else TRAIN, KT_RATIOS)
    val_cases = [case_dict(*c) for c in (CASES[:2] if args.quick else CASES)]
    val = collect(val_cases, [None])
    cK, cG = fit(train)
    pd.set_option("display.width", 220)
    print("features:", FEATURES)
    print("COEF_K =", np.array2string(cK, precision=6, separator=", "))
    print("COEF_G =", np.array2string(cG, precision=6, separator=", "))
    print("stored: K", COEF_K, "G", COEF_G)
    print(f"training ranges: dZ {train.nc.min() - 3:.3f}-{train.nc.max() - 3:.3f}, kt/kn {train.kt_over_kn.min()}-"
          f"{train.kt_over_kn.max()}, dispersity {train.dispersity.min()}-{train.dispersity.max()}, "
          f"r {train.r.min():.4f}-{train.r.max():.4f}, phi {train.phi.min():.3f}-{train.phi.max():.3f}; "
          f"stored RANGES {RANGES}")
    tr = errors(train, cK, cG)
    va = errors(val, cK, cG)
    for name, d in (("training (fit)", tr), ("validation (not fitted)", va)):
        v = d[d.closure_valid]
        print(f"{name}: {len(v)}/{len(d)} valid; rms err K {np.sqrt((v.err_K ** 2).mean()):.3f}, "
              f"G {np.sqrt((v.err_G ** 2).mean()):.3f}; max |err| K {v.err_K.abs().max():.3f}, "
              f"G {v.err_G.abs().max():.3f}")
    va.to_csv(out / "validation_full.csv", index=False)
    cols = ["dispersity", "mu_prep", "p_over_kn", "kt_over_kn", "nc", "r", "phi", "exact_K", "closure_K",
            "err_K", "exact_G", "closure_G", "err_G", "closure_valid", "mK1", "mK2", "mK3"]
    print(va[cols].to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    tr.to_csv(out / "training.csv", index=False)
    write_table(va[cols], out, "validation", "Statistics-only closure on packings it was not built from",
                f"Fit on {len(tr)} rows (16 packings x 4 kt/kn); wall {time.perf_counter() - t0:.0f} s; "
                f"load {os.getloadavg()[0]:.1f}.")
    print(f"written {out}")


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
