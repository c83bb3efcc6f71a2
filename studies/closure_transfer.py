"""Does any statistic make the closure's K transfer to a preparation family it was not fitted on?
(issue 25, item 2)

    python -m studies.closure_transfer [--cache DIR] [--out DIR] [--quick]

The closure's K is 3-5 % rms off for a held-out *protocol* whose family is in the corpus, but 7.5 %
for the fixed-phi family held out whole (``studies.closure_fit.lofo``). This study adds candidate
statistics to K's design one at a time (and in a few combinations) and judges each by leave one
preparation family out, not by the in-sample fit: per family the valid cases, the rms K error, the
mean K error of the fixed-phi family at kt/kn = 0.05 (its largest bias), the coverage of the
in-family stated error (the closure refitted without the family), and the across-family stated
error :func:`studies.closure_fit.calibrate_family` would then store (its median over the valid
cases and its nested coverage of the fixed-phi family).

Candidates:

* contact statistics measured on the cached packings (:func:`contact_columns`; committed in
  ``studies/closure_corpus.csv``): ``weak_fraction`` (load-bearing contacts with a normal force
  below the mean), ``fn_small`` (below a tenth of the mean), ``near_contacts`` (pairs of
  load-bearing particles not in contact with a gap below 1e-3 of the mean diameter, per
  load-bearing particle: the "almost contacts"), ``Z_stick`` (mean sticking contacts per
  load-bearing particle), ``f_z3`` (fraction of load-bearing particles with exactly three
  contacts);
* columns the corpus already has (``fn_cv``, ``f_min``, anisotropies, the pebble game's
  ``rigid_*`` when the packings are cached);
* interactions with ``ln kt/kn`` (the fixed-phi family's bias grows as kt/kn falls): with
  ``log10 p/kn``, the rattler fraction, r, phi, psi6_local, ...; and the pressure relative to
  the jamming scaling, ``log10 (p/kn) / dZ^2`` (a combination of two features already in K:
  it changes nothing, a check of the harness).

:func:`cross_family_pairs`: the nearest pairs of rows of different families at the same kt/kn in
the standardised statistics of ``studies.closure_twins`` (distance, K/K_mf of both, the part of
their K ratio the stored closure does not explain).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from studies.closure_fit import (SUMMARY, calibrate, calibrate_family, family_error_scale, family_of, lofo,
                                 lofo_table, lopo, lopo_table, mean_field, scale, usable)
from studies.common import cli_out_dir, write_table

#: the contact statistics :func:`contact_columns` adds (per packing and frictional state)
CONTACT_COLUMNS = ("weak_fraction", "fn_small", "near_contacts", "Z_stick", "f_z3")
#: gap below which two load-bearing particles not in contact count as a near contact [mean diameter]
NEAR_GAP = 1e-3


def contact_statistics(net, frictional: bool) -> dict:
    """:data:`CONTACT_COLUMNS` of one network (kt > 0 state if ``frictional``: rattlers with two
    contacts kept; else frictionless: three). Needs ``fn``, positions, radii and cell."""
    from microhom.network import from_overlaps
    from microhom.structural_sums import rattlers
    net = net.with_stiffness(kt=(0.5 if frictional else 0.0) * np.asarray(net.kn))
    rat, active = rattlers(net)
    lb, n = ~rat, net.n_particles
    if not active.any():   # nothing load-bearing (not jammed): no statistic
        return dict.fromkeys(CONTACT_COLUMNS, np.nan)
    fn = np.asarray(net.fn)[active]
    deg = lambda sel: (np.bincount(net.pairs[sel, 0], minlength=n)  # noqa: E731
                       + np.bincount(net.pairs[sel, 1], minlength=n))
    z, zs = deg(active), deg(active & ~np.asarray(net.sliding))
    R = np.asarray(net.radii)
    wide = from_overlaps(net.positions, R + NEAR_GAP * R.mean(), net.cell, kn=1.0, kt=0.0).pairs
    contacts = set(map(tuple, np.sort(net.pairs, axis=1)))
    new = np.array([tuple(p) not in contacts for p in np.sort(wide, axis=1)], dtype=bool)
    near = new & lb[wide[:, 0]] & lb[wide[:, 1]]
    return dict(weak_fraction=float(np.mean(fn < fn.mean())), fn_small=float(np.mean(fn < 0.1 * fn.mean())),
                near_contacts=float(2 * near.sum() / lb.sum()), Z_stick=float(zs[lb].mean()),
                f_z3=float(np.mean(z[lb] == 3)))


def contact_columns(df: pd.DataFrame, cache) -> pd.DataFrame:
    """``df`` (corpus rows: ``protocol``, ``key``, ``kt_over_kn``) with :data:`CONTACT_COLUMNS` of
    the packings found in ``cache`` (NaN for the others), in the state the corpus analyses
    (``pack_frictionless``: no contact sliding)."""
    from pathlib import Path

    from studies.corpus import _load_network
    vals = {}
    for (prot, key), g in df.groupby(["protocol", "key"], sort=False):
        path = Path(cache) / f"{key}.npz"
        if not path.exists():
            continue
        net, _ = _load_network(path)
        if prot == "pack_frictionless":
            net = net.with_stiffness(sliding=False)
        for fr in sorted(set(g.kt_over_kn > 0)):
            vals[key, fr] = contact_statistics(net, fr)
    rows = [vals.get((k, kt > 0), {}) for k, kt in zip(df.key, df.kt_over_kn)]
    extra = pd.DataFrame(rows, index=df.index, columns=list(CONTACT_COLUMNS))
    return pd.concat([df.drop(columns=[c for c in CONTACT_COLUMNS if c in df]), extra], axis=1)


def with_interactions(df: pd.DataFrame) -> pd.DataFrame:
    """Usable rows with the interaction candidates (``lk_x_<column>``: ln kt/kn times it, 0 at kt = 0)
    and ``log_p_over_dZ2`` = log10 (p/kn) - 2 log10 dZ."""
    kt = df.kt_over_kn.to_numpy()
    lk = np.where(kt > 0, np.log(np.where(kt > 0, kt, 1.0)), 0.0)
    out = {f"lk_x_{c}": lk * df[c].to_numpy(float)
           for c in ("log_p_over_kn", "rattler_fraction", "r", "phi", "psi6_local", "dispersity", "fn_cv",
                     "near_contacts", "weak_fraction") if c in df}
    out["lk2_x_log_p_over_kn"] = lk ** 2 * df.log_p_over_kn.to_numpy()
    out["lk_x_log_dZ"] = lk * np.log(df.dZ.to_numpy())
    out["log_p_over_dZ2"] = df.log_p_over_kn.to_numpy() - 2 * np.log10(df.dZ.to_numpy())
    return df.assign(**out)


#: the trials (name, extra columns of K's design): each candidate alone, then combinations
SINGLE = ("weak_fraction", "fn_small", "near_contacts", "Z_stick", "f_z3", "fn_cv", "f_min", "force_anisotropy",
          "fabric_anisotropy", "rigid_redundant", "log_p_over_dZ2", "lk_x_log_p_over_kn", "lk_x_rattler_fraction",
          "lk_x_r", "lk_x_phi", "lk_x_psi6_local", "lk_x_dispersity", "lk_x_fn_cv", "lk_x_near_contacts",
          "lk_x_weak_fraction", "lk_x_log_dZ", "lk2_x_log_p_over_kn")
COMBINATIONS = (("p and x_r interactions (no new input)", ("lk_x_log_p_over_kn", "lk_x_rattler_fraction")),
                ("+ near_contacts", ("lk_x_log_p_over_kn", "lk_x_rattler_fraction", "near_contacts")),
                ("nine at once", ("lk_x_log_p_over_kn", "lk_x_rattler_fraction", "near_contacts", "weak_fraction",
                                  "fn_cv", "Z_stick", "lk_x_phi", "lk2_x_log_p_over_kn", "force_anisotropy")))


def trial(df, extra=()) -> dict:
    """One candidate design (``extra``: columns added to K's features) judged both ways; see the
    module docstring for the figures."""
    ex = {"K": tuple(extra)} if extra else ()
    lo = lopo(df, ex)
    q, inside = calibrate(lo)
    lf = lofo(df, ex)
    qf = calibrate_family(lf, q)
    qn = calibrate_family(lf, q, exclude="fixed_phi")
    t = lofo_table(lf).set_index("held_out")
    v = lf[lf.valid]
    stated = family_error_scale(v.kt_over_kn.to_numpy(), q["K"], qf["K"]) * scale(v, "K").to_numpy()
    fp = v[v.held_out == "fixed_phi"]
    nested = family_error_scale(fp.kt_over_kn.to_numpy(), q["K"], qn["K"]) * scale(fp, "K").to_numpy()
    out = dict(lopo_log_K=float(np.sqrt(np.mean(np.log1p(lo.err_K) ** 2))),
               lopo_worst_K=float(lopo_table(lo, q, inside).rms_K.max()), Q_K=q["K"],
               fixed_phi_K_at_005=float(fp[fp.kt_over_kn == 0.05].err_K.mean()),
               across_median_K=float(np.median(stated)),
               fixed_phi_nested_inside_K=float(np.mean(fp.err_K.abs().to_numpy() <= nested)))
    for f, r in t.iterrows():
        out.update({f"{f}_valid": int(r.valid), f"{f}_rms_K": r.rms_K, f"{f}_inside_K": r.inside_K})
    return out


def trials(df, single=SINGLE, combinations=COMBINATIONS) -> pd.DataFrame:
    """:func:`trial` for the stored closure, each available candidate of ``single`` and each
    combination (candidates missing from ``df`` or with NaN are skipped)."""
    df = with_interactions(df)
    todo = [("the closure", ())] + [(c, (c,)) for c in single] + list(combinations)
    rows = []
    for name, extra in todo:
        if any(c not in df or df[c].isna().any() for c in extra):
            continue
        rows.append(dict(candidate=name, **trial(df, extra)))
    return pd.DataFrame(rows)


def cross_family_pairs(df, n=5) -> pd.DataFrame:
    """The ``n`` nearest pairs of rows of different families per kt/kn (standardised statistics of
    :func:`studies.closure_twins.standardised`): keys, distance ``d``, ``Kr_1``, ``Kr_2`` (K/K_mf),
    ``dK`` (K_2/K_1 - 1), ``dKr`` (the same of K/K_mf) and ``unexplained_K`` (exp of the part of
    |log K_1/K_2| the stored closure does not predict, minus 1)."""
    from studies.closure_twins import pairs
    pr = pairs(df)
    pr = pr[family_of(pr.protocol_1) != family_of(pr.protocol_2)]
    K_mf, _ = mean_field(df)
    kmf = dict(zip(zip(df.key, df.kt_over_kn), K_mf))
    r1 = np.array([k / kmf[a, t] for k, a, t in zip(pr.K_1, pr.key_1, pr.kt_over_kn)])
    r2 = np.array([k / kmf[a, t] for k, a, t in zip(pr.K_2, pr.key_2, pr.kt_over_kn)])
    out = pr.assign(Kr_1=r1, Kr_2=r2, dK=pr.K_2 / pr.K_1 - 1, dKr=r2 / r1 - 1,
                    unexplained_K=np.expm1(pr.unexplained_K))
    out = out.sort_values(["kt_over_kn", "d"]).groupby("kt_over_kn").head(n)
    return out[["kt_over_kn", "protocol_1", "protocol_2", "key_1", "key_2", "d", "Kr_1", "Kr_2", "dKr", "dK",
                "unexplained_K"]].reset_index(drop=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="out/closure/cache", help="cached packings (the pebble game's columns)")
    ap.add_argument("--out", default="out/closure_transfer")
    ap.add_argument("--quick", action="store_true", help="single candidates from the committed summary only")
    args = ap.parse_args(argv)
    out = cli_out_dir(args.out)
    t0 = time.perf_counter()
    raw = pd.read_csv(SUMMARY, keep_default_na=False, na_values=[""])
    if not args.quick:
        from pathlib import Path

        from studies.closure_rigidity import rigidity_columns
        if Path(args.cache).is_dir():
            raw = rigidity_columns(raw, args.cache)
    df = usable(raw)
    pd.set_option("display.width", 250)
    tab = trials(df, combinations=() if args.quick else COMBINATIONS)
    print("K's candidates judged by leave one family out (rms, coverage of the in-family stated error; the "
          "across-family error calibrate_family would store):")
    print(tab.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    write_table(tab, out, "transfer_trials", "Candidates for K across families (leave one family out)")
    near = cross_family_pairs(df)
    print("nearest pairs of different families (same kt/kn):")
    print(near.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    write_table(near, out, "cross_family_pairs", "Nearest pairs of rows of different preparation families")
    print(f"written {out} ({time.perf_counter() - t0:.0f} s)")
    return tab


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
