"""Analyse a packing file: contacts, structural sums, theory beside the exact stiffness.

The engine behind ``python -m dem analyse FILE`` (see ``docs/scale_out.md``):

* :func:`load_network` reads any supported file — LAMMPS dump/data, OVAL D-file, dem.io npz/CSV
  (:func:`dem.io.read`), the packing npz of :meth:`dem.engine.packing.PackingResult.save`, or a LAMMPS
  run folder of :mod:`dem.engine.lammps` — and builds the :class:`~microhom.network.ContactNetwork`.
  Files that carry contact forces (packing npz, LAMMPS run folder) give a network with ``fn``,
  ``ft`` and their own ``kn``, ``kt``; plain configurations give contacts by overlap with the
  ``kn``, ``kt`` passed (default kn = 1, so moduli come out in units of kn).
* :func:`analyse` measures coordination (with and without rattlers), the structural-sum statistics
  (vbar, ebar of the mean A4 beside the isotropic values (37)), rho, the stress when forces are
  known, the theory's predictions (mean field; corrected with the measured rho; corrected with the
  alignment model at ``alpha``), the statistics-only closure of :mod:`microhom.closure` with its
  stated error, the relaxation hierarchy of :mod:`microhom.hierarchy` (moduli with a rigorous upper
  bound and a stated error, without a factorisation), and the exact stiffness tensor of
  :func:`dem.analysis.stiffness.stiffness` (with the pre-stress terms when asked).
* :class:`AnalysisResult` holds the result (frozen; ``as_dict()`` is the JSON of the command
  line, NaN as ``null``); :func:`format_table`, :func:`flatten` render it as text or as one flat
  record (the CSV row).

Units: whatever the file's (lengths) and kn's (N/m); 2D moduli and stresses in N/m (force per
length); vbar, ebar in N m (kn times a length squared). A section that cannot be computed (e.g.
the theory below phi = pi/4, the stiffness of an open packing, any statistic of a network whose
particles are all rattlers) holds ``{"error": "..."}`` with the reason instead of failing the
whole analysis or reporting a 0/0 as a number.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from microhom.closure import closure_inputs, predict_closure
from microhom.hierarchy import DEFAULT_TOL, relaxation_hierarchy
from microhom.moduli import predict_from_network
from microhom.results import Result
from microhom.structural_sums import network_statistics

from .. import io
from ..io.lammps_run import read_run
from .measure import coordination, stress
from .stiffness import stiffness

__all__ = ["load_network", "analyse", "analyse_file", "format_table", "flatten", "FORMATS",
           "AnalysisResult", "NOT_JAMMED"]

#: the reason given for every statistic of a network without a contact between non-rattlers
NOT_JAMMED = ("not jammed: every particle is a rattler (no contact left once particles with fewer "
              "than min_contacts contacts are removed), so Nc, r, rho and the theory are 0/0")
#: radii spread (max/min) above which the identical-disk theory gets a note
DISPERSITY_NOTE = 1.0 + 1e-6


@dataclass(frozen=True)
class AnalysisResult(Result):
    """What ``python -m dem analyse`` reports on one packing file (:func:`analyse_file`).

    Every field is one section of the report, a mapping of plain values (``{"error": reason}``
    when the section cannot be computed); ``as_dict()`` is the command line's JSON (NaN -> null).

    Attributes
    ----------
    file : dict
        ``source``, ``format``, ``forces`` ("from file" or None), ``kn``, ``kt`` (mean contact
        stiffnesses used [N/m]), ``branch_length``, ``read_s``, ``analyse_s`` (wall times [s]).
    network : dict
        ``n_particles``, ``n_contacts``, ``periodic``, ``kn_mean``, ``kt_mean`` [N/m], ``forces``
        (bool).
    coordination : dict
        ``z_all``, ``z`` (mean contacts per particle with / without rattlers), ``n_rattlers``,
        ``rattler_fraction``, ``hist_all``, ``hist`` (contact-count histograms).
    structural : dict
        The statistics of :func:`microhom.structural_sums.network_statistics` (``nc``, ``r``,
        ``rho`` with and without rattlers, ``phi``, ``nbar_phi``, ``diameter`` [m],
        ``sliding_fraction``, ``vbar``, ``ebar`` measured and ``*_theory`` (37) [N m],
        ``odd_norm``); ``r``, ``rho`` are ``None`` (not 0) when no particle is left.
    stress : dict
        Love-Weber stress [N/m], tension positive: ``sxx``, ``syy``, ``sxy``, ``pressure``
        (``-tr/2``) and ``p_over_kn`` (pressure over the mean ``kn``, dimensionless).
    theory : dict
        Moduli of :mod:`microhom.moduli` [N/m]: mean field ``K_mf``, ``G_mf``; corrected with the
        measured rho ``K_rho``, ``G_rho`` (``valid_rho``, ``reason_rho``); with the alignment model
        ``K_alpha``, ``G_alpha`` at ``alpha`` (``rho_alpha``, ``valid_alpha``, ``reason_alpha``).
    closure : dict
        :func:`microhom.closure.predict_closure` on the inputs measured by
        :func:`microhom.closure.closure_inputs` (Z as ``nc``, r, phi, kt/kn, dispersity, sliding
        and rattler fractions, size-coordination, p/kn; all in the dict too): ``K``, ``G`` [N/m],
        their stated errors ``error_K``, ``error_G`` [N/m] (per prediction, from the
        leave-one-protocol-out residuals, docs/results/closure.md), ``valid`` and ``reason``.
    hierarchy : dict
        :func:`microhom.hierarchy.relaxation_hierarchy` (same pre-stress choice as the exact
        stiffness; tolerance 1e-3, at most 16 CG steps): ``K``, ``G`` (best values), ``K_upper``,
        ``G_upper`` (rigorous upper bounds), ``K_lower``, ``G_lower`` (rigorous lower bounds or
        None), ``K_error``, ``G_error`` (stated errors) [N/m], ``order`` (CG steps),
        ``converged``, ``unstable``, ``reasons``, ``time_s`` [s].
    stiffness : dict
        :func:`dem.analysis.stiffness.stiffness`: ``K``, ``G``, ``K_affine``, ``G_affine`` [N/m],
        ``C_mandel`` (3, 3) [N/m], ``prestress``, ``n_rattlers``, ``n_floppy``, ``n_unstable``,
        ``n_dof``, ``residual``, ``time_s`` [s].
    comparison : dict
        ``{K,G}_{mf,rho,alpha,closure,hierarchy}_over_exact`` ratios (dimensionless).
    notes : list of str
        The assumptions made (kn, kt, frame) and what the reader warned.
    """

    file: dict = field(default_factory=dict)
    network: dict = field(default_factory=dict)
    coordination: dict = field(default_factory=dict)
    structural: dict = field(default_factory=dict)
    stress: dict = field(default_factory=dict)
    theory: dict = field(default_factory=dict)
    closure: dict = field(default_factory=dict)
    hierarchy: dict = field(default_factory=dict)
    stiffness: dict = field(default_factory=dict)
    comparison: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def sections(self) -> dict:
        """The sections as they are (numpy scalars and NaN kept), in report order."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @property
    def jammed(self) -> bool:
        """False when no contact is left between non-rattlers (see :data:`NOT_JAMMED`)."""
        return self.structural.get("error") != NOT_JAMMED

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


def load_network(path, format=None, *, kn=None, kt=None, kt_ratio=None, kn_convention=None,
                 branch_length="distance", frame=-1, mu=None, radius=None):
    """Read ``path`` and build its contact network.

    Returns ``(network, info)``; ``info`` has ``source``, ``format``, ``kn``, ``kt``,
    ``forces`` ("from file" or None) and ``notes`` (list of text). ``kn``/``kt``: contact
    stiffnesses [N/m] for files without them (default kn = 1, kt = kn, said in the notes);
    ``kt_ratio``: kt = kt_ratio * kn instead (LAMMPS gran/hooke/history's default is 2/7);
    ``kn_convention`` as :meth:`dem.io.Configuration.network`; ``branch_length`` ``"distance"`` or
    ``"radii"``; ``frame``: dump frame (default the last; the notes say which); ``radius``: a
    constant radius for dumps without a radius column; ``mu``: friction for sliding flags of a
    LAMMPS run folder (default: the run's).
    Raises :class:`dem.io.FormatError` / ``ValueError`` / ``FileNotFoundError``.
    """
    path = Path(path)
    notes = []
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if not path.is_dir():
        io.check_regular_file(path)   # the reading rule: no FIFO, device or oversized file
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
    file_arm = "radius" if format.startswith("lammps") else "contact"
    if format == "packing":
        net = io.read_npz_network(path)
        if net is None:
            raise io.FormatError(path, None, "network:pairs", "a dem packing file without its stored "
                                 "contact network (written before it was stored): load it with "
                                 "dem.engine.packing.PackingResult.load and save it again")
        forces = "from file"
        law = io.read_npz(path).meta.get("law") or {}
        if kn is not None or kt is not None or kt_ratio is not None:
            notes.append("--kn/--kt ignored: a packing file carries its own contact law "
                         f"({law.get('law', 'stored')}) and network")
    elif format == "lammps-run":
        if not path.is_dir() or not (path / "in.packing").is_file():
            raise io.FormatError(path, None, None, "not a LAMMPS run folder (no in.packing: the "
                                 "folder dem.engine.lammps.pack_lammps writes holds in.packing, "
                                 "final.dump and contacts.dump)")
        run = read_run(path)
        net = run.network
        forces = "from file"
        if mu is not None:
            net = replace(net, sliding=np.abs(net.ft) >= mu * net.fn * (1 - 1e-9))
        if kn is not None or kt is not None or kt_ratio is not None:
            notes.append("--kn/--kt ignored: the run's kn, kt are used")
    else:
        kw = {"frame": frame, "radius": radius} if format == "lammps-dump" else {}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            cfg = io.read(path, format=format, **kw)
        notes += [str(w.message) for w in caught]
        if format == "lammps-dump":
            m = cfg.meta
            notes.append(f"LAMMPS dump: analysed frame {m['frame'] + 1} of {m.get('n_frames', '?')} "
                         f"(timestep {m.get('timestep', '?')})"
                         + ("; --frame N picks another (1 = first, -1 = last)"
                            if m.get("n_frames", 1) > 1 else ""))
        if kn is None:
            kn = 1.0
            notes.append("kn not given: kn = 1, moduli and stiffnesses are in units of kn")
        if kt is not None and kt_ratio is not None:
            raise ValueError("give --kt or --kt-ratio, not both")
        if kt_ratio is not None:
            if not (math.isfinite(kt_ratio) and kt_ratio >= 0):
                raise ValueError(f"--kt-ratio must be finite and >= 0, got {kt_ratio!r}")
            # the ratio is of the physical stiffnesses: OVAL's kn multiplies half the overlap, its
            # force per unit overlap (the network's kn) is kn/2, and kt is never converted
            kt = kt_ratio * (kn / 2.0 if kn_convention == "oval" else kn)
        elif kt is None:
            notes.append("kt not given: kt = kn assumed (LAMMPS gran/hooke/history defaults to "
                         "kt = 2/7 kn: give --kt or --kt-ratio 0.2857 for such a run)")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            net = cfg.network(kn=kn, kt=kt, kn_convention=kn_convention)
        notes += [str(w.message) for w in caught]
    net = _with_branch_length(net, branch_length)
    info = {"source": str(path), "format": format, "forces": forces, "notes": notes,
            "kn": float(np.mean(net.kn)) if net.n_contacts else float("nan"),
            "kt": float(np.mean(net.kt)) if net.n_contacts else float("nan"),
            "branch_length": branch_length, "spin_arm": file_arm}
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


def _get(obj, key):
    """``obj[key]`` for a dict, ``obj.key`` for a result dataclass (either shape is accepted)."""
    return obj[key] if isinstance(obj, dict) else getattr(obj, key)


def _coordination(net, min_contacts):
    c = coordination(net, min_contacts)
    return {"z_all": _get(c, "z_all"), "z": _get(c, "z"), "n_rattlers": _get(c, "n_rattlers"),
            "rattler_fraction": _get(c, "rattler_fraction"),
            "hist_all": np.asarray(_get(c, "hist_all")).tolist(),
            "hist": np.asarray(_get(c, "hist")).tolist()}


_STAT_KEYS = ("n_particles", "n_contacts", "nc_all", "nc", "r_all", "r", "rho_all", "rho", "phi",
              "nbar_phi", "diameter", "sliding_fraction", "vbar", "ebar", "vbar_theory",
              "ebar_theory", "odd_norm", "rho_nbar", "rho_note")


def _statistics(net, min_contacts, rho_neighbours="near"):
    st = network_statistics(net, min_contacts, rho_neighbours=rho_neighbours)
    get = (lambda k: st.get(k)) if isinstance(st, dict) else (lambda k: getattr(st, k, None))
    out = {k: get(k) for k in _STAT_KEYS}
    out["rho_neighbours"] = rho_neighbours
    # r = var/mean^2 and rho = sum V.W / sum V^2 are 0/0 without contacts: None, never 0
    if not out["nc_all"]:
        out["r_all"] = out["rho_all"] = None
    if not out["nc"]:
        out["r"] = out["rho"] = None
    return out


def _stress(net):
    s = stress(net)
    return {"pressure": float(-np.trace(s) / 2), "sxx": float(s[0, 0]), "syy": float(s[1, 1]),
            "sxy": float(s[0, 1]), "p_over_kn": float(-np.trace(s) / 2 / np.mean(net.kn))}


def _theory(net, alpha, min_contacts, rho_neighbours="near"):
    p = predict_from_network(net, warn=False, min_contacts=min_contacts, rho_neighbours=rho_neighbours)
    out = {"K_mf": float(p.K_mf), "G_mf": float(p.G_mf), "K_rho": float(p.K), "G_rho": float(p.G),
           "rho": float(p.rho), "nbar": float(p.nbar), "valid_rho": bool(p.valid),
           "reason_rho": str(p.reason)}
    pa = predict_from_network(net, warn=False, measured_rho=False, alpha=alpha, min_contacts=min_contacts)
    a = alpha if alpha is not None else 2.0 * (1.0 - 1.0 / float(pa.nbar))
    out.update({"alpha": float(a), "K_alpha": float(pa.K), "G_alpha": float(pa.G), "rho_alpha": float(pa.rho),
                "valid_alpha": bool(pa.valid), "reason_alpha": str(pa.reason)})
    return out


def _closure(net, structural):
    x = closure_inputs(net)       # Z, r, phi, sliding and rattler fractions, dispersity, size-coordination, p/kn
    p = predict_closure(**x)
    return {"K": float(p.K), "G": float(p.G), "error_K": float(p.error_K), "error_G": float(p.error_G),
            "valid": bool(p.valid), "reason": str(p.reason), **{k: float(v) for k, v in x.items()}}


def _hierarchy(net, prestress, min_contacts, tol=DEFAULT_TOL):
    t0 = time.perf_counter()
    h = relaxation_hierarchy(net, prestress=prestress, tol=tol, max_order=16, min_contacts=min_contacts)
    return {"K": h.K.value, "G": h.G.value, "K_upper": h.K.upper, "G_upper": h.G.upper,
            "K_lower": h.K.lower, "G_lower": h.G.lower, "K_error": h.K.error, "G_error": h.G.error,
            "order": h.order, "converged": h.converged, "unstable": h.unstable,
            "valid": h.valid, "certified": h.certified, "calibrated": h.calibrated,
            "reasons": list(h.reasons), "time_s": time.perf_counter() - t0}


def _stiffness(net, prestress, min_contacts, spin_arm="contact"):
    r = stiffness(net, prestress=prestress, min_contacts=min_contacts, spin_arm=spin_arm)
    return {"K": r.K, "G": r.G, "K_affine": r.K_affine, "G_affine": r.G_affine,
            "C_mandel": np.asarray(r.C_mandel).tolist(), "prestress": r.prestress,
            "n_rattlers": r.n_rattlers, "n_floppy": r.n_floppy, "n_unstable": r.n_unstable,
            "n_dof": r.n_dof, "residual": r.residual, "time_s": r.assembly_time + r.solve_time}


def analyse(net, *, alpha=None, prestress=False, min_contacts=None, exact=True,
            hierarchy=True, spin_arm="contact", hierarchy_tol=DEFAULT_TOL,
            rho_neighbours="near") -> AnalysisResult:
    """All measurements and predictions of one network (see the module docstring).

    Parameters
    ----------
    net : microhom.network.ContactNetwork
        The packing (positions [m], radii [m], contacts, stiffnesses [N/m], forces if any).
    alpha : float, optional
        Alignment width for the model-rho prediction, in [0, 2] (None: the paper's
        ``2 (1 - 1/Nbar)``).
    prestress : bool
        Include the pre-stress terms in the exact stiffness; the normal forces are the network's
        ``fn`` or, if it has none, ``kn * overlap``.
    min_contacts : int, optional
        Rattler threshold (None: 2 with friction, 3 without).
    exact : bool
        Compute the exact stiffness (one sparse factorisation).
    hierarchy : bool
        Compute the relaxation hierarchy (periodic networks only).
    spin_arm : ``"contact"`` or ``"radius"``
        Spin kinematics of the exact stiffness (:mod:`microhom.kinematics`): the distance to the
        contact point (default, the theory's) or the radius (LAMMPS ``gran/*``, the disk engine's
        default law). :func:`analyse_file` matches it to the file's code.
    hierarchy_tol : float
        Target relative width of the hierarchy's interval, in (0, 1); default
        :data:`microhom.hierarchy.DEFAULT_TOL` (the library's own default).
    rho_neighbours : str
        The neighbourhood of the measured rho (``microhom.structural_sums.network_statistics``):
        ``"near"`` (default, the paper's N̄ near neighbours) or ``"contacts"``.

    Returns
    -------
    AnalysisResult
        Its ``file`` section empty. A network without a contact between non-rattlers is not
        jammed: its statistics, theory and stiffness sections hold ``{"error": NOT_JAMMED}``
        instead of 0/0 values.
    """
    notes = []
    network = {"n_particles": net.n_particles, "n_contacts": net.n_contacts,
               "periodic": net.cell is not None,
               "kn_mean": float(np.mean(net.kn)) if net.n_contacts else None,
               "kt_mean": float(np.mean(net.kt)) if net.n_contacts else None,
               "forces": net.fn is not None}
    coord = _section(_coordination, net, min_contacts)
    jammed = "error" in coord or coord["n_rattlers"] < net.n_particles
    if not jammed:
        coord["z"] = None  # the mean over no particle
    structural = _section(_statistics, net, min_contacts, rho_neighbours) if jammed else {"error": NOT_JAMMED}
    stress_ = (_section(_stress, net) if net.fn is not None and net.n_contacts
               else {"error": "no contact forces in the file" if net.fn is None else "no contacts"})
    theory = _section(_theory, net, alpha, min_contacts, rho_neighbours) if jammed else {"error": NOT_JAMMED}
    closure = (_section(_closure, net, structural) if jammed and "error" not in structural
               else {"error": structural.get("error", NOT_JAMMED)})
    snet = net
    if prestress and net.fn is None and (exact or hierarchy):
        snet = replace(net, fn=_elastic_normal_forces(net))
        notes.append("--prestress: the file has no contact forces; fn = kn * overlap (linear law)")
    if not hierarchy:
        hier = {"error": "not computed"}
    elif not jammed:
        hier = {"error": NOT_JAMMED}
    elif net.cell is None:
        hier = {"error": "open packing: the hierarchy estimates the stiffness of a periodic cell"}
    else:
        hier = _section(_hierarchy, snet, prestress, min_contacts, hierarchy_tol)
    if not exact:
        stiff = {"error": "not computed"}
    elif not jammed:
        stiff = {"error": NOT_JAMMED}
    else:
        stiff = _section(_stiffness, snet, prestress, min_contacts, spin_arm)
    if not jammed:
        notes.append(NOT_JAMMED)
    if net.n_particles and net.radii.max() > DISPERSITY_NOTE * net.radii.min():
        notes.append(f"the radii differ (max/min = {net.radii.max() / net.radii.min():.3g}, "
                     f"relative spread {np.std(net.radii) / np.mean(net.radii):.3g}): the theory "
                     "is for identical disks, its moduli are a reference for this packing")
    cmp = {}
    if "error" not in stiff:
        for k in ("K", "G"):
            if stiff[k] == 0:
                continue
            if "error" not in theory:
                for lab in ("mf", "rho", "alpha"):
                    cmp[f"{k}_{lab}_over_exact"] = theory[f"{k}_{lab}"] / stiff[k]
            if "error" not in closure:
                cmp[f"{k}_closure_over_exact"] = closure[k] / stiff[k]
            if "error" not in hier:
                cmp[f"{k}_hierarchy_over_exact"] = hier[k] / stiff[k]
    return AnalysisResult(network=network, coordination=coord, structural=structural,
                          stress=stress_, theory=theory, closure=closure, hierarchy=hier,
                          stiffness=stiff, comparison=cmp, notes=notes)


def analyse_file(path, format=None, *, kn=None, kt=None, kt_ratio=None, kn_convention=None,
                 branch_length="distance", alpha=None, prestress=False, min_contacts=None, frame=-1,
                 radius=None, exact=True, hierarchy=True, spin_arm=None,
                 hierarchy_tol=DEFAULT_TOL, rho_neighbours="near") -> AnalysisResult:
    """:func:`load_network` then :func:`analyse`; the result's ``file`` section says what was read
    and how long it took, its notes start with the assumptions made while reading.

    ``spin_arm=None`` (default) matches the exact stiffness's spin kinematics to the file's code:
    ``"radius"`` for LAMMPS files and run folders (``gran/*`` turns spins about the radius),
    ``"contact"`` otherwise (the kinematics of the theory and of the hierarchy, whose bounds hold
    for it; ``dem.engine.packing`` files too, although the engine's default law turns spins about the
    radius); the notes say which was used. Give ``"contact"`` or ``"radius"`` to choose."""
    t0 = time.perf_counter()
    net, info = load_network(path, format, kn=kn, kt=kt, kt_ratio=kt_ratio,
                             kn_convention=kn_convention, branch_length=branch_length,
                             frame=frame, radius=radius)
    t1 = time.perf_counter()
    file_arm = info["spin_arm"]
    if spin_arm is None:
        spin_arm = file_arm
        why = "matched to the file's code" if file_arm == "radius" else "the exact solver's default"
    else:
        why = "as asked" + ("" if spin_arm == file_arm else f"; the file's code uses {file_arm!r}")
    info["spin_arm"] = spin_arm
    if exact:
        info["notes"].append(
            f"spin arms of the exact stiffness: {spin_arm!r} ({why}; "
            + ("the radius r_i, as LAMMPS gran/*" if spin_arm == "radius" else
               "the distance to the contact point |c| r_i/(r_i + r_j)")
            + "; --spin-arm contact|radius chooses; the theory and the hierarchy use contact arms)")
    res = analyse(net, alpha=alpha, prestress=prestress, min_contacts=min_contacts, exact=exact,
                  hierarchy=hierarchy, spin_arm=spin_arm, hierarchy_tol=hierarchy_tol,
                  rho_neighbours=rho_neighbours)
    notes = info.pop("notes") + res.notes
    return replace(res, file={**info, "read_s": t1 - t0, "analyse_s": time.perf_counter() - t1},
                   notes=notes)


def flatten(res) -> dict:
    """One flat record ``section.key -> scalar`` (lists joined with spaces), for CSV/JSON rows."""
    sections = res.sections() if isinstance(res, AnalysisResult) else res
    flat = {}
    for sec, d in sections.items():
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


def format_table(res) -> str:
    """The readable report of :func:`analyse_file` (an :class:`AnalysisResult`)."""
    if isinstance(res, AnalysisResult):
        res = res.sections()
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
            hood = ("V over contacts" if s.get("rho_neighbours") == "contacts"
                    else f"V over Nbar = {_g(s.get('rho_nbar'), '.3g')}")
            L.append(f"  {'rho (' + hood + ')':28}{_g(s['rho_all'], '.5f'):>16}{_g(s['rho'], '.5f'):>16}")
            if s.get("rho_note"):
                L.append(f"  rho: {s['rho_note']}")
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
            L.append(f"  {k + ' [N m]':10}{_g(m):>14}{_g(t):>14}{_g(ratio, '.4f'):>10}")
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
    L.append(f"  {'estimate':44}{'K [N/m]':>14}{'G [N/m]':>14}{'K/exact':>10}{'G/exact':>10}")
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
    cl, hi = res.get("closure", {}), res.get("hierarchy", {})
    if cl and "error" not in cl:
        flag = "" if cl["valid"] else "  FLAGGED: " + cl["reason"]
        L.append(f"  {'closure (statistics only)':44}{_g(cl['K']):>14}{_g(cl['G']):>14}"
                 f"{_g(cmp.get('K_closure_over_exact'), '.4f'):>10}{_g(cmp.get('G_closure_over_exact'), '.4f'):>10}{flag}")
        L.append(f"  {'  stated error (this prediction)':44}{_g(cl['error_K'], '.3g'):>14}{_g(cl['error_G'], '.3g'):>14}")
    elif cl:
        L.append(f"  closure: n/a ({cl['error']})")
    if hi and "error" not in hi:
        flag = "" if hi.get("valid", True) else "  FLAGGED: not valid (see notes)"
        L.append(f"  {'hierarchy (%d CG steps), value' % hi['order']:44}{_g(hi['K']):>14}{_g(hi['G']):>14}"
                 f"{_g(cmp.get('K_hierarchy_over_exact'), '.4f'):>10}{_g(cmp.get('G_hierarchy_over_exact'), '.4f'):>10}{flag}")
        L.append(f"  {'  rigorous upper bound':44}{_g(hi['K_upper']):>14}{_g(hi['G_upper']):>14}")
        L.append(f"  {'  rigorous lower bound':44}{_g(hi['K_lower']):>14}{_g(hi['G_lower']):>14}")
        L.append(f"  {'  stated error':44}{_g(hi['K_error'], '.3g'):>14}{_g(hi['G_error'], '.3g'):>14}"
                 f"  ({'converged' if hi['converged'] else 'tolerance not met'}"
                 f"{', UNSTABLE' if hi['unstable'] else ''}, {hi['time_s']:.3f} s)")
    elif hi:
        L.append(f"  hierarchy: n/a ({hi['error']})")
    if "error" in ex:
        L.append(f"  exact: n/a ({ex['error']})")
    else:
        L.append(f"  {'affine (dem.analysis.stiffness)':44}{_g(ex['K_affine']):>14}{_g(ex['G_affine']):>14}")
        L.append(f"  {'exact' + (' with prestress' if ex['prestress'] else '') + ' (dem.analysis.stiffness)':44}"
                 f"{_g(ex['K']):>14}{_g(ex['G']):>14}")
        C = np.asarray(ex["C_mandel"])
        L.append("  exact C (Mandel [xx, yy, sqrt2 xy]):")
        for row in C:
            L.append("    " + "".join(f"{v:>14.6g}" for v in row))
        L.append(f"  rattlers removed {ex['n_rattlers']}, floppy modes {ex['n_floppy']}, dof {ex['n_dof']}, "
                 f"residual {ex['residual']:.1e}, solve {ex['time_s']:.3f} s")
    notes = list(res.get("notes", []))
    for sec in ("coordination", "structural", "stress", "theory", "closure", "hierarchy", "stiffness"):
        notes += [f"{sec}: {w}" for w in res.get(sec, {}).get("warnings", [])]
    notes += [f"hierarchy: {r}" for r in hi.get("reasons", [])] if hi and "error" not in hi else []
    if notes:
        L.append("")
        L.append("notes:")
        L += [f"  - {n}" for n in notes]
    return "\n".join(L)
