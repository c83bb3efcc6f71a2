"""One study case: build (or reuse) a packing, measure it, and get its moduli every way we have.

``packing_case(case)`` is the unit of work of every ensemble study (``studies.kuhn``,
``studies.sweep``, ``studies.error_vs_runtime``): a plain function of a JSON-able dict, so it runs
serially or as a Dask task (``studies.runner``). Each estimate of K and G carries its wall time.

Moduli are in units of kn (the packings use kn = 1): multiply by kn [N/m] for 2D moduli in N/m.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

import dem.engine.packing
from dem.engine.packing import PackingProtocol, PackingResult, pack
from dem.engine.probes import strain_probes
from dem.analysis.stiffness import stiffness
from microhom.closure import closure_inputs, predict_closure
from microhom.hierarchy import relaxation_hierarchy
from microhom.moduli import predict_moduli
from microhom.structural_sums import network_statistics

MU_26DEG = float(np.tan(np.radians(26.0)))  # the seed's friction angle
PACK_KEYS = ("n", "p_over_kn", "kt_over_kn", "mu", "mu_prep", "dispersity", "seed")
DEFAULTS = {"n": 1000, "p_over_kn": 1e-4, "kt_over_kn": 1.0, "mu": round(MU_26DEG, 4), "mu_prep": 0.05,
            "dispersity": 0.0, "seed": 1}


#: the packing protocol of the studies: the one before issue 12.3 (``dem.engine.packing.PackingProtocol``
#: fields, bit-identical to it), under which the documented results were computed
PROTOCOL = dict(damping_compaction=0.1, dt_over_dtcrit=0.8, fire=False)


def cache_dir() -> Path:
    return Path(os.environ.get("MICROHOM_CACHE", "out/cache/packings"))


def _protocol_tag() -> str:
    """Hash of the packing code: a cached packing is reused only if made by the same protocol."""
    return hashlib.sha1(Path(dem.engine.packing.__file__).read_bytes()).hexdigest()[:8]


def packing_key(case: dict) -> str:
    p = {k: case.get(k, DEFAULTS[k]) for k in PACK_KEYS}
    p["protocol"] = _protocol_tag()
    return hashlib.sha1(json.dumps(p, sort_keys=True).encode()).hexdigest()[:16]


def get_packing(case: dict):
    """The packing of a case: loaded from the cache if it was built before, else built and cached.

    Returns (PackingResult, build wall time [s] (0 if cached), built: bool).
    """
    p = {k: case.get(k, DEFAULTS[k]) for k in PACK_KEYS}
    folder = cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{packing_key(case)}.npz"
    if final.exists():
        res = PackingResult.load(final)
        return res, float(res.report.get("wall_time", 0.0)), False
    t0 = time.perf_counter()
    # kt/kn = 0 or mu = mu_prep = 0: the protocol takes the frictionless law itself
    proto = PackingProtocol(n=int(p["n"]), p_over_kn=p["p_over_kn"], kn=1.0,
                            kt_over_kn=p["kt_over_kn"], mu=p["mu"], mu_prep=p["mu_prep"],
                            dispersity=p["dispersity"], seed=int(p["seed"]), **PROTOCOL)
    res = pack(proto, checkpoint=folder / f"{packing_key(case)}.partial.npz")
    wall = time.perf_counter() - t0
    res = res.replace(report=res.report.annotate(wall_time=wall))
    res.save(final)
    partial = folder / f"{packing_key(case)}.partial.npz"
    if partial.exists():
        partial.unlink()
    return res, wall, True


def theory_estimates(stats: dict, kn: float, kt: float, alpha=1.76) -> dict:
    """Mean-field and corrected theory from measured statistics; each with its wall time."""
    out = {}
    t0 = time.perf_counter()
    nbar = stats["nbar_phi"]
    base = dict(kn=kn, kt=kt, nc=stats["nc"], phi=stats["phi"], nbar=nbar, warn=False)
    variants = {
        "theory_mf": dict(r=0.0),
        "theory_alpha": dict(r=stats["r"], alpha=alpha),
        "theory_rho": dict(r=stats["r"], rho=stats["rho"]),
        "theory_rho_all": dict(r=stats["r_all"], rho=stats["rho_all"], nc=stats["nc_all"]),
    }
    for name, kw in variants.items():
        args = {**base, **kw}
        p = predict_moduli(**args)
        out[f"{name}_K"], out[f"{name}_G"] = float(p.K), float(p.G)
        out[f"{name}_valid"] = bool(p.valid)
    out["theory_time_s"] = (time.perf_counter() - t0) / len(variants)
    return out


def closure_estimate(stats: dict, kt_over_kn: float, dispersity: float, net=None) -> dict:
    """Statistics-only closure (``microhom.closure``) from measured statistics, with its stated
    error and validity; wall time of the prediction alone. With ``net``, every input of the
    closure is measured on it (``microhom.closure.closure_inputs``; kt/kn as given)."""
    t0 = time.perf_counter()
    if net is not None:
        p = predict_closure(**closure_inputs(net, kt_over_kn=kt_over_kn))
    else:
        p = predict_closure(nc=stats["nc"], r=stats["r"], phi=stats["phi"], kt_over_kn=kt_over_kn,
                            dispersity=dispersity)
    return {"closure_K": float(p.K), "closure_G": float(p.G), "closure_err_K": float(p.error_K),
            "closure_err_G": float(p.error_G), "closure_valid": bool(p.valid),
            "closure_time_s": time.perf_counter() - t0}


def hierarchy_estimates(net, prestress: bool, order: int = 8) -> dict:
    """Relaxation hierarchy after ``order`` CG steps: upper bounds, extrapolated values with their
    stated errors, and the first-order (single-particle) estimate; wall time."""
    t0 = time.perf_counter()
    h = relaxation_hierarchy(net, prestress=prestress, tol=1e-9, max_order=order, spectral_bound="none")
    return {"hier_upper_K": h.K.upper, "hier_upper_G": h.G.upper, "hier_K": h.K.value, "hier_G": h.G.value,
            "hier_err_K": h.K.error, "hier_err_G": h.G.error, "hier_order": h.order,
            "first_order_K": h.K_first_order, "first_order_G": h.G_first_order,
            "hier_time_s": time.perf_counter() - t0}


def packing_case(case: dict) -> dict:
    """Build/load the packing of ``case``, measure it, and compute every estimate of K and G.

    case keys (defaults in ``DEFAULTS``): n, p_over_kn, kt_over_kn, mu, mu_prep, dispersity, seed;
    optional ``probes`` (bool), ``probe_amplitude``, ``alpha`` (theory model, default 1.76).
    Returns a flat dict of scalars (statistics, moduli, wall times).
    """
    res, t_pack, built = get_packing(case)
    kn, kt = 1.0, float(case.get("kt_over_kn", DEFAULTS["kt_over_kn"]))
    out = {"pack_time_s": t_pack, "pack_steps": int(res.report.get("steps", -1)),
           "psi6": float(res.report.get("psi6", np.nan)), "converged": bool(res.report.get("converged", True))}
    t0 = time.perf_counter()
    net = res.to_network()
    stats = network_statistics(net).as_dict()
    out["stats_time_s"] = time.perf_counter() - t0
    for k in ("nc", "nc_all", "r", "r_all", "rho", "rho_all", "phi", "nbar_phi", "rattler_fraction",
              "sliding_fraction", "vbar", "ebar", "vbar_theory", "ebar_theory"):
        out[k] = stats.get(k)
    if stats["nbar_phi"] is None:
        raise ValueError(f"phi = {stats['phi']:.4f} < pi/4: Nbar(phi) undefined for this packing")
    out.update(theory_estimates(stats, kn, kt, alpha=case.get("alpha", 1.76)))
    t0 = time.perf_counter()
    ex = stiffness(net, prestress=True)
    out["exact_time_s"] = time.perf_counter() - t0
    out.update({"exact_K": ex.K, "exact_G": ex.G, "affine_K": ex.K_affine, "affine_G": ex.G_affine,
                "n_floppy": ex.n_floppy, "exact_rattlers": ex.n_rattlers})
    ex0 = stiffness(net, prestress=False)
    out.update({"exact_noprestress_K": ex0.K, "exact_noprestress_G": ex0.G})
    out.update(closure_estimate(stats, kt, float(case.get("dispersity", DEFAULTS["dispersity"])), net=net))
    out.update(hierarchy_estimates(net, prestress=True, order=int(case.get("hierarchy_order", 16))))
    if case.get("probes"):
        pr = strain_probes(res.state, res.law, amplitude=case.get("probe_amplitude", 1e-8),
                           tol_unbalanced=case.get("probe_tol", 1e-8))
        out.update({"probe_K": pr.K, "probe_G": pr.G, "probe_time_s": pr.wall_time, "probe_steps": pr.steps,
                    "probe_converged": pr.converged, "probe_contact_events": pr.contact_events})
    return out
