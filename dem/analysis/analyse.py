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
* :class:`AnalysisResult` holds the typed results themselves (frozen): ``res.structural.rho``,
  ``res.theory.rho_prediction.K``, ``res.hierarchy.K.upper``, ``res.stiffness.C_mandel``, ...
  ``as_dict()`` is the JSON of the command line (NaN as ``null``), built by one view per section
  (:meth:`AnalysisResult.sections`); :func:`format_table`, :func:`flatten` render it as text or
  as one flat record (the CSV row).

Units: whatever the file's (lengths) and kn's (N/m); 2D moduli and stresses in N/m (force per
length); vbar, ebar in N m (kn times a length squared). A section that cannot be computed (e.g.
the stiffness of an open packing, any statistic of a network whose particles are all rattlers)
holds a :class:`SectionError` with the reason (``{"error": "..."}`` in the JSON) instead of failing
the whole analysis or reporting a 0/0 as a number; reading a field of it raises
``AttributeError`` naming the reason.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from microhom.options import OptionError, real
from microhom.options import finite_real as _finite_real, flag as _flag, integer as _integer
from microhom.closure import ClosurePrediction, closure_inputs, predict_closure
from microhom.hierarchy import DEFAULT_TOL, HierarchyResult, relaxation_hierarchy
from microhom.moduli import Prediction, predict_from_network
from microhom.results import Result, to_plain
from microhom.structural_sums import (NetworkStatistics, SphereStatistics, network_statistics,
                                      sphere_statistics)

from .. import io
from ..io.lammps_run import read_run
from .measure import Coordination, coordination, stress
from .stiffness import StiffnessResult, stiffness

__all__ = ["load_network", "analyse", "analyse_file", "AnalysisOptions", "OptionError",
           "format_table", "flatten", "FORMATS", "AnalysisResult", "SectionError",
           "SectionWarnings", "FileInfo", "NetworkSummary", "StressResult", "TheoryResult",
           "ClosureInputs", "Comparison", "NOT_JAMMED"]

#: the reason given for every statistic of a network without a contact between non-rattlers
NOT_JAMMED = ("not jammed: every particle is a rattler (no contact left once particles with fewer "
              "than min_contacts contacts are removed), so Nc, r, rho and the theory are 0/0")
#: radii spread (max/min) above which the identical-disk theory gets a note
DISPERSITY_NOTE = 1.0 + 1e-6

#: the sections of the report, in the order of the JSON and the CSV
SECTIONS = ("file", "network", "coordination", "structural", "stress", "theory", "closure",
            "hierarchy", "stiffness", "comparison", "notes")


@dataclass(frozen=True)
class SectionError(Result):
    """A section of :class:`AnalysisResult` that could not be computed, and why.

    Attributes
    ----------
    message : str
        The reason (e.g. :data:`NOT_JAMMED`, ``"not computed"``, the error the library raised).

    ``as_dict()`` is the section's JSON, ``{"error": message}``. Reading any other attribute (as
    if the section had been computed, ``res.hierarchy.K``) raises ``AttributeError`` naming the
    reason, never a silent ``None``.
    """

    message: str

    def as_dict(self) -> dict:
        """``{"error": message}``, the section as the JSON prints it."""
        return {"error": self.message}

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        raise AttributeError(f"{name!r}: this section was not computed "
                             f"({self.__dict__.get('message', '?')})")


@dataclass(frozen=True)
class SectionWarnings(Result):
    """The warnings a section's computation raised, one sentence each (empty: none); the JSON
    lists them as the section's ``warnings`` key, the table as notes.

    Attributes
    ----------
    coordination, structural, stress, theory, closure, hierarchy, stiffness : tuple of str
        Per section of :class:`AnalysisResult`.
    """

    coordination: tuple = ()
    structural: tuple = ()
    stress: tuple = ()
    theory: tuple = ()
    closure: tuple = ()
    hierarchy: tuple = ()
    stiffness: tuple = ()


@dataclass(frozen=True)
class FileInfo(Result):
    """What :func:`analyse_file` read and how long it took (the JSON's ``file`` section).

    Attributes
    ----------
    source : str
        The path as given.
    format : str
        One of :data:`FORMATS`.
    forces : str or None
        ``"from file"`` when the file carries contact forces and its own contact law, else None.
    kn, kt : float
        Mean contact stiffnesses of the network built [N/m] (NaN without contacts).
    branch_length : str
        ``"distance"`` or ``"radii"`` (:func:`load_network`).
    spin_arm : str
        Spin kinematics of the exact stiffness, ``"contact"`` or ``"radius"``.
    read_s, analyse_s : float
        Wall times of reading and of :func:`analyse` [s].
    """

    source: str
    format: str
    forces: str | None
    kn: float
    kt: float
    branch_length: str
    spin_arm: str
    read_s: float
    analyse_s: float


@dataclass(frozen=True)
class NetworkSummary(Result):
    """Size and contact law of the network analysed (the JSON's ``network`` section).

    Attributes
    ----------
    n_particles, n_contacts : int
        Particles N and contacts C.
    periodic : bool
        True with a periodic cell.
    kn_mean, kt_mean : float or None
        Mean contact stiffnesses [N/m]; None without contacts.
    forces : bool
        True when the network carries contact forces ``fn``.
    """

    n_particles: int
    n_contacts: int
    periodic: bool
    kn_mean: float | None
    kt_mean: float | None
    forces: bool


@dataclass(frozen=True)
class StressResult(Result):
    """Love-Weber stress of the contact forces [N/m, 2D force per length], tension positive.

    Attributes
    ----------
    pressure : float
        ``-tr(sigma)/2`` [N/m].
    sxx, syy, sxy : float
        Components [N/m].
    p_over_kn : float
        Pressure over the mean ``kn`` [-].
    """

    pressure: float
    sxx: float
    syy: float
    sxy: float
    p_over_kn: float


@dataclass(frozen=True)
class TheoryResult(Result):
    """The theory's two predictions (:func:`microhom.moduli.predict_from_network`, eqs. (37),
    (50)-(51)); moduli [N/m].

    Attributes
    ----------
    rho_prediction : microhom.moduli.Prediction
        With the rho measured on the network (its ``K_mf``, ``G_mf`` are the mean field (37)).
    alpha_prediction : microhom.moduli.Prediction
        With rho of the alignment model (54) at ``alpha``.
    alpha : float
        The alignment width used, in [0, 2] (default ``2 (1 - 1/Nbar)``) [-].
    """

    rho_prediction: Prediction
    alpha_prediction: Prediction
    alpha: float


@dataclass(frozen=True)
class ClosureInputs(Result):
    """The inputs of :func:`microhom.closure.predict_closure` measured on the network
    (:func:`microhom.closure.closure_inputs`).

    Attributes
    ----------
    nc : float
        Mean coordination Z of the non-rattlers [-].
    r : float
        ``var(Z)/Z^2`` [-].
    phi : float
        Solid fraction [-].
    kt_over_kn : float
        Mean kt of the non-sliding contacts over the mean kn [-].
    dispersity : float
        Relative spread of the radii [-].
    kn : float
        Mean kn [N/m].
    sliding_fraction, rattler_fraction : float
        Fractions of contacts at the Coulomb limit and of particles that are rattlers [-].
    size_coordination : float
        Size-coordination correlation [-].
    p_over_kn : float or None
        Love-Weber pressure over kn [-]; None when not positive (then not passed to the closure).
    psi6_local : float or None
        Mean local bond order ``<|psi6_i|>`` of the load-bearing contacts
        (:func:`microhom.structural_sums.bond_order`) [-]; None when there are none.
    n_particles : int or None
        Number of particles, rattlers included (below 1000 the closure flags its prediction).
    """

    nc: float
    r: float
    phi: float
    kt_over_kn: float
    dispersity: float
    kn: float
    sliding_fraction: float
    rattler_fraction: float
    size_coordination: float
    p_over_kn: float | None = None
    psi6_local: float | None = None
    n_particles: int | None = None


@dataclass(frozen=True)
class Comparison(Result):
    """Each estimate's modulus over the exact one (dimensionless); None where either side was
    not computed or the exact modulus is 0 (the JSON leaves those keys out).

    Attributes
    ----------
    K_mf_over_exact, K_rho_over_exact, K_alpha_over_exact : float or None
        The theory's mean field (37) and its corrections with the measured rho and with alpha;
        on spheres (3D) ``K_mf_over_exact`` is the affine (Voigt) mean field of the fabric
        (``structural.K_affine``) and the corrections are not defined.
    K_closure_over_exact, K_hierarchy_over_exact : float or None
        The closure and the hierarchy's best value.
    G_mf_over_exact, G_rho_over_exact, G_alpha_over_exact : float or None
        As above, shear modulus.
    G_closure_over_exact, G_hierarchy_over_exact : float or None
        As above, shear modulus.
    """

    K_mf_over_exact: float | None = None
    K_rho_over_exact: float | None = None
    K_alpha_over_exact: float | None = None
    K_closure_over_exact: float | None = None
    K_hierarchy_over_exact: float | None = None
    G_mf_over_exact: float | None = None
    G_rho_over_exact: float | None = None
    G_alpha_over_exact: float | None = None
    G_closure_over_exact: float | None = None
    G_hierarchy_over_exact: float | None = None


def _ok(x) -> bool:
    """True when a section was computed (not a :class:`SectionError`)."""
    return not isinstance(x, SectionError)


@dataclass(frozen=True)
class AnalysisResult(Result):
    """What ``python -m dem analyse`` reports on one packing file (:func:`analyse_file`).

    Every section is the library's own typed result, or a :class:`SectionError` saying why it
    could not be computed. ``as_dict()`` is the command line's JSON (NaN -> null), one dict per
    section in the order of ``SECTIONS`` (:meth:`sections` gives the views; the key names
    are the JSON's, e.g. ``hierarchy.K_upper`` is ``res.hierarchy.K.upper``).

    Attributes
    ----------
    network : NetworkSummary
        Particles, contacts, periodicity, mean ``kn``, ``kt`` [N/m], forces.
    coordination : dem.analysis.measure.Coordination or SectionError
        Mean contacts per particle with (``z_all``) and without (``z``) rattlers, histograms,
        rattlers. ``z`` is NaN (JSON null) when every particle is a rattler.
    structural : microhom.structural_sums.NetworkStatistics, SphereStatistics or SectionError
        Nc, r, rho with and without rattlers, phi, Nbar(phi), mean diameter [m], sliding
        fraction, vbar, ebar measured and of (37) [N m], odd-sum norm; :data:`NOT_JAMMED` when no
        contact is left between non-rattlers. On spheres (3D) the
        :class:`~microhom.structural_sums.SphereStatistics`: Z and r with and without rattlers,
        phi, the sliding and rattler fractions, and the mean field, the affine (Voigt) moduli of
        the fabric ``K_affine``, ``G_affine`` [Pa] with their (6, 6) tensor ``C_affine``.
    stress : StressResult or SectionError
        Love-Weber stress [N/m], when the network has contact forces.
    theory : TheoryResult or SectionError
        The predictions with the measured rho (``theory.rho_prediction``) and with the alignment
        model (``theory.alpha_prediction``, ``theory.alpha``) [N/m].
    closure : microhom.closure.ClosurePrediction or SectionError
        The statistics-only closure (0-d arrays): ``K``, ``G`` [N/m] and their stated errors
        ``error_K``, ``error_G`` [N/m] (per prediction, for a packing of any preparation:
        leave-one-family-out residuals), ``error_K_in_family``, ``error_G_in_family`` [N/m] (for a
        preparation like the corpus's: leave-one-protocol-out residuals; docs/results/closure.md,
        section 4), ``valid``, ``reason``.
    closure_inputs : ClosureInputs or SectionError
        What the closure was given (Z, r, phi, kt/kn, ...); printed in the JSON's ``closure``
        section after the prediction.
    hierarchy : microhom.hierarchy.HierarchyResult or SectionError
        The relaxation hierarchy (same pre-stress choice as the exact stiffness, 16 multilevel CG
        steps, then up to 4 steps preconditioned by the certificate's factorisation while the
        certified interval is wider than tol): ``hierarchy.K.value``, ``.upper`` (rigorous upper bound), ``.lower`` (rigorous
        lower bound or None), ``.error`` (stated) [N/m], ``order``, ``converged``, ``unstable``,
        ``valid``, ``certified``, ``calibrated``, ``reasons``. On spheres (3D) with the exact
        stiffness's spin arms (its tensor then lies in the rigorous interval); the JSON adds its
        first order ``K_first_order``, ``G_first_order`` (every sphere relaxed alone) [Pa].
    hierarchy_s : float or None
        Wall time of the hierarchy [s] (None when not computed).
    stiffness : dem.analysis.stiffness.StiffnessResult or SectionError
        The exact stiffness: ``K``, ``G``, ``K_affine``, ``G_affine`` [N/m], ``C_mandel``
        (3, 3) [N/m], ``prestress``, ``n_rattlers``, ``n_floppy``, ``n_unstable``, ``n_dof``,
        ``residual``; its wall time is ``assembly_time + solve_time`` [s].
    rho_neighbours : str
        The neighbourhood of the measured rho asked for, ``"near"`` or ``"contacts"`` (the JSON's
        ``structural.rho_neighbours``); ``structural.rho_neighbours`` is the one used, ``"contacts"``
        when no near neighbourhood fits (``structural.rho_note`` says why).
    warnings : SectionWarnings
        What each section's computation warned.
    notes : tuple of str
        The assumptions made (kn, kt, frame, spin arms) and what the reader warned.
    file : FileInfo or None
        What was read and the wall times [s]; None from :func:`analyse` (JSON ``{}``).
    comparison : Comparison
        (property) Each estimate over the exact modulus.
    """

    network: NetworkSummary
    coordination: Coordination | SectionError
    structural: NetworkStatistics | SphereStatistics | SectionError
    stress: StressResult | SectionError
    theory: TheoryResult | SectionError
    closure: ClosurePrediction | SectionError
    closure_inputs: ClosureInputs | SectionError
    hierarchy: HierarchyResult | SectionError
    hierarchy_s: float | None
    stiffness: StiffnessResult | SectionError
    rho_neighbours: str = "near"
    warnings: SectionWarnings = field(default_factory=SectionWarnings)
    notes: tuple = ()
    file: FileInfo | None = None

    @property
    def jammed(self) -> bool:
        """False when no contact is left between non-rattlers (see :data:`NOT_JAMMED`)."""
        return _ok(self.structural) or self.structural.message != NOT_JAMMED

    @property
    def comparison(self) -> Comparison:
        """Each estimate's modulus over the exact one (:class:`Comparison`)."""
        ex, th, cl, hi = self.stiffness, self.theory, self.closure, self.hierarchy
        out = {}
        if _ok(ex):
            exact = {"K": ex.K, "G": ex.G}
            for k in ("K", "G"):
                if exact[k] == 0:
                    continue
                if isinstance(self.structural, SphereStatistics):    # 3D: the Voigt mean field
                    out[f"{k}_mf_over_exact"] = float(getattr(self.structural, f"{k}_affine")) / exact[k]
                if _ok(th):
                    p, pa = th.rho_prediction, th.alpha_prediction
                    est = {"mf": float(getattr(p, f"{k}_mf")), "rho": float(getattr(p, k)),
                           "alpha": float(getattr(pa, k))}
                    for lab in ("mf", "rho", "alpha"):
                        out[f"{k}_{lab}_over_exact"] = est[lab] / exact[k]
                if _ok(cl):
                    out[f"{k}_closure_over_exact"] = float(getattr(cl, k)) / exact[k]
                if _ok(hi):
                    out[f"{k}_hierarchy_over_exact"] = getattr(hi, k).value / exact[k]
        return Comparison(**out)

    def sections(self) -> dict:
        """The JSON sections, in report order (``SECTIONS``), as plain dicts of the typed
        results' values (numpy scalars and NaN kept; ``as_dict()`` makes them JSON-ready)."""
        w = self.warnings

        def warned(view, sec):
            extra = getattr(w, sec)
            return {**view, "warnings": list(extra)} if extra else view

        return {
            "file": {} if self.file is None else _file_view(self.file),
            "network": _network_view(self.network),
            "coordination": warned(_view(self.coordination, _coordination_view), "coordination"),
            "structural": warned(_view(self.structural,
                                       lambda st: _sphere_view(st) if isinstance(st, SphereStatistics)
                                       else _statistics_view(st, self.rho_neighbours)),
                                 "structural"),
            "stress": warned(_view(self.stress, _stress_view), "stress"),
            "theory": warned(_view(self.theory, _theory_view), "theory"),
            "closure": warned(_view(self.closure, lambda p: _closure_view(p, self.closure_inputs)),
                              "closure"),
            "hierarchy": warned(_view(self.hierarchy, lambda h: _hierarchy_view(h, self.hierarchy_s)),
                                "hierarchy"),
            "stiffness": warned(_view(self.stiffness, _stiffness_view), "stiffness"),
            "comparison": _comparison_view(self.comparison),
            "notes": list(self.notes),
        }

    def as_dict(self) -> dict:
        """The command line's JSON: :meth:`sections` as plain Python (NaN/inf -> None)."""
        return {name: to_plain(view) for name, view in self.sections().items()}


# ---- the views: each typed result as its JSON section (the keys the command line has always
# written; a field the view names and the result lacks raises AttributeError) --------------------

def _view(x, view):
    return x.as_dict() if isinstance(x, SectionError) else view(x)


def _file_view(f: FileInfo) -> dict:
    return {k.name: getattr(f, k.name) for k in fields(f)}


def _network_view(n: NetworkSummary) -> dict:
    return {k.name: getattr(n, k.name) for k in fields(n)}


def _coordination_view(c: Coordination) -> dict:
    z = None if isinstance(c.z, float) and math.isnan(c.z) else c.z   # the mean over no particle
    return {"z_all": c.z_all, "z": z, "n_rattlers": c.n_rattlers,
            "rattler_fraction": c.rattler_fraction,
            "hist_all": np.asarray(c.hist_all).tolist(), "hist": np.asarray(c.hist).tolist()}


_STAT_KEYS = ("n_particles", "n_contacts", "nc_all", "nc", "r_all", "r", "rho_all", "rho", "phi",
              "nbar_phi", "diameter", "sliding_fraction", "vbar", "ebar", "vbar_theory",
              "ebar_theory", "odd_norm", "rho_nbar", "rho_note")


def _statistics_view(st: NetworkStatistics, rho_neighbours: str) -> dict:
    out = {k: getattr(st, k) for k in _STAT_KEYS}
    out["rho_neighbours"] = rho_neighbours     # as asked (st.rho_neighbours: as used)
    # r = var/mean^2 and rho = sum V.W / sum V^2 are 0/0 without contacts: None, never 0
    if not out["nc_all"]:
        out["r_all"] = out["rho_all"] = None
    if not out["nc"]:
        out["r"] = out["rho"] = None
    return out


def _sphere_view(st: SphereStatistics) -> dict:
    out = {k.name: getattr(st, k.name) for k in fields(st) if k.name not in ("C_affine", "not_defined")}
    out["C_affine"] = np.asarray(st.C_affine).tolist()
    if not out["nc_all"]:
        out["r_all"] = None
    if not out["nc"]:
        out["r"] = None
    return out


def _stress_view(s: StressResult) -> dict:
    return {k.name: getattr(s, k.name) for k in fields(s)}


def _theory_view(t: TheoryResult) -> dict:
    p, pa = t.rho_prediction, t.alpha_prediction
    return {"K_mf": float(p.K_mf), "G_mf": float(p.G_mf), "K_rho": float(p.K), "G_rho": float(p.G),
            "rho": float(p.rho), "nbar": float(p.nbar), "valid_rho": bool(p.valid),
            "reason_rho": str(p.reason),
            "alpha": float(t.alpha), "K_alpha": float(pa.K), "G_alpha": float(pa.G),
            "rho_alpha": float(pa.rho), "valid_alpha": bool(pa.valid), "reason_alpha": str(pa.reason)}


def _closure_view(p: ClosurePrediction, x: ClosureInputs) -> dict:
    inputs = {k.name: float(getattr(x, k.name)) for k in fields(x) if getattr(x, k.name) is not None}
    return {"K": float(p.K), "G": float(p.G), "error_K": float(p.error_K), "error_G": float(p.error_G),
            "error_K_in_family": float(p.error_K_in_family), "error_G_in_family": float(p.error_G_in_family),
            "valid": bool(p.valid), "reason": str(p.reason), **inputs}


def _hierarchy_view(h: HierarchyResult, time_s) -> dict:
    out = {"K": h.K.value, "G": h.G.value, "K_upper": h.K.upper, "G_upper": h.G.upper,
           "K_lower": h.K.lower, "G_lower": h.G.lower, "K_error": h.K.error, "G_error": h.G.error,
           "order": h.order, "converged": h.converged, "unstable": h.unstable,
           "valid": h.valid, "certified": h.certified, "calibrated": h.calibrated,
           "reasons": list(h.reasons), "time_s": time_s}
    if np.shape(h.C_upper) == (6, 6):      # spheres: the 3D mean field beyond Voigt (2D JSON unchanged)
        out.update(K_first_order=h.K_first_order, G_first_order=h.G_first_order)
    return out


def _stiffness_view(r: StiffnessResult) -> dict:
    return {"K": r.K, "G": r.G, "K_affine": r.K_affine, "G_affine": r.G_affine,
            "C_mandel": np.asarray(r.C_mandel).tolist(), "prestress": r.prestress,
            "n_rattlers": r.n_rattlers, "n_floppy": r.n_floppy, "n_unstable": r.n_unstable,
            "n_dof": r.n_dof, "residual": r.residual, "time_s": r.assembly_time + r.solve_time}


def _comparison_view(c: Comparison) -> dict:
    return {k.name: getattr(c, k.name) for k in fields(c) if getattr(c, k.name) is not None}


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
    LAMMPS run folder (default: the run's). Contacts of a 3D LAMMPS dump or data file are LAMMPS's
    own, centre distance <= r_i + r_j exactly (2D files and other formats: the default tolerance
    of :func:`microhom.network.from_overlaps`, 1e-9 of r_i + r_j).
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
        kw = {}
        if cfg.dim == 3 and format.startswith("lammps"):
            # LAMMPS's own contact test (compute contact/atom, the pair style): d <= r_i + r_j,
            # no tolerance. from_overlaps' default 1e-9 (for exactly touching lattices) would add
            # pairs at a gap below 1e-9 D with no force (7 of 19 641 on 1e4 LAMMPS spheres)
            kw["tolerance"] = 0.0
            notes.append("contacts: centre distance <= r_i + r_j, LAMMPS's own test (compute "
                         "contact/atom), no tolerance")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            net = cfg.network(kn=kn, kt=kt, kn_convention=kn_convention, **kw)
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


#: the sections written for disks, on a 3D network (spheres: docs/spheres.md)
ONLY_2D = ("2D only: the seed paper's theory, its structural sums, the closure and this stress "
           "section are written for disks; this is a 3D network (its statistics, mean field, "
           "hierarchy and exact stiffness are below; docs/spheres.md)")


def _section(fn, *args, **kwargs):
    """``(fn(...), warnings raised)``, or ``(SectionError(reason), ())`` when it fails."""
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = fn(*args, **kwargs)
        return out, tuple(str(w.message) for w in caught)
    except (ValueError, np.linalg.LinAlgError, RuntimeError) as exc:
        return SectionError(str(exc)), ()


def _stress(net) -> StressResult:
    s = stress(net)
    return StressResult(pressure=float(-np.trace(s) / 2), sxx=float(s[0, 0]), syy=float(s[1, 1]),
                        sxy=float(s[0, 1]), p_over_kn=float(-np.trace(s) / 2 / np.mean(net.kn)))


def _theory(net, alpha, min_contacts, rho_neighbours="near") -> TheoryResult:
    p = predict_from_network(net, warn=False, min_contacts=min_contacts, rho_neighbours=rho_neighbours)
    pa = predict_from_network(net, warn=False, measured_rho=False, alpha=alpha, min_contacts=min_contacts)
    a = alpha if alpha is not None else 2.0 * (1.0 - 1.0 / float(pa.nbar))
    return TheoryResult(rho_prediction=p, alpha_prediction=pa, alpha=float(a))


def _closure(net):
    x = ClosureInputs(**closure_inputs(net))   # Z, r, phi, sliding and rattler fractions, dispersity, ...
    kw = {k.name: getattr(x, k.name) for k in fields(x) if getattr(x, k.name) is not None}
    return predict_closure(**kw), x


def _hierarchy(net, prestress, min_contacts, tol=DEFAULT_TOL, spin_arm="contact"):
    t0 = time.perf_counter()
    h = relaxation_hierarchy(net, prestress=prestress, tol=tol, min_contacts=min_contacts,   # max_order="auto"
                             spin_arm=spin_arm)
    return h, time.perf_counter() - t0


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
        default law). :func:`analyse_file` matches it to the file's code. On spheres (3D) the
        hierarchy uses it too, so that the exact tensor lies in its rigorous interval; on disks
        the hierarchy keeps contact arms (the 2D report is unchanged).
    hierarchy_tol : float
        Target relative width of the hierarchy's interval, in (0, 1); default
        :data:`microhom.hierarchy.DEFAULT_TOL` (the library's own default).
    rho_neighbours : str
        The neighbourhood of the measured rho (``microhom.structural_sums.network_statistics``):
        ``"near"`` (default, the paper's N̄ near neighbours) or ``"contacts"``.

    Returns
    -------
    AnalysisResult
        Its ``file`` None. A network without a contact between non-rattlers is not jammed: its
        statistics, theory, closure, hierarchy and stiffness hold ``SectionError(NOT_JAMMED)``
        instead of 0/0 values, and its coordination's ``z`` is NaN.
    """
    notes = []
    network = NetworkSummary(n_particles=net.n_particles, n_contacts=net.n_contacts,
                             periodic=net.cell is not None,
                             kn_mean=float(np.mean(net.kn)) if net.n_contacts else None,
                             kt_mean=float(np.mean(net.kt)) if net.n_contacts else None,
                             forces=net.fn is not None)
    w = {}
    coord, w["coordination"] = _section(coordination, net, min_contacts)
    jammed = not _ok(coord) or coord.n_rattlers < net.n_particles
    if not jammed:
        coord = replace(coord, z=float("nan"))   # the mean over no particle
    not_jammed = SectionError(NOT_JAMMED)
    disks = net.dim == 2
    if not jammed:
        structural = not_jammed
    elif not disks:      # spheres: the 3D statistics and the Voigt mean field (docs/spheres.md)
        structural, w["structural"] = _section(sphere_statistics, net, min_contacts)
    else:
        structural, w["structural"] = _section(network_statistics, net, min_contacts,
                                               rho_neighbours=rho_neighbours)
    if not disks:
        stress_ = SectionError(ONLY_2D)
    elif net.fn is not None and net.n_contacts:
        stress_, w["stress"] = _section(_stress, net)
    else:
        stress_ = SectionError("no contact forces in the file" if net.fn is None else "no contacts")
    theory = not_jammed if disks else SectionError(ONLY_2D)
    if jammed and disks:
        theory, w["theory"] = _section(_theory, net, alpha, min_contacts, rho_neighbours)
    if not disks:
        closure = closure_in = SectionError(ONLY_2D)
    elif jammed and _ok(structural):
        cl, w["closure"] = _section(_closure, net)
        closure, closure_in = cl if _ok(cl) else (cl, cl)
    else:
        closure = closure_in = structural if not _ok(structural) else not_jammed
    snet = net
    if prestress and net.fn is None and (exact or hierarchy):
        snet = replace(net, fn=_elastic_normal_forces(net))
        notes.append("--prestress: the file has no contact forces; fn = kn * overlap (linear law)")
    hier_s = None
    if not hierarchy:
        hier = SectionError("not computed")
    elif not jammed:
        hier = not_jammed
    elif net.cell is None:
        hier = SectionError("open packing: the hierarchy estimates the stiffness of a periodic cell")
    else:
        # the exact solver's spin arms (disks and spheres), so that its tensor is the one the
        # interval bounds (issue 26: the 2D report had kept contact arms on LAMMPS files)
        h, w["hierarchy"] = _section(_hierarchy, snet, prestress, min_contacts, hierarchy_tol,
                                     spin_arm)
        hier, hier_s = h if _ok(h) else (h, None)
    if not exact:
        stiff = SectionError("not computed")
    elif not jammed:
        stiff = not_jammed
    else:
        stiff, w["stiffness"] = _section(stiffness, snet, prestress=prestress,
                                         min_contacts=min_contacts, spin_arm=spin_arm)
    if not jammed:
        notes.append(NOT_JAMMED)
    if disks and net.n_particles and net.radii.max() > DISPERSITY_NOTE * net.radii.min():
        notes.append(f"the radii differ (max/min = {net.radii.max() / net.radii.min():.3g}, "
                     f"relative spread {np.std(net.radii) / np.mean(net.radii):.3g}): the theory "
                     "is for identical disks, its moduli are a reference for this packing")
    return AnalysisResult(network=network, coordination=coord, structural=structural,
                          stress=stress_, theory=theory, closure=closure, closure_inputs=closure_in,
                          hierarchy=hier, hierarchy_s=hier_s, stiffness=stiff,
                          rho_neighbours=rho_neighbours,
                          warnings=SectionWarnings(**w), notes=tuple(notes))


#: the check of each option: (allowed range as text, test of a value that is not None); the
#: fields that may be None say so in their text
_OPTION_RULES = {
    "format": ("None or one of " + ", ".join(FORMATS), lambda v: v in FORMATS),
    "kn": ("finite and > 0", lambda v: _finite_real(v) and v > 0),
    "kt": ("finite and >= 0", lambda v: _finite_real(v) and v >= 0),
    "kt_ratio": ("finite and >= 0", lambda v: _finite_real(v) and v >= 0),
    "kn_convention": ("None, 'standard' or 'oval'", lambda v: v in ("standard", "oval")),
    "branch_length": ("'distance' or 'radii'", lambda v: v in ("distance", "radii")),
    "alpha": ("in [0, 2]", lambda v: real(v) and 0 <= v <= 2),
    "prestress": ("True or False", _flag),
    "min_contacts": ("an integer >= 1", lambda v: _integer(v) and v >= 1),
    "frame": ("an integer (0 the first frame, -1 the last)", _integer),
    "radius": ("finite and > 0", lambda v: _finite_real(v) and v > 0),
    "exact": ("True or False", _flag),
    "hierarchy": ("True or False", _flag),
    "spin_arm": ("None, 'contact' or 'radius'", lambda v: v in ("contact", "radius")),
    "hierarchy_tol": ("a relative width in (0, 1)", lambda v: real(v) and 0 < v < 1),
    "rho_neighbours": ("'near' or 'contacts'", lambda v: v in ("near", "contacts")),
}
#: the options that may be None (meaning: from the file, or the documented default)
_OPTIONAL = ("format", "kn", "kt", "kt_ratio", "kn_convention", "alpha", "min_contacts", "radius",
             "spin_arm")


@dataclass(frozen=True)
class AnalysisOptions(Result):
    """How :func:`analyse_file` reads and analyses a file: frozen, validated when made.

    A value outside its range raises :class:`OptionError` (a ``ValueError``) naming the field and
    its range; ``python -m dem analyse`` builds one from its options (``--kt-ratio`` is
    ``kt_ratio``; its ``--frame`` counts from 1, this ``frame`` from 0). Variants:
    ``options.replace(kn=2.0)``; ``as_dict()`` records them.

    Attributes
    ----------
    format : str or None
        One of ``FORMATS``; None: from the name/extension (a folder: ``"lammps-run"``).
    kn : float or None
        Normal contact stiffness [N/m] (force per unit overlap) for files without a contact law,
        > 0; None: 1 (moduli in units of kn, said in the notes).
    kt : float or None
        Tangential stiffness [N/m], >= 0; None: ``kt = kn`` (said in the notes) unless
        ``kt_ratio`` is given.
    kt_ratio : float or None
        ``kt = kt_ratio * kn``, >= 0 (LAMMPS ``gran/hooke/history``'s default is 2/7); not with
        ``kt``.
    kn_convention : str or None
        ``"oval"``: ``kn`` is OVAL's, which multiplies half the overlap (the network gets kn/2);
        None or ``"standard"``: force per unit overlap (:meth:`dem.io.Configuration.network`).
    branch_length : str
        ``"distance"`` (centre distance, default) or ``"radii"`` (direction kept, length
        ``r_i + r_j``: the paper's ``|c| = D``).
    alpha : float or None
        Alignment width of the model-rho prediction (eq. 54), in [0, 2]; None: ``2 (1 - 1/Nbar)``.
    prestress : bool
        Exact stiffness and hierarchy with the pre-stress terms (the file's normal forces, else
        ``kn * overlap``).
    min_contacts : int or None
        Rattler threshold, >= 1; None: 2 with friction, 3 without.
    frame : int
        Frame of a LAMMPS dump, 0-based, negative from the end (default -1, the last).
    radius : float or None
        Constant radius [m] for LAMMPS dumps without a radius or diameter column, > 0.
    exact : bool
        Compute the exact stiffness (one sparse factorisation).
    hierarchy : bool
        Compute the relaxation hierarchy (:mod:`microhom.hierarchy`).
    spin_arm : str or None
        Spin kinematics of the exact stiffness, ``"contact"`` or ``"radius"``; None: matched to
        the file's code (:func:`analyse_file`).
    hierarchy_tol : float
        Target relative width of the hierarchy's interval, in (0, 1); default
        :data:`microhom.hierarchy.DEFAULT_TOL`.
    rho_neighbours : str
        Neighbourhood of the measured rho, ``"near"`` (the paper's Nbar near neighbours, eq. 39)
        or ``"contacts"``.
    """

    format: str | None = None
    kn: float | None = None
    kt: float | None = None
    kt_ratio: float | None = None
    kn_convention: str | None = None
    branch_length: str = "distance"
    alpha: float | None = None
    prestress: bool = False
    min_contacts: int | None = None
    frame: int = -1
    radius: float | None = None
    exact: bool = True
    hierarchy: bool = True
    spin_arm: str | None = None
    hierarchy_tol: float = DEFAULT_TOL
    rho_neighbours: str = "near"

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name in _OPTIONAL:
                continue
            allowed, ok = _OPTION_RULES[f.name]
            if v is None or not ok(v):
                raise OptionError(f.name, allowed, v)
        if self.kt is not None and self.kt_ratio is not None:
            raise OptionError("kt_ratio", "None when kt is given (kt or kt_ratio, not both)",
                              self.kt_ratio)

    @classmethod
    def names(cls) -> tuple:
        """The option names, in order."""
        return tuple(f.name for f in fields(cls))

    def replace(self, **changes) -> "AnalysisOptions":
        """A copy with ``changes`` (validated again); a TypeError names an unknown option."""
        unknown = sorted(set(changes) - set(self.names()))
        if unknown:
            raise TypeError(f"unknown analysis option {unknown[0]!r}; the options are "
                            f"{', '.join(self.names())}")
        return replace(self, **changes)


def analyse_file(path, options=None, **overrides) -> AnalysisResult:
    """:func:`load_network` then :func:`analyse` of the file (or LAMMPS run folder) ``path``, with
    the :class:`AnalysisOptions` ``options`` (None: the defaults) and any of its fields given as
    keywords (``analyse_file(path, kn=2.0, format="oval")``, or ``analyse_file(path, opts,
    hierarchy=False)``: the keywords replace the options' values). The result's ``file``
    (:class:`FileInfo`) says what was read and how long it took, its notes start with the
    assumptions made while reading.

    ``spin_arm=None`` (default) matches the exact stiffness's spin kinematics to the file's code:
    ``"radius"`` for LAMMPS files and run folders (``gran/*`` turns spins about the radius),
    ``"contact"`` otherwise (the kinematics of the theory and of the hierarchy, whose bounds hold
    for it; ``dem.engine.packing`` files too, although the engine's default law turns spins about the
    radius); the notes say which was used. Give ``"contact"`` or ``"radius"`` to choose."""
    o = _analysis_options(options, overrides)
    t0 = time.perf_counter()
    net, info = load_network(path, o.format, kn=o.kn, kt=o.kt, kt_ratio=o.kt_ratio,
                             kn_convention=o.kn_convention, branch_length=o.branch_length,
                             frame=o.frame, radius=o.radius)
    t1 = time.perf_counter()
    file_arm = info["spin_arm"]
    spin_arm = o.spin_arm
    if spin_arm is None:
        spin_arm = file_arm
        why = "matched to the file's code" if file_arm == "radius" else "the exact solver's default"
    else:
        why = "as asked" + ("" if spin_arm == file_arm else f"; the file's code uses {file_arm!r}")
    notes = list(info["notes"])
    if o.exact:
        notes.append(
            f"spin arms of the exact stiffness: {spin_arm!r} ({why}; "
            + ("the radius r_i, as LAMMPS gran/*" if spin_arm == "radius" else
               "the distance to the contact point |c| r_i/(r_i + r_j)")
            + "; --spin-arm contact|radius chooses; "
            + ("the hierarchy uses the same arms)" if net.dim == 3 else
               "the hierarchy uses the same arms, the theory contact arms)"))
    res = analyse(net, alpha=o.alpha, prestress=o.prestress, min_contacts=o.min_contacts,
                  exact=o.exact, hierarchy=o.hierarchy, spin_arm=spin_arm,
                  hierarchy_tol=o.hierarchy_tol, rho_neighbours=o.rho_neighbours)
    file = FileInfo(source=info["source"], format=info["format"], forces=info["forces"],
                    kn=info["kn"], kt=info["kt"], branch_length=info["branch_length"],
                    spin_arm=spin_arm, read_s=t1 - t0, analyse_s=time.perf_counter() - t1)
    return replace(res, file=file, notes=tuple(notes) + res.notes)


def _analysis_options(options, overrides) -> AnalysisOptions:
    """The options of :func:`analyse_file`: ``options`` (None: the defaults) with ``overrides``."""
    if options is None:
        options = AnalysisOptions()
    elif not isinstance(options, AnalysisOptions):
        hint = (f"; give the format as format={options!r}" if isinstance(options, str) else "")
        raise TypeError(f"analyse_file's second argument is an AnalysisOptions or None, got "
                        f"{type(options).__name__}{hint}")
    return options.replace(**overrides) if overrides else options


def flatten(res) -> dict:
    """One flat record ``section.key -> scalar`` (lists joined with spaces), for CSV/JSON rows;
    ``res`` an :class:`AnalysisResult` (or its :meth:`~AnalysisResult.sections`)."""
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


def _spheres(res: AnalysisResult) -> bool:
    """True when the report is of a sphere network (3D)."""
    if isinstance(res.structural, SphereStatistics):
        return True
    for sec, key in ((res.stiffness, "C_mandel"), (res.hierarchy, "C_upper")):
        if _ok(sec):
            return np.shape(getattr(sec, key)) == (6, 6)
    return _ok(res.theory) is False and res.theory.message == ONLY_2D


def _coordination_lines(res: AnalysisResult) -> list:
    c, s = res.coordination, res.structural
    L = ["", "coordination"]
    if not _ok(c):
        L.append(f"  n/a: {c.message}")
        return L
    L.append(f"  {'':28}{'all particles':>16}{'no rattlers':>16}")
    L.append(f"  {'mean Z':28}{_g(c.z_all, '.5f'):>16}{_g(c.z, '.5f'):>16}")
    if _ok(s):
        L.append(f"  {'r = var(Z)/Z^2':28}{_g(s.r_all, '.5f'):>16}{_g(s.r, '.5f'):>16}")
    if _ok(s) and not isinstance(s, SphereStatistics):
        hood = ("V over contacts" if res.rho_neighbours == "contacts"
                else f"V over Nbar = {_g(s.rho_nbar, '.3g')}")
        L.append(f"  {'rho (' + hood + ')':28}{_g(s.rho_all, '.5f'):>16}{_g(s.rho, '.5f'):>16}")
        if s.rho_note:
            L.append(f"  rho: {s.rho_note}")
    L.append(f"  rattlers: {c.n_rattlers} ({100 * c.rattler_fraction:.2f} %); "
             f"contact-count histogram (0, 1, 2, ...): {np.asarray(c.hist_all).tolist()}")
    return L


def _structural_lines(res: AnalysisResult) -> list:
    s = res.structural
    if isinstance(s, SphereStatistics):
        return ["", "statistics (3D, docs/spheres.md)",
                f"  phi = {_g(s.phi, '.5f')}, mean D = {_g(s.diameter, '.5g')}, sliding fraction = "
                f"{_g(s.sliding_fraction, '.4f')}, rattlers {s.n_rattlers} (fewer than 2 contacts "
                "with friction, 4 without)",
                "  mean field: affine (Voigt) moduli of the fabric, K = sum kn l^2/(9V), "
                "G = sum (2kn + 3kt) l^2/(30V)"]
    L = ["", "structural sums (mean A4 over non-rattlers, isotropic fit) vs (37)"]
    if not _ok(s):
        L.append(f"  n/a: {s.message}")
        return L
    L.append(f"  {'':10}{'measured':>14}{'(37)':>14}{'ratio':>10}")
    for k, m, t in (("vbar", s.vbar, s.vbar_theory), ("ebar", s.ebar, s.ebar_theory)):
        ratio = (m / t) if (m is not None and t) else None
        L.append(f"  {k + ' [N m]':10}{_g(m):>14}{_g(t):>14}{_g(ratio, '.4f'):>10}")
    L.append(f"  phi = {_g(s.phi, '.5f')}, Nbar(phi) = {_g(s.nbar_phi, '.4f')}, "
             f"mean D = {_g(s.diameter, '.5g')}, sliding fraction = {_g(s.sliding_fraction, '.4f')}, "
             f"odd-sum norm |A3|/(kn D) = {_g(s.odd_norm, '.4g')}")
    return L


def _ratios(cmp, lab):
    return (f"{_g(getattr(cmp, f'K_{lab}_over_exact'), '.4f'):>10}"
            f"{_g(getattr(cmp, f'G_{lab}_over_exact'), '.4f'):>10}")


def _flag(p):
    return "" if bool(p.valid) else "  FLAGGED: " + str(p.reason)


def _estimate_lines(res: AnalysisResult, spheres: bool) -> list:
    """The mean field and the theory's rows (2D), or the Voigt mean field and the hierarchy's
    first order (3D); then the closure's."""
    th, cmp, st, hi = res.theory, res.comparison, res.structural, res.hierarchy
    L = []
    if spheres:
        if isinstance(st, SphereStatistics):
            L.append(f"  {'mean field (Voigt, fabric)':44}{_g(st.K_affine):>14}{_g(st.G_affine):>14}"
                     f"{_ratios(cmp, 'mf')}")
        else:
            L.append(f"  mean field: n/a ({st.message})")
        if _ok(hi):
            ex = res.stiffness
            rk = [hi.K_first_order / ex.K if _ok(ex) and ex.K else None,
                  hi.G_first_order / ex.G if _ok(ex) and ex.G else None]
            L.append(f"  {'hierarchy first order (spheres relaxed alone)':44}{_g(hi.K_first_order):>14}"
                     f"{_g(hi.G_first_order):>14}{_g(rk[0], '.4f'):>10}{_g(rk[1], '.4f'):>10}")
    elif not _ok(th):
        L.append(f"  theory: n/a ({th.message})")
    else:
        p, pa = th.rho_prediction, th.alpha_prediction
        rows = [("mean field (37)", "mf", float(p.K_mf), float(p.G_mf), ""),
                (f"corrected, measured rho = {float(p.rho):.4f}", "rho", float(p.K), float(p.G), _flag(p)),
                (f"corrected, alpha = {th.alpha:.4g} (rho = {float(pa.rho):.4f})", "alpha",
                 float(pa.K), float(pa.G), _flag(pa))]
        for name, lab, K, G, fl in rows:
            L.append(f"  {name:44}{_g(K):>14}{_g(G):>14}{_ratios(cmp, lab)}{fl}")
    cl = res.closure
    if _ok(cl):
        L.append(f"  {'closure (statistics only)':44}{_g(float(cl.K)):>14}{_g(float(cl.G)):>14}"
                 f"{_ratios(cmp, 'closure')}{_flag(cl)}")
        L.append(f"  {'  stated error (any preparation)':44}{_g(float(cl.error_K), '.3g'):>14}"
                 f"{_g(float(cl.error_G), '.3g'):>14}")
        L.append(f"  {'  stated error (preparation like the corpus)':44}"
                 f"{_g(float(cl.error_K_in_family), '.3g'):>14}{_g(float(cl.error_G_in_family), '.3g'):>14}")
    elif not spheres:
        L.append(f"  closure: n/a ({cl.message})")
    return L


def _containment(res: AnalysisResult) -> str:
    """Whether the exact K and G lie in the hierarchy's rigorous interval (3D report)."""
    hi, ex = res.hierarchy, res.stiffness
    out = []
    for k in ("K", "G"):
        e, v = getattr(hi, k), getattr(ex, k)
        if e.lower is None:
            out.append(f"{k} {'<=' if v <= e.upper else 'ABOVE'} upper bound (no certified lower bound)")
        else:
            out.append(f"{k} {'yes' if e.lower <= v <= e.upper else 'NO'}")
    return "  exact inside the hierarchy's interval: " + ", ".join(out)


def _hierarchy_exact_lines(res: AnalysisResult, spheres: bool) -> list:
    hi, ex, cmp = res.hierarchy, res.stiffness, res.comparison
    L = []
    if _ok(hi):
        fl = "" if hi.valid else "  FLAGGED: not valid (see notes)"
        L.append(f"  {'hierarchy (%d CG steps), value' % hi.order:44}{_g(hi.K.value):>14}{_g(hi.G.value):>14}"
                 f"{_ratios(cmp, 'hierarchy')}{fl}")
        L.append(f"  {'  rigorous upper bound':44}{_g(hi.K.upper):>14}{_g(hi.G.upper):>14}")
        L.append(f"  {'  rigorous lower bound':44}{_g(hi.K.lower):>14}{_g(hi.G.lower):>14}")
        L.append(f"  {'  stated error':44}{_g(hi.K.error, '.3g'):>14}{_g(hi.G.error, '.3g'):>14}"
                 f"  ({'converged' if hi.converged else 'tolerance not met'}"
                 f"{', UNSTABLE' if hi.unstable else ''}, {res.hierarchy_s:.3f} s)")
    else:
        L.append(f"  hierarchy: n/a ({hi.message})")
    if not _ok(ex):
        L.append(f"  exact: n/a ({ex.message})")
        return L
    L.append(f"  {'affine (dem.analysis.stiffness)':44}{_g(ex.K_affine):>14}{_g(ex.G_affine):>14}")
    L.append(f"  {'exact' + (' with prestress' if ex.prestress else '') + ' (dem.analysis.stiffness)':44}"
             f"{_g(ex.K):>14}{_g(ex.G):>14}")
    if spheres and _ok(hi):
        L.append(_containment(res))
    L.append("  exact C (Mandel [xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy]):" if spheres
             else "  exact C (Mandel [xx, yy, sqrt2 xy]):")
    for row in np.asarray(ex.C_mandel).tolist():
        L.append("    " + "".join(f"{v:>14.6g}" for v in row))
    L.append(f"  rattlers removed {ex.n_rattlers}, floppy modes {ex.n_floppy}, dof {ex.n_dof}, "
             f"residual {ex.residual:.1e}, solve {ex.assembly_time + ex.solve_time:.3f} s")
    return L


def format_table(res: AnalysisResult) -> str:
    """The readable report of :func:`analyse_file` (an :class:`AnalysisResult`), read from its
    typed results. On a sphere network (3D) the moduli section has the Voigt mean field, the
    hierarchy's first order and interval, the exact tensor and whether the exact K and G lie in the
    interval."""
    if not isinstance(res, AnalysisResult):
        raise TypeError(f"format_table needs an AnalysisResult, got {type(res).__name__}")
    L = []
    f, nw = res.file, res.network
    src, fmt = (f.source, f.format) if f is not None else ("?", "?")
    read_s, analyse_s = (f.read_s, f.analyse_s) if f is not None else (None, None)
    L.append(f"file: {src}  (format {fmt}, read in {_g(read_s, '.3f')} s, "
             f"analysed in {_g(analyse_s, '.3f')} s)")
    L.append(f"network: N = {nw.n_particles}, contacts = {nw.n_contacts}, "
             f"{'periodic' if nw.periodic else 'open'}, kn = {_g(nw.kn_mean)}, kt = {_g(nw.kt_mean)}, "
             f"branch = {f.branch_length if f is not None else 'distance'}, "
             f"forces: {'yes' if nw.forces else 'no'}")
    L += _coordination_lines(res)
    L += _structural_lines(res)
    st = res.stress
    L.append("")
    if not _ok(st):
        L.append(f"stress: n/a ({st.message})")
    else:
        L.append(f"stress (Love-Weber, tension positive, force/length): sxx = {_g(st.sxx)}, "
                 f"syy = {_g(st.syy)}, sxy = {_g(st.sxy)}; pressure = {_g(st.pressure)} "
                 f"(p/kn = {_g(st.p_over_kn, '.4g')})")
    L.append("")
    spheres = _spheres(res)
    if spheres:
        L.append("moduli (3D, force/area)")
        L.append(f"  {'estimate':44}{'K [Pa]':>14}{'G [Pa]':>14}{'K/exact':>10}{'G/exact':>10}")
    else:
        L.append("moduli (2D, force/length)")
        L.append(f"  {'estimate':44}{'K [N/m]':>14}{'G [N/m]':>14}{'K/exact':>10}{'G/exact':>10}")
    L += _estimate_lines(res, spheres)
    L += _hierarchy_exact_lines(res, spheres)
    notes = list(res.notes)
    for sec in ("coordination", "structural", "stress", "theory", "closure", "hierarchy", "stiffness"):
        notes += [f"{sec}: {w}" for w in getattr(res.warnings, sec)]
    hi = res.hierarchy
    notes += [f"hierarchy: {r}" for r in hi.reasons] if _ok(hi) else []
    if notes:
        L.append("")
        L.append("notes:")
        L += [f"  - {n}" for n in notes]
    return "\n".join(L)
