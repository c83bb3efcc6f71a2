"""Numeric predictions of the 2D incremental bulk and shear moduli: fast, vectorised, stable.

The formulas are derived in :mod:`microhom.symbolic` and checked against these functions by
``python -m microhom.derivations`` (check ``numeric_matches_symbolic``). For identical disks of
diameter D with constant contact stiffnesses kn, kt [N/m] (2D moduli are in N/m too):

* mean field (37):     ``K_mf = Nc phi kn / (2 pi)``,  ``G_mf = Nc phi (kn + kt) / (4 pi)``
* corrected (50)-(51): ``K = K_mf [1 - 4 kn/(3kn + kt) * x]``,
  ``G = G_mf [1 - 2 (2kn + kt)/(3kn + kt) * x]``, with ``x = r (Nbar/Nc) rho``
* ``rho = Nc sum V.W / sum V^2``, modelled (54) as ``cos(pi alpha/2)/(1 - alpha^2)``
* ``Nbar`` from ``phi = (pi/4)/sin(pi (Nbar-2)/Nbar)`` (branch Nbar >= 4, needs phi >= pi/4)

Everything broadcasts over numpy arrays and pandas Series. ``predict_moduli`` needs numpy only;
``predict_from_network`` also measures the network (``microhom.structural_sums``) and checks the
prediction against the rigorous upper bounds of the relaxation hierarchy (``microhom.hierarchy``).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, fields, replace

import numpy as np

from .hierarchy import relaxation_hierarchy
from .limits import as_float_array, check_broadcast
from .neighbourhood import PHI_MAX, PHI_MIN_NBAR, nbar_from_phi
from .network import ContactNetwork
from .structural_sums import network_statistics
from .results import Result

#: Above this kt/kn a prediction is flagged with bit 128. The DEM of this project packs with kt
#: in [0, 10 kn] (``python -m dem pack --kt``); beyond that the theory has no check.
KT_OVER_KN_MAX = 10.0

__all__ = ["predict_moduli", "predict_from_network", "Prediction", "rho_from_alpha", "nbar_from_phi", "KT_OVER_KN_MAX",
           "PHI_MAX", "PHI_MIN_NBAR"]

_REASONS = (
    (1, "correction exceeds the mean field (negative modulus): first-order theory invalid"),
    (2, "first-order correction (softening or stiffening) larger than max_correction of the mean field: "
        "outside the theory's range"),
    (4, "phi above close packing pi/(2 sqrt 3) (overlaps inflate it): Nbar and the mean field taken "
        "at close packing"),
    (8, "near isostatic (Z - Z_iso < 0.5 on the load-bearing particles): the shear modulus vanishes "
        "at isostaticity and the first-order theory cannot follow"),
    (16, "prediction above the rigorous upper bound of the relaxation hierarchy: provably too stiff"),
    (32, "overflow: a modulus exceeds the float64 range (about 1.8e308): the inputs (kn, kt, nc) are "
         "too large; rescale the stiffnesses (the moduli are proportional to kn)"),
    (64, "underflow: a modulus below float64's normal range (2.2e-308) has lost digits: rescale the "
         "stiffnesses (the moduli are proportional to kn)"),
    (128, f"kt/kn above {KT_OVER_KN_MAX:g}: outside the range the theory was checked against (the "
          f"DEM packs with kt in [0, {KT_OVER_KN_MAX:g} kn])"),
    (256, "phi below pi/4: Nbar(phi) does not exist; Nbar = 4 (its value at phi = pi/4) used for Nbar/Nc "
         "(and for the near neighbourhood of a measured rho); pass nbar to choose"),
)
_N_CODES = 1 << len(_REASONS)
#: Bytes :func:`predict_moduli` allocates per entry of the broadcast shape (its 15 output arrays
#: and temporaries, float64): the memory guard's estimate (see :func:`microhom.limits.check_broadcast`).
BYTES_PER_PREDICTION = 8 * 32


def _check(name, x, lo=None, hi=None, lo_open=False, hi_open=False, unit=""):
    """Array of float64, finite, in the allowed range; else ValueError naming the parameter (also
    for text, ``None`` and other non-numbers)."""
    a = as_float_array(name, x, unit=f" [{unit.strip()}]" if unit else "")
    bad = ~np.isfinite(a)
    rng = f"{'(' if lo_open else '['}{'-inf' if lo is None else f'{lo:.6g}'}, " \
          f"{'inf' if hi is None else f'{hi:.6g}'}{')' if hi_open or hi is None else ']'}"
    if lo is not None:
        bad |= (a <= lo) if lo_open else (a < lo)
    if hi is not None:
        bad |= (a >= hi) if hi_open else (a > hi)
    if np.any(bad):
        first = np.flatnonzero(np.broadcast_to(bad, a.shape).ravel())[0]
        val = float(a.ravel()[first])
        where = f" (first at flat index {first})" if a.ndim else ""
        raise ValueError(f"{name} must be finite and in {rng}{unit}; got {val!r}{where}")
    return a


def rho_from_alpha(alpha):
    """rho(alpha) = cos(pi alpha/2)/(1 - alpha^2) (54), evaluated without the 0/0 at alpha = 1.

    Written as ``(pi/2) sinc((1 - alpha)/2) / (1 + alpha)`` (numpy's normalised sinc), which is the
    same function (sympy check ``alignment_model``) and equals pi/4 at alpha = 1.
    alpha: the alignment width, in [0, 2]. Returns rho in [1/3, 1].
    """
    a = _check("alpha", alpha, 0.0, 2.0)
    return 0.5 * np.pi * np.sinc(0.5 * (1.0 - a)) / (1.0 + a)


@dataclass(frozen=True, eq=False)
class Prediction(Result):
    """Result of :func:`predict_moduli` (read-only); every field is an array of the broadcast input
    shape.

    Moduli in the unit of kn (N/m for 2D disks per unit thickness).

    Attributes
    ----------
    K_mf, G_mf : ndarray
        Mean-field (37) bulk and shear moduli [N/m].
    K, G : ndarray
        Fluctuation-corrected (50)-(51) bulk and shear moduli [N/m].
    drop_K, drop_G : ndarray
        Fraction change ``1 - modulus/mean field`` (the seed table's "fraction change") [-].
    delta_mf, delta : ndarray
        Biaxial volume-change ratio ``(G - K)/(G + K)``, mean field and corrected [-].
    poisson_mf, poisson : ndarray
        2D Poisson ratio ``(K - G)/(K + G)``, mean field and corrected [-].
    nbar : ndarray
        Mean number of near neighbours Nbar used [-].
    rho : ndarray
        Correlation factor ``Nc sum V.W / sum V^2`` used [-].
    valid : ndarray of bool
        False where the first-order theory is out of range.
    flags : ndarray of int16
        Bit mask of the reasons (1 correction >= 1, 2 correction above ``max_correction``,
        4 phi above close packing, 8 near-isostatic, 16 above the hierarchy's upper bound,
        32 overflow (a modulus beyond float64's range), 64 underflow (a modulus below float64's
        normal range, digits lost), 128 kt/kn above :data:`KT_OVER_KN_MAX`,
        256 phi below pi/4 with no ``nbar`` given: N̄ = 4 used).
    index : pandas Index or None
        Index of the inputs when they were pandas Series, else None.
    reason : ndarray of str
        Why a result is flagged, per parameter set (``"ok"`` where valid; property).
    """

    K_mf: np.ndarray
    G_mf: np.ndarray
    K: np.ndarray
    G: np.ndarray
    drop_K: np.ndarray
    drop_G: np.ndarray
    delta_mf: np.ndarray
    delta: np.ndarray
    poisson_mf: np.ndarray
    poisson: np.ndarray
    nbar: np.ndarray
    rho: np.ndarray
    valid: np.ndarray
    flags: np.ndarray  # bit mask of _REASONS
    index: object = None  # pandas index of the inputs, if any

    @property
    def reason(self) -> np.ndarray:
        """Why a result is flagged, as text per parameter set ("ok" where valid)."""
        texts = ["; ".join(t for bit, t in _REASONS if code & bit) or "ok" for code in range(_N_CODES)]
        return np.asarray(np.asarray(texts, dtype=object)[np.asarray(self.flags)], dtype=object)

    def to_frame(self):
        """A pandas DataFrame with one column per field (pandas imported only here)."""
        import pandas as pd

        cols = {f.name: np.ravel(getattr(self, f.name)) for f in fields(self) if f.name not in ("flags", "index")}
        cols["reason"] = np.ravel(self.reason)
        return pd.DataFrame(cols, index=self.index)

    def as_dict(self):
        """Plain Python scalars (for one parameter set) or lists, e.g. for JSON."""
        out = {}
        for f in fields(self):
            if f.name in ("flags", "index"):
                continue
            a = np.asarray(getattr(self, f.name))
            out[f.name] = a.item() if a.ndim == 0 else a.tolist()
        r = self.reason
        out["reason"] = r.item() if r.ndim == 0 else r.tolist()
        return out


def predict_moduli(kn, kt, nc, phi, r, alpha=None, rho=None, diameter=1.0, nbar=None,
                   max_correction=0.5, warn=True) -> Prediction:
    """Mean-field and fluctuation-corrected 2D bulk and shear moduli of a random disk packing.

    All array arguments broadcast together (numpy arrays or pandas Series).

    Parameters
    ----------
    kn : array_like
        Normal contact stiffness [N/m], > 0.
    kt : array_like
        Tangential contact stiffness [N/m], >= 0 (0 = all contacts sliding/frictionless).
    nc : array_like
        Mean coordination number Nc (contacts per particle), > 0.
    phi : array_like
        Solid (area) fraction, in (0, pi/(2 sqrt 3)].
    r : array_like
        Contact-number fluctuation mean((Nc_mu - Nc)^2)/Nc^2, >= 0; r = 0 gives the mean field.
    alpha : array_like, optional
        Alignment width of the paper's model (54), in [0, 2]. Used when ``rho`` is None;
        if both are None, the paper's estimate ``alpha = 2 (1 - 1/Nbar)`` is used.
    rho : array_like, optional
        Measured ``Nc sum V.W / sum V^2`` (overrides ``alpha``), finite.
    diameter : float
        Particle diameter [m], > 0. The 2D moduli do not depend on it (they scale with
        D^2/v = 4 phi/pi); it is validated and kept for symmetry with the 3D theory.
    nbar : array_like, optional
        Mean number of near neighbours, > 2; default from ``phi``. Below phi = pi/4, where
        N̄(phi) does not exist, the default is N̄ = 4 (its value at pi/4) and the result is
        flagged (bit 256, ``reason`` names the substitute).
    max_correction : float
        Fraction change above which a result is flagged as outside the first-order
        range, in (0, 1] (default 0.5).
    warn : bool
        Emit a RuntimeWarning when any result is flagged invalid.

    Returns
    -------
    Prediction
        Moduli [N/m] of the broadcast shape. Reproduces the seed's table: Nc = 4.1, r = 0.35, Nbar = 5, alpha = 1.76, kt = kn
    gives fraction changes 0.19 (bulk) and 0.28 (shear).
    """
    index = next((a.index for a in (kn, kt, nc, phi, r, alpha, rho, nbar)
                  if type(a).__module__.startswith("pandas") and hasattr(a, "index")), None)
    kn = _check("kn", kn, 0.0, lo_open=True, unit=" N/m")
    kt = _check("kt", kt, 0.0, unit=" N/m")
    nc = _check("nc", nc, 0.0, lo_open=True)
    phi = _check("phi", phi, 0.0, PHI_MAX * (1 + 1e-12), lo_open=True)
    r = _check("r", r, 0.0)
    _check("diameter", diameter, 0.0, lo_open=True, unit=" m")
    _check("max_correction", max_correction, 0.0, 1.0, lo_open=True)
    named = {"kn": kn, "kt": kt, "nc": nc, "phi": phi, "r": r}
    for name, v in (("alpha", alpha), ("rho", rho), ("nbar", nbar)):
        if v is not None:
            named[name] = _check(name, v) if name != "alpha" else as_float_array(name, v)
    check_broadcast(named, bytes_per_element=BYTES_PER_PREDICTION, what="predict_moduli's result")
    loose = np.zeros(np.shape(phi), dtype=bool)
    if nbar is None:   # below pi/4 N̄(phi) does not exist: N̄ = 4, flagged (bit 256) with its reason
        loose = phi < PHI_MIN_NBAR * (1 - 1e-12)
        nbar = np.where(loose, 4.0, nbar_from_phi(np.maximum(phi, PHI_MIN_NBAR)))
    else:
        nbar = _check("nbar", nbar, 2.0, lo_open=True)
    if rho is None:
        if alpha is None:
            alpha = 2.0 * (1.0 - 1.0 / nbar)
        rho = rho_from_alpha(alpha)
    else:
        if alpha is not None:
            raise ValueError("give either alpha (the paper's model) or rho (measured), not both")
        rho = _check("rho", rho)

    with np.errstate(over="ignore", under="ignore"):   # flagged below (bits 32, 64), with the reason
        ratio = kt / kn  # stable for kn over many decades; kt = 0 exactly gives the frictionless pair
        # kn times a factor of order one, kn (1 + kt/kn) rather than kn + kt: no spurious
        # overflow of an intermediate product near float64's top
        K_mf = kn * (nc * phi / (2.0 * np.pi))
        G_mf = kn * (nc * phi * (1.0 + ratio) / (4.0 * np.pi))
        x = r * (nbar / nc) * rho
        drop_K = 4.0 / (3.0 + ratio) * x
        drop_G = 2.0 * (2.0 + ratio) / (3.0 + ratio) * x
        K = K_mf * (1.0 - drop_K)
        G = G_mf * (1.0 - drop_G)
    drop_K, drop_G = np.broadcast_arrays(drop_K, drop_G)
    big = np.maximum(drop_K, drop_G)
    size = np.maximum(np.abs(drop_K), np.abs(drop_G))  # a stiffening correction counts too
    flags = np.where(big >= 1.0, 1, 0) | np.where(size > max_correction, 2, 0) | np.where(loose, 256, 0)
    # overflow: K = K_mf (1 - drop_K) is inf or NaN whenever K_mf is, so K and G tell it all
    flags = flags | np.where(np.isfinite(K) & np.isfinite(G), 0, 32)
    # underflow, per element only when a cheap global check finds a subnormal somewhere (a
    # subnormal input has lost its digits already; kt = 0 is exact, not subnormal)
    tiny = np.finfo(np.float64).tiny
    arrays = (K_mf, G_mf, K, G, kn, kt)
    sub = [(m != 0) & (np.abs(m) < tiny) for m in arrays]
    if any(np.any(b) for b in sub):
        for b in sub:
            flags = flags | np.where(b, 64, 0)
    if np.size(ratio) and np.max(ratio) > KT_OVER_KN_MAX:
        flags = flags | np.where(ratio > KT_OVER_KN_MAX, 128, 0)
    flags = np.asarray(flags).astype(np.int16)
    valid = flags == 0
    if warn and not np.all(valid):
        n_bad = int(np.size(valid) - np.count_nonzero(valid))
        warnings.warn(f"{n_bad} parameter set(s) outside the first-order theory's range; see .valid/.reason",
                      RuntimeWarning, stacklevel=2)
    K_mf, G_mf, K, G = np.broadcast_arrays(K_mf, G_mf, K, G)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta_mf = (G_mf - K_mf) / (G_mf + K_mf)
        delta = (G - K) / (G + K)
    return Prediction(K_mf=K_mf, G_mf=G_mf, K=K, G=G, drop_K=drop_K, drop_G=drop_G,
                      delta_mf=delta_mf, delta=delta, poisson_mf=-delta_mf, poisson=-delta,
                      nbar=np.broadcast_to(nbar, K.shape), rho=np.broadcast_to(rho, K.shape),
                      valid=valid, flags=flags, index=index)


def predict_from_network(network, *, alpha=None, measured_rho=True, rattlers="exclude", min_contacts=None,
                         nbar=None, check_bounds=True, bound_order=8, rho_neighbours="near",
                         **kwargs) -> Prediction:
    """Predict the moduli of a :class:`~microhom.network.ContactNetwork` from its own statistics.

    ``kn`` is the mean contact ``kn``; ``kt`` the mean *effective* tangent stiffness (0 for sliding
    contacts), so the mean field equals the affine structural sum of an isotropic network.
    ``Nc``, ``r`` and ``rho`` are measured (see :func:`microhom.structural_sums.network_statistics`)
    with rattlers excluded (``rattlers="exclude"``, default) or included; ``phi`` is the network's
    solid fraction. With ``measured_rho=False`` the paper's alpha model is used instead.
    ``rho_neighbours`` chooses the neighbourhood V of (41) is summed over: ``"near"`` (default,
    the paper's N̄ near neighbours of (39), N̄ = ``nbar`` or from phi) or ``"contacts"`` (the
    option; only mu's contacting neighbours, which makes rho ~ 1 by definition,
    ``docs/results/rho.md``).

    It flags (``valid = False``, ``reason``) rather than raising:

    * ``phi`` above close packing (overlapping disks): Nbar and the mean field are taken at close
      packing; below pi/4, where Nbar(phi) does not exist, Nbar = 4 is used (bit 256, unless
      ``nbar`` is given);
    * near-isostatic packings, ``Z - Z_iso < 0.5`` with ``Z`` the mean coordination of the
      load-bearing particles and ``Z_iso`` = 3 (frictional: some contact has kt_eff > 0) or 4;
    * with ``check_bounds`` (periodic networks), a K or G above the rigorous upper bound of the
      relaxation hierarchy after ``bound_order`` CG steps (``microhom.hierarchy``, the block-Jacobi
      ladder: its cheapest rigorous bound; without pre-stress, as the theory): the prediction is
      then provably too stiff.
    """
    if not isinstance(network, ContactNetwork):
        raise TypeError(f"network must be a microhom.network.ContactNetwork (e.g. from "
                        f"microhom.network.from_overlaps), got {type(network).__name__}")
    st = network_statistics(network, min_contacts=min_contacts, rho_neighbours=rho_neighbours, nbar=nbar)
    key = {"exclude": "", "include": "_all"}.get(rattlers)
    if key is None:
        raise ValueError(f"rattlers must be 'exclude' or 'include', got {rattlers!r}")
    if measured_rho and alpha is not None:
        raise ValueError("alpha is only used with measured_rho=False")
    kn = float(np.mean(network.kn)) if network.n_contacts else 1.0
    kt = float(np.mean(network.effective_kt)) if network.n_contacts else 0.0
    rho = getattr(st, "rho" + key) if measured_rho else None
    phi = st.phi
    extra = 0
    if phi > PHI_MAX:     # overlaps inflate phi: flag and take Nbar, the mean field at close packing
        extra |= 4
        phi = PHI_MAX
    z_iso = 3.0 if kt > 0 else 4.0
    if not st.nc - z_iso >= 0.5:   # also NaN: no load-bearing particle
        extra |= 8
    nc = getattr(st, "nc" + key)
    if not nc > 0:  # no load-bearing particle: report the zero network as invalid, not a crash
        nc, extra = 1e-300, extra | 8
    warn = kwargs.pop("warn", True)
    r = getattr(st, "r" + key)
    p = predict_moduli(kn, kt, nc, phi, r if np.isfinite(r) else 0.0, alpha=alpha,
                       rho=rho if rho is None or np.isfinite(rho) else 0.0,
                       nbar=nbar, diameter=st.diameter, warn=False, **kwargs)
    if check_bounds and network.cell is not None and network.n_contacts:
        # the cheap rigorous bound (block ladder, no soft-mode search): enough to prove a
        # prediction too stiff, at a fraction of an exact solve's cost at every size
        h = relaxation_hierarchy(network, max_order=bound_order, spectral_bound="none",
                                 min_contacts=min_contacts, preconditioner="block", soft_modes=0)
        tol = 1e-9 * max(h.K.upper, h.G.upper, 1e-300)
        if not h.unstable and (float(p.K) > h.K.upper + tol or float(p.G) > h.G.upper + tol):
            extra |= 16
    if extra:
        flags = (np.asarray(p.flags) | extra).astype(np.int16)
        p = replace(p, flags=flags, valid=flags == 0)
    if warn and not np.all(p.valid):
        warnings.warn(f"prediction flagged: {p.reason}", RuntimeWarning, stacklevel=2)
    return p
