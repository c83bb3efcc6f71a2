"""Analyse a packing file: contacts, structural sums, theory beside the exact stiffness.

The engine behind ``python -m microhom analyse FILE`` (see ``docs/scale_out.md``):

* :func:`load_network` reads any supported file — LAMMPS dump/data, OVAL D-file, dem.io npz/CSV
  (:func:`dem.io.read`), the packing npz of :meth:`dem.packing.PackingResult.save`, or a LAMMPS
  run folder of :mod:`dem.lammps` — and builds the :class:`~microhom.network.ContactNetwork`.
  Files that carry contact forces (packing npz, LAMMPS run folder) give a network with ``fn``,
  ``ft`` and their own ``kn``, ``kt``; plain configurations give contacts by overlap with the
  ``kn``, ``kt`` passed (default kn = 1, so moduli come out in units of kn).
* :func:`analyse` measures coordination (with and without rattlers), the structural-sum statistics
  (vbar, ebar of the mean A4 beside the isotropic values (37)), rho, the stress when forces are
  known, the theory's predictions (mean field; corrected with the measured rho; corrected with the
  alignment model at ``alpha``), and the exact stiffness tensor of :func:`dem.stiffness.stiffness`
  (with the pre-stress terms when asked).
* :func:`format_table`, :func:`flatten` render the result as text or as one flat record.

Units: whatever the file's (lengths) and kn's (N/m); 2D moduli and stresses in N/m (force per
length). A section that cannot be computed (e.g. the theory below phi = pi/4, the stiffness of an
open packing) holds ``{"error": "..."}`` instead of failing the whole analysis.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["load_network", "analyse", "analyse_file", "format_table", "flatten", "FORMATS"]

#: accepted ``format`` names: dem.io's plus the packing checkpoint and a LAMMPS run folder
FORMATS = ("lammps-data", "lammps-dump", "oval", "npz", "csv", "vtk", "packing", "lammps-run")


def _is_packing_npz(path) -> bool:
    try:
        with np.load(path, allow_pickle=False) as z:
            return "_scalars" in z.files and "x" in z.files
    except Exception:
        return False


def _with_branch_length(net, branch_length):
    if branch_length == "distance":
        return net
    if branch_length != "radii":
        raise ValueError(f"branch_length must be 'distance' or 'radii', got {branch_length!r}")
    rs = net.radii[net.pairs[:, 0]] + net.radii[net.pairs[:, 1]]
    return replace(net, branch=net.branch * (rs / net.lengths)[:, None])


def load_network(path, format=None, *, kn=None, kt=None, kn_convention=None, branch_length="distance",
                 frame=0, mu=None):
    """Read ``path`` and build its contact network.

    Returns ``(network, info)``; ``info`` has ``source``, ``format``, ``kn``, ``kt``,
    ``forces`` ("from file" or None) and ``notes`` (list of text). ``kn``/``kt``: contact
    stiffnesses [N/m] for files without them (default kn = 1, kt = kn); ``kn_convention`` as
    :meth:`dem.io.Configuration.network`; ``branch_length`` ``"distance"`` or ``"radii"``;
    ``frame``: dump frame; ``mu``: friction for sliding flags of a LAMMPS run folder (default:
    the run's). Raises :class:`dem.io.FormatError` / ``ValueError`` / ``FileNotFoundError``.
    """
    from dem import io

    path = Path(path)
    notes = []
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if format is None:
        if path.is_dir():
            format = "lammps-run"
        elif path.suffix.lower() == ".npz" and _is_packing_npz(path):
            format = "packing"
        else:
            format = io.detect_format(path)
    if format not in FORMATS:
        raise ValueError(f"unknown format {format!r}; known: {list(FORMATS)}")
    forces = None
    if format == "packing":
        from dem.packing import PackingResult
        try:
            res = PackingResult.load(path)
        except (KeyError, ValueError, OSError) as exc:
            raise io.FormatError(path, None, None, f"not a dem.packing result ({exc})") from None
        net = res.to_network()
        forces = "from file"
        law = res.law.to_meta() if hasattr(res.law, "to_meta") else {}
        if kn is not None or kt is not None:
            notes.append("--kn/--kt ignored: a packing file carries its own contact law "
                         f"({law.get('kind', type(res.law).__name__)})")
    elif format == "lammps-run":
        from dem.lammps import read_run
        run = read_run(path)
        net = run.network
        forces = "from file"
        if mu is not None:
            net = replace(net, sliding=np.abs(net.ft) >= mu * net.fn * (1 - 1e-9))
        if kn is not None or kt is not None:
            notes.append("--kn/--kt ignored: the run's kn, kt are used")
    else:
        kw = {"frame": frame} if format == "lammps-dump" else {}
        cfg = io.read(path, format=format, **kw)
        if kn is None:
            kn = 1.0
            notes.append("kn not given: kn = 1, moduli and stiffnesses are in units of kn")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            net = cfg.network(kn=kn, kt=kt, kn_convention=kn_convention)
        notes += [str(w.message) for w in caught]
    net = _with_branch_length(net, branch_length)
    info = {"source": str(path), "format": format, "forces": forces, "notes": notes,
            "kn": float(np.mean(net.kn)) if net.n_contacts else float("nan"),
            "kt": float(np.mean(net.kt)) if net.n_contacts else float("nan"),
            "branch_length": branch_length}
    return net, info


def _elastic_normal_forces(net):
    """fn = kn * overlap (linear law), from the geometry (the branch length is the centre distance)."""
    delta = net.radii[net.pairs[:, 0]] + net.radii[net.pairs[:, 1]] - net.lengths
    return net.kn * delta


def _section(fn, *args, **kwargs):
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = fn(*args, **kwargs)
        if caught:
            out["warnings"] = [str(w.message) for w in caught]
        return out
    except (ValueError, np.linalg.LinAlgError, RuntimeError) as exc:
        return {"error": str(exc)}


def _coordination(net, min_contacts):
    from dem.measure import coordination
    c = coordination(net, min_contacts)
    return {"z_all": c["z_all"], "z": c["z"], "n_rattlers": c["n_rattlers"],
            "rattler_fraction": c["rattler_fraction"], "hist_all": c["hist_all"].tolist(),
            "hist": c["hist"].tolist()}


def _statistics(net, min_contacts):
    from microhom.structural_sums import network_statistics
    st = network_statistics(net, min_contacts).as_dict()
    keys = ("n_particles", "n_contacts", "nc_all", "nc", "r_all", "r", "rho_all", "rho", "phi", "nbar_phi",
            "diameter", "sliding_fraction", "vbar", "ebar", "vbar_theory", "ebar_theory", "odd_norm")
    return {k: st.get(k) for k in keys}


def _stress(net):
    from dem.measure import stress
    s = stress(net)
    return {"pressure": float(-np.trace(s) / 2), "sxx": float(s[0, 0]), "syy": float(s[1, 1]),
            "sxy": float(s[0, 1]), "p_over_kn": float(-np.trace(s) / 2 / np.mean(net.kn))}


def _theory(net, alpha, min_contacts):
    from microhom.moduli import predict_from_network
    p = predict_from_network(net, warn=False, min_contacts=min_contacts)
    out = {"K_mf": float(p.K_mf), "G_mf": float(p.G_mf), "K_rho": float(p.K), "G_rho": float(p.G),
           "rho": float(p.rho), "nbar": float(p.nbar), "valid_rho": bool(p.valid),
           "reason_rho": str(p.reason)}
    pa = predict_from_network(net, warn=False, measured_rho=False, alpha=alpha, min_contacts=min_contacts)
    a = alpha if alpha is not None else 2.0 * (1.0 - 1.0 / float(pa.nbar))
    out.update({"alpha": float(a), "K_alpha": float(pa.K), "G_alpha": float(pa.G), "rho_alpha": float(pa.rho),
                "valid_alpha": bool(pa.valid), "reason_alpha": str(pa.reason)})
    return out


def _stiffness(net, prestress, min_contacts):
    from dem.stiffness import stiffness
    r = stiffness(net, prestress=prestress, min_contacts=min_contacts)
    return {"K": r.K, "G": r.G, "K_affine": r.K_affine, "G_affine": r.G_affine,
            "C_mandel": np.asarray(r.C_mandel).tolist(), "prestress": r.prestress,
            "n_rattlers": r.n_rattlers, "n_floppy": r.n_floppy, "n_unstable": r.n_unstable,
            "n_dof": r.n_dof, "residual": r.residual, "time_s": r.assembly_time + r.solve_time}


def analyse(net, *, alpha=None, prestress=False, min_contacts=None, exact=True) -> dict:
    """All measurements and predictions of one network (see the module docstring).

    alpha : alignment width for the model-rho prediction, in [0, 2] (None: the paper's
        ``2 (1 - 1/Nbar)``). prestress : include the pre-stress terms in the exact stiffness; the
        normal forces are the network's ``fn`` or, if it has none, ``kn * overlap``.
    min_contacts : rattler threshold (None: 2 with friction, 3 without). exact : compute the
        exact stiffness (one sparse factorisation).
    Returns a dict of sections: ``network``, ``coordination``, ``structural``, ``stress``,
    ``theory``, ``stiffness``, ``comparison``, ``notes``.
    """
    notes = []
    out = {"network": {"n_particles": net.n_particles, "n_contacts": net.n_contacts,
                       "periodic": net.cell is not None,
                       "kn_mean": float(np.mean(net.kn)) if net.n_contacts else None,
                       "kt_mean": float(np.mean(net.kt)) if net.n_contacts else None,
                       "forces": net.fn is not None}}
    out["coordination"] = _section(_coordination, net, min_contacts)
    out["structural"] = _section(_statistics, net, min_contacts)
    out["stress"] = _section(_stress, net) if net.fn is not None else {"error": "no contact forces in the file"}
    out["theory"] = _section(_theory, net, alpha, min_contacts)
    if exact:
        snet = net
        if prestress and net.fn is None:
            snet = replace(net, fn=_elastic_normal_forces(net))
            notes.append("--prestress: the file has no contact forces; fn = kn * overlap (linear law)")
        out["stiffness"] = _section(_stiffness, snet, prestress, min_contacts)
    else:
        out["stiffness"] = {"error": "not computed"}
    cmp = {}
    th, ex = out["theory"], out["stiffness"]
    if "error" not in th and "error" not in ex:
        for k in ("K", "G"):
            for lab in ("mf", "rho", "alpha"):
                if ex[k] != 0:
                    cmp[f"{k}_{lab}_over_exact"] = th[f"{k}_{lab}"] / ex[k]
    out["comparison"] = cmp
    out["notes"] = notes
    return out


def analyse_file(path, format=None, *, kn=None, kt=None, kn_convention=None, branch_length="distance",
                 alpha=None, prestress=False, min_contacts=None, frame=0, exact=True) -> dict:
    """:func:`load_network` then :func:`analyse`; the result has an extra ``file`` section."""
    import time

    t0 = time.perf_counter()
    net, info = load_network(path, format, kn=kn, kt=kt, kn_convention=kn_convention,
                             branch_length=branch_length, frame=frame)
    t1 = time.perf_counter()
    res = analyse(net, alpha=alpha, prestress=prestress, min_contacts=min_contacts, exact=exact)
    res["notes"] = info.pop("notes") + res["notes"]
    res["file"] = {**info, "read_s": t1 - t0, "analyse_s": time.perf_counter() - t1}
    return {"file": res.pop("file"), **res}


def flatten(res: dict) -> dict:
    """One flat record ``section.key -> scalar`` (lists joined with spaces), for CSV/JSON rows."""
    flat = {}
    for sec, d in res.items():
        if isinstance(d, dict):
            for k, v in d.items():
                if isinstance(v, (list, tuple)):
                    v = " ".join(str(x) for x in np.ravel(np.asarray(v, dtype=object)))
                flat[f"{sec}.{k}"] = v
        elif isinstance(d, list):
            flat[sec] = " | ".join(str(x) for x in d)
        else:
            flat[sec] = d
    return flat


def _g(x, fmt=".6g"):
    if x is None:
        return "n/a"
    if isinstance(x, float) and not math.isfinite(x):
        return "n/a"
    return format(x, fmt) if isinstance(x, (int, float, np.floating, np.integer)) else str(x)


def format_table(res: dict) -> str:
    """The readable report of :func:`analyse_file`."""
    L = []
    f = res.get("file", {})
    nw = res["network"]
    L.append(f"file: {f.get('source', '?')}  (format {f.get('format', '?')}, read in {_g(f.get('read_s'), '.3f')} s, "
             f"analysed in {_g(f.get('analyse_s'), '.3f')} s)")
    L.append(f"network: N = {nw['n_particles']}, contacts = {nw['n_contacts']}, "
             f"{'periodic' if nw['periodic'] else 'open'}, kn = {_g(nw['kn_mean'])}, kt = {_g(nw['kt_mean'])}, "
             f"branch = {f.get('branch_length', 'distance')}, forces: {'yes' if nw['forces'] else 'no'}")
    c = res["coordination"]
    L.append("")
    L.append("coordination")
    if "error" in c:
        L.append(f"  n/a: {c['error']}")
    else:
        L.append(f"  {'':28}{'all particles':>16}{'no rattlers':>16}")
        s = res["structural"]
        L.append(f"  {'mean Z':28}{_g(c['z_all'], '.5f'):>16}{_g(c['z'], '.5f'):>16}")
        if "error" not in s:
            L.append(f"  {'r = var(Z)/Z^2':28}{_g(s['r_all'], '.5f'):>16}{_g(s['r'], '.5f'):>16}")
            L.append(f"  {'rho (measured)':28}{_g(s['rho_all'], '.5f'):>16}{_g(s['rho'], '.5f'):>16}")
        L.append(f"  rattlers: {c['n_rattlers']} ({100 * c['rattler_fraction']:.2f} %); "
                 f"contact-count histogram (0, 1, 2, ...): {c['hist_all']}")
    s = res["structural"]
    L.append("")
    L.append("structural sums (mean A4 over non-rattlers, isotropic fit) vs (37)")
    if "error" in s:
        L.append(f"  n/a: {s['error']}")
    else:
        L.append(f"  {'':10}{'measured':>14}{'(37)':>14}{'ratio':>10}")
        for k in ("vbar", "ebar"):
            m, t = s.get(k), s.get(k + "_theory")
            ratio = (m / t) if (m is not None and t) else None
            L.append(f"  {k:10}{_g(m):>14}{_g(t):>14}{_g(ratio, '.4f'):>10}")
        L.append(f"  phi = {_g(s['phi'], '.5f')}, Nbar(phi) = {_g(s['nbar_phi'], '.4f')}, "
                 f"mean D = {_g(s['diameter'], '.5g')}, sliding fraction = {_g(s['sliding_fraction'], '.4f')}, "
                 f"odd-sum norm |A3|/(kn D) = {_g(s.get('odd_norm'), '.4g')}")
    st = res["stress"]
    L.append("")
    if "error" in st:
        L.append(f"stress: n/a ({st['error']})")
    else:
        L.append(f"stress (Love-Weber, tension positive, force/length): sxx = {_g(st['sxx'])}, "
                 f"syy = {_g(st['syy'])}, sxy = {_g(st['sxy'])}; pressure = {_g(st['pressure'])} "
                 f"(p/kn = {_g(st['p_over_kn'], '.4g')})")
    th, ex = res["theory"], res["stiffness"]
    L.append("")
    L.append("moduli (2D, force/length)")
    L.append(f"  {'estimate':44}{'K':>14}{'G':>14}{'K/exact':>10}{'G/exact':>10}")
    cmp = res.get("comparison", {})
    if "error" in th:
        L.append(f"  theory: n/a ({th['error']})")
    else:
        rows = [("mean field (37)", "mf", ""),
                (f"corrected, measured rho = {th['rho']:.4f}", "rho",
                 "" if th["valid_rho"] else "  FLAGGED: " + th["reason_rho"]),
                (f"corrected, alpha = {th['alpha']:.4g} (rho = {th['rho_alpha']:.4f})", "alpha",
                 "" if th["valid_alpha"] else "  FLAGGED: " + th["reason_alpha"])]
        for name, lab, flag in rows:
            L.append(f"  {name:44}{_g(th['K_' + lab]):>14}{_g(th['G_' + lab]):>14}"
                     f"{_g(cmp.get(f'K_{lab}_over_exact'), '.4f'):>10}{_g(cmp.get(f'G_{lab}_over_exact'), '.4f'):>10}{flag}")
    if "error" in ex:
        L.append(f"  exact: n/a ({ex['error']})")
    else:
        L.append(f"  {'affine (dem.stiffness)':44}{_g(ex['K_affine']):>14}{_g(ex['G_affine']):>14}")
        L.append(f"  {'exact' + (' with prestress' if ex['prestress'] else '') + ' (dem.stiffness)':44}"
                 f"{_g(ex['K']):>14}{_g(ex['G']):>14}")
        C = np.asarray(ex["C_mandel"])
        L.append("  exact C (Mandel [xx, yy, sqrt2 xy]):")
        for row in C:
            L.append("    " + "".join(f"{v:>14.6g}" for v in row))
        L.append(f"  rattlers removed {ex['n_rattlers']}, floppy modes {ex['n_floppy']}, dof {ex['n_dof']}, "
                 f"residual {ex['residual']:.1e}, solve {ex['time_s']:.3f} s")
    notes = list(res.get("notes", []))
    for sec in ("coordination", "structural", "stress", "theory", "stiffness"):
        notes += [f"{sec}: {w}" for w in res.get(sec, {}).get("warnings", [])]
    if notes:
        L.append("")
        L.append("notes:")
        L += [f"  - {n}" for n in notes]
    return "\n".join(L)
