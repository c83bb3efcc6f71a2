"""The 3D study: LAMMPS sphere packings at several pressures and frictions, every estimate side by side.

    python -m studies.spheres [--quick] [--n 2000] [--p-over-kn 1e-4 1e-3 1e-2] [--mu 0 0.1 0.5]
                              [--seed 1] [--probes] [--tol 0.01] [--out out/spheres]

For each packing (made by LAMMPS with the project's 3D deck, :func:`dem.engine.lammps.write_inputs`
with ``dimension=3``: polydisperse spheres, radii 0.5 (1 +- 0.2), kn = kt = 1, ``gran/hooke/history``,
the friction ``mu`` from the gas on (``mu_prep = mu``), isotropic pressure p with ``p D / kn`` =
``--p-over-kn``), read back as a 3D network with LAMMPS's forces:

* statistics (:func:`microhom.structural_sums.sphere_statistics`): Z with and without rattlers,
  the contact-number fluctuation r, phi, the sliding and rattler fractions;
* the mean field: the affine (Voigt) moduli of the load-bearing contacts' fabric;
* the relaxation hierarchy (:func:`microhom.hierarchy.relaxation_hierarchy`, to ``--tol``): its
  first order (every sphere relaxed alone) and its certified interval;
* the exact tensor (:func:`dem.analysis.stiffness.stiffness`), the reference: the stiffness of the
  energy density (no pre-stress, the hierarchy's quantity), and the Cauchy stiffness with the
  pre-stress and LAMMPS's spin arm (the probes' quantity);
* the same Cauchy tensor under the former 3D rattler rule (``min_contacts="rigid"``: frictional
  spheres need 3 contacts), for comparison: the rule now keeps frictional spheres with two
  contacts, which transmit force between their neighbours (LAMMPS's probes include them);
* with ``--probes``: LAMMPS's own strain probes (:mod:`studies.lammps_probes3d`, amplitude 1e-6,
  relaxed to unbalanced force and torque ratios below 1e-11), against the exact Cauchy tensor.

Moduli in Pa (kn = 1 N/m, mean diameter 1 m: in units of kn/D). Every packing and its results are
cached under ``OUT/packings/`` (``case.json``): the same command resumes, ``--probes`` adds the
probes to finished cases. ``--quick``: one packing of 150 spheres at pD/kn = 1e-2, mu = 0.5, for CI.
"""
from __future__ import annotations

import argparse
import json
import os
import time
import warnings

import numpy as np
import pandas as pd

from dem.engine.lammps import lammps_available
from dem.engine.packing import PackingProtocol
from studies.common import cli_out_dir, markdown_table, report_to
from studies.lammps_probes3d import compare, lammps_probes, pack_with_restart, relax_base

PROBE_AMPLITUDE = 1e-6
#: the probes' relaxation tolerance (unbalanced force and torque ratios): above the round-off floor
#: of 1000-sphere packings (about 1e-12; 1e-13 was not reached in 200 000 steps on one of them)
PROBE_TOL = 1e-11


def _exact(net, **kw):
    from dem.analysis.stiffness import stiffness
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = stiffness(net, **kw)
    return r, time.perf_counter() - t0


#: version of the rattler rule the cached measurements were made with (2: frictional spheres need 2
#: contacts); rows measured under another are measured again (the packing and probes are reused)
RATTLER_RULE = 2


def _measure(run, tol) -> dict:
    """Statistics, mean field, hierarchy and exact tensors of one packing (a flat dict)."""
    from microhom.hierarchy import relaxation_hierarchy
    from microhom.structural_sums import sphere_statistics

    net = run.network
    t0 = time.perf_counter()
    st = sphere_statistics(net)
    t_st = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = relaxation_hierarchy(net, tol=tol)
    t_h = time.perf_counter() - t0
    ex, t_ex = _exact(net)
    exc, t_exc = _exact(net, prestress=True, spin_arm="radius")
    excr, _ = _exact(net, prestress=True, spin_arm="radius", min_contacts="rigid")
    return dict(
        N=net.n_particles, phi=st.phi, Z_all=st.nc_all, Z=st.nc, r=st.r, r_all=st.r_all,
        rattler_fraction=st.rattler_fraction, sliding_fraction=st.sliding_fraction,
        pressure=run.lammps["pressure"], lammps_Z=run.lammps["Z"],
        K_mf=st.K_affine, G_mf=st.G_affine, stats_s=t_st,
        K_first=h.K_first_order, G_first=h.G_first_order,
        K_lower=h.K.lower, K_upper=h.K.upper, G_lower=h.G.lower, G_upper=h.G.upper,
        hier_order=h.order, hier_certified=bool(h.certified), hier_valid=bool(h.valid),
        hier_reasons="; ".join(h.reasons), hier_s=t_h,
        K_exact=ex.K, G_exact=ex.G, K_affine_exact=ex.K_affine, G_affine_exact=ex.G_affine,
        exact_flags="; ".join(ex.flags), n_floppy=ex.n_floppy, exact_s=t_ex,
        rattlers=ex.n_rattlers,
        K_cauchy=exc.K, G_cauchy=exc.G, cauchy_unstable=exc.n_unstable, cauchy_s=t_exc,
        K_cauchy_rigid=excr.K, G_cauchy_rigid=excr.G, rattlers_rigid=excr.n_rattlers,
        rattler_rule=RATTLER_RULE)


def _two_contact(net) -> int:
    """Non-rattlers with exactly two load-bearing contacts, frictional ones (the spheres the former
    rule, ``min_contacts="rigid"``, removed; each has one floppy turn about its chord)."""
    from microhom.structural_sums import rattlers
    rat, act = rattlers(net)
    cnt = np.bincount(net.pairs[act].ravel(), minlength=net.n_particles)
    fric = np.bincount(net.pairs[act & (net.effective_kt > 0)].ravel(), minlength=net.n_particles)
    return int(np.count_nonzero(~rat & (cnt == 2) & (fric > 0)))


def sphere_case(n, p_over_kn, mu, seed, folder, *, tol=0.01, probes=False, progress=print) -> dict:
    """One packing of the study, from the cache ``folder/case.json`` when there (see module doc)."""
    folder.mkdir(parents=True, exist_ok=True)
    cache = folder / "case.json"
    row = json.loads(cache.read_text()) if cache.exists() else None
    proto = PackingProtocol(n=n, p_over_kn=p_over_kn, kn=1.0, mu=mu, mu_prep=mu,
                            dispersity=0.2, seed=seed)
    if row is not None and row.get("rattler_rule") != RATTLER_RULE:   # measured under the former rule
        run, _, _ = pack_with_restart(proto, folder)
        keep = {k: row[k] for k in ("p_over_kn", "mu", "seed", "pack_s", "steps", "converged")}
        row = dict(keep, **_measure(run, tol))
        cache.write_text(json.dumps(row))
    if row is None:
        t0 = time.perf_counter()
        run, prm, wall = pack_with_restart(proto, folder, max_steps=2_000_000)
        progress(f"  packed by LAMMPS in {wall:.1f} s ({int(run.lammps['steps'])} steps, converged "
                 f"{bool(run.lammps['converged'])})")
        row = dict(p_over_kn=p_over_kn, mu=mu, seed=seed, pack_s=wall,
                   steps=int(run.lammps["steps"]), converged=bool(run.lammps["converged"]))
        row.update(_measure(run, tol))
        row["case_s"] = time.perf_counter() - t0
        cache.write_text(json.dumps(row))
    if "two_contact" not in row:       # spheres the former rule removed: two load-bearing contacts
        run, _, _ = pack_with_restart(proto, folder)
        row["two_contact"] = _two_contact(run.network)
        cache.write_text(json.dumps(row))
    if probes and "probes_difference_rigid" not in row:     # (run, or re-read from the logs)
        run, prm, _ = pack_with_restart(proto, folder)
        base, blog = relax_base(folder, prm, tol=PROBE_TOL)
        pr = lammps_probes(folder, prm, blog, amplitudes=(PROBE_AMPLITUDE,), tol=PROBE_TOL)
        cmp = compare(base, pr)
        cmp2 = compare(base, pr, min_contacts="rigid")
        row.update(probes_difference_rigid=cmp2.difference, K_probes_vs_rigid=pr.K / cmp2.K_exact - 1,
                   G_probes_vs_rigid=pr.G / cmp2.G_exact - 1, K_probes=pr.K, G_probes=pr.G, probes_difference=cmp.difference,
                   probes_asymmetry=pr.asymmetry, probes_events=pr.contact_events,
                   probes_s=pr.lammps_time, probes_sliding=max(pr.sliding_by_amplitude.values()),
                   probes_prestress_size=cmp.prestress_size, probes_tangential_scale=cmp.tangential_scale)
        cache.write_text(json.dumps(row))
    return row


def tables(df: pd.DataFrame) -> dict:
    """The study's tables (pandas): statistics, moduli, and the 3D main table."""
    key = ["p_over_kn", "mu"]
    stats = df[key + ["N", "phi", "Z_all", "Z", "r", "rattler_fraction", "sliding_fraction", "two_contact", "n_floppy",
                      "cauchy_unstable",
                      "pack_s"]].copy()
    mods = []
    for m in ("K", "G"):
        t = df[key].copy()
        t.insert(0, "modulus", m)
        t["mean_field"] = df[f"{m}_mf"]
        t["first_order"] = df[f"{m}_first"]
        t["hierarchy_lower"] = df[f"{m}_lower"]
        t["hierarchy_upper"] = df[f"{m}_upper"]
        t["exact"] = df[f"{m}_exact"]
        t["fraction_change"] = 1 - df[f"{m}_exact"] / df[f"{m}_mf"]
        t["mf_error"] = df[f"{m}_mf"] / df[f"{m}_exact"] - 1
        t["first_order_error"] = df[f"{m}_first"] / df[f"{m}_exact"] - 1
        t["upper_error"] = df[f"{m}_upper"] / df[f"{m}_exact"] - 1
        t["exact_cauchy"] = df[f"{m}_cauchy"]
        t["exact_cauchy_rigid"] = df[f"{m}_cauchy_rigid"]
        if f"{m}_probes" in df:
            t["probes"] = df[f"{m}_probes"]
            t["probes_error"] = df[f"{m}_probes"] / df[f"{m}_cauchy"] - 1
            t["probes_error_rigid"] = df[f"{m}_probes"] / df[f"{m}_cauchy_rigid"] - 1
        mods.append(t)
    times = df[key + ["pack_s", "stats_s", "hier_s", "hier_order", "hier_certified", "exact_s"]
               + (["probes_s", "probes_difference", "probes_difference_rigid", "probes_tangential_scale",
                   "probes_prestress_size", "probes_asymmetry", "probes_events", "probes_sliding"]
                  if "probes_difference_rigid" in df else [])].copy()
    return {"statistics": stats, "moduli": pd.concat(mods, ignore_index=True), "times": times}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one packing of 150 spheres (CI, seconds)")
    ap.add_argument("--n", type=int, default=None, help="spheres per packing (default 2000)")
    ap.add_argument("--p-over-kn", type=float, nargs="+", default=None,
                    help="p D / kn (default 1e-4 1e-3 1e-2)")
    ap.add_argument("--mu", type=float, nargs="+", default=None, help="frictions (default 0 0.1 0.5)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tol", type=float, default=0.01, help="hierarchy tolerance (relative width)")
    ap.add_argument("--probes", action="store_true", help="also LAMMPS's strain probes (slow)")
    ap.add_argument("--out", default="out/spheres", help="output folder (default out/spheres)")
    a = ap.parse_args(argv)
    for name, vals, ok in (("--p-over-kn", a.p_over_kn or [], lambda v: 0 < v < 0.1),
                           ("--mu", a.mu or [], lambda v: 0 <= v <= 10)):
        if not all(ok(v) for v in vals):
            raise SystemExit(f"error: {name} must be in {'(0, 0.1)' if name == '--p-over-kn' else '[0, 10]'}, "
                             f"got {vals}")
    n = a.n or (150 if a.quick else 2000)
    pks = a.p_over_kn or ([1e-2] if a.quick else [1e-4, 1e-3, 1e-2])
    mus = a.mu or ([0.5] if a.quick else [0.0, 0.1, 0.5])
    out = cli_out_dir(a.out, cache=False)
    report_to(out)
    if not lammps_available():
        print("lmp (LAMMPS) not on PATH: the 3D packings are made by LAMMPS (Debian: apt-get install -y lammps)")
        return 1
    t_all = time.perf_counter()
    print(f"3D study: N = {n}, pD/kn {pks}, mu {mus}, seed {a.seed}; load {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    # the fast packings first (high pressure, high friction): a partial run covers the most cases
    order = [(pk, mu) for pk in sorted(pks, reverse=True) for mu in sorted(mus, reverse=True)]
    for k, (pk, mu) in enumerate(order):
        print(f"[{k + 1}/{len(pks) * len(mus)}] pD/kn = {pk:g}, mu = {mu:g}", flush=True)
        folder = out / "packings" / f"n{n}_p{pk:g}_mu{mu:g}_s{a.seed}"
        r = sphere_case(n, pk, mu, a.seed, folder, tol=a.tol, probes=a.probes)
        rows.append(r)
        print(f"  Z = {r['Z_all']:.3f} (no rattlers {r['Z']:.3f}), phi = {r['phi']:.4f}, rattlers "
              f"{100 * r['rattler_fraction']:.1f} %, sliding {100 * r['sliding_fraction']:.1f} %; K: mean field "
              f"{r['K_mf']:.4g}, first order {r['K_first']:.4g}, hierarchy [{r['K_lower']:.4g}, {r['K_upper']:.4g}], "
              f"exact {r['K_exact']:.4g}; G: {r['G_mf']:.4g}, {r['G_first']:.4g}, [{r['G_lower']:.4g}, "
              f"{r['G_upper']:.4g}], {r['G_exact']:.4g}" + (f"; probes K {r['K_probes']:.6g} G {r['G_probes']:.6g}"
                                                              if "K_probes" in r else ""), flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(out / "cases.csv", index=False)
    tabs = tables(df)
    pd.set_option("display.width", 250)
    text = [f"# The 3D study (`python -m studies.spheres`)\n\nN = {n}, seed {a.seed}; moduli in Pa "
            f"(kn = 1 N/m, D = 1 m). Total wall time {time.perf_counter() - t_all:.0f} s (cached "
            f"packings reused).\n"]
    for name, t in tabs.items():
        print(f"\n{name}:\n" + t.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
        text.append(f"## {name}\n\n{markdown_table(t)}\n")
    (out / "spheres.md").write_text("\n".join(text))
    print(f"\nwritten {out / 'spheres.md'}; total {time.perf_counter() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
