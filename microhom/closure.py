"""Statistics-only closure: the moduli of a random disk packing from numbers a user can know
(Z, phi, the contact-number fluctuation r, kt/kn, the radius dispersity, the sliding fraction),
with an error stated per prediction and a flag wherever the input is far from the data.

Where the seed's first-order formula (:func:`microhom.moduli.predict_moduli`, kept unchanged)
misses the non-affine relaxation (docs/results/kuhn.md, sweep.md), this closure is fitted to the
exact linear response (``dem.stiffness``, without pre-stress) of a corpus of packings made by five
protocols (``studies.corpus``; results, leave-one-protocol-out errors and what fails in
docs/results/closure.md). It is an empirical closure with the known limits built into its form:

    G = G_mf  dZ / (dZ + a),        a = exp(c_G . f)
    K = K_mf  / (1 + b),            b = exp(c_K . f)
    K_mf = Z phi kn / (2 pi),       G_mf = Z phi (kn + kt) / (4 pi)            (mean field (37))

with ``dZ = Z - Z_iso`` the distance to the isostatic point that the mobilised contacts imply
(counting constraints: a non-sliding frictional contact fixes 2 relative motions, a sliding or
frictionless one 1; a frictional disk has 3 degrees of freedom, a frictionless one 2):

    Z_iso = 6 / (2 - s)     (kt > 0, s = sliding fraction of the load-bearing contacts; 3 if none)
    Z_iso = 4               (kt = 0, frictionless)

So G vanishes linearly at the isostatic point (the scaling G ~ dZ of the jamming literature) and
tends to the mean field at high Z (``a`` is bounded); K stays finite at the isostatic point. The
features ``f`` are those of :func:`features` (named in ``FEATURES``).

Error (``error_K``, ``error_G``): stated per prediction, from the leave-one-protocol-out residuals
of the corpus, growing with the distance of the input from the data: the leverage
``h = f (F^T F)^-1 f^T`` of the input's features in the fitted design ``F`` (a Mahalanobis distance
in feature space), ``error = Q sqrt(1 + h / h_mean)`` (relative), with ``Q`` set so that 90 % of the
held-out cases lie within it. Inputs with ``h > H_MAX`` (beyond the corpus) are flagged.

Flags (``valid = False`` with a reason, never silent): 1 outside the data (leverage above
``H_MAX`` or outside the box ``RANGES``), 2 at or below the isostatic point (``dZ < DZ_MIN``:
G -> 0, relative error unbounded).

Vectorised numpy: >= 1e6 parameter sets per second (``python -m studies.closure_fit --bench``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .results import Result

__all__ = ["features", "isostatic_point", "predict_closure", "ClosurePrediction", "FEATURES", "COEF_K",
           "COEF_G", "COV_K", "COV_G", "Q", "H_MEAN", "H_MAX", "RANGES", "DZ_MIN", "ERROR"]

FEATURES = ("1", "frictionless", "log kt/kn", "(log kt/kn)^2", "log kt/kn * (Z - 4)", "log dZ",
            "dispersity", "r", "frictionless * log dZ")
# --- fitted by python -m studies.closure_fit (data: docs/results/closure.md) ---------------------
COEF_K = np.zeros(len(FEATURES))
COEF_G = np.zeros(len(FEATURES))
COV_K = np.eye(len(FEATURES))        # (F^T F)^-1 of the fitted design
COV_G = np.eye(len(FEATURES))
Q = {"K": 0.1, "G": 0.2}            # relative error at the mean leverage (90 % LOPO coverage)
H_MEAN = 1.0
H_MAX = 1.0
RANGES = {"Z": (3.0, 6.0), "kt_over_kn": (0.05, 1.0), "dispersity": (0.0, 0.5), "r": (0.0, 0.1),
          "phi": (0.8, 0.92)}
DZ_MIN = 0.05
# -------------------------------------------------------------------------------------------------
ERROR = Q   # kept name: the error scale of the closure (relative, at the mean leverage)

_REASONS = (
    (1, "outside the data the closure was fitted on (feature-space distance or range)"),
    (2, "at or below the isostatic point of its mobilised contacts (Z - Z_iso below DZ_MIN): G -> 0, "
        "relative error unbounded"),
)


def isostatic_point(kt_over_kn, sliding_fraction=0.0):
    """Z_iso: 4 for frictionless contacts (kt = 0), 6 / (2 - s) for frictional ones with a sliding
    fraction s of the load-bearing contacts (3 without sliding) [-]."""
    kr = np.asarray(kt_over_kn, dtype=float)
    s = np.asarray(sliding_fraction, dtype=float)
    return np.where(kr > 0, 6.0 / (2.0 - s), 4.0)


def features(nc, kt_over_kn, dispersity, r, sliding_fraction=0.0):
    """(..., len(FEATURES)) feature matrix of the closure and dZ = Z - Z_iso (...,).

    nc: mean contacts per load-bearing particle; kt_over_kn >= 0; dispersity >= 0 (sqrt(3) times
    the relative standard deviation of the radii: the half-width of a uniform law); r =
    var(Nc)/Nc^2 over the load-bearing particles; sliding_fraction in [0, 1]. dZ is floored at
    1e-3 inside the logarithm so that the matrix stays finite for flagged inputs.
    """
    nc, kr, d, r, s = np.broadcast_arrays(*(np.asarray(a, dtype=float)
                                            for a in (nc, kt_over_kn, dispersity, r, sliding_fraction)))
    dz = nc - isostatic_point(kr, s)
    fl = (kr <= 0).astype(float)
    lk = np.where(kr > 0, np.log(np.maximum(kr, 1e-12)), 0.0)
    lz = np.log(np.maximum(dz, 1e-3))
    X = np.stack([np.ones_like(lz), fl, lk, lk * lk, lk * (nc - 4.0), lz, d, r, fl * lz], axis=-1)
    return X, dz


@dataclass(frozen=True, eq=False)
class ClosurePrediction(Result):
    """Statistics-only moduli (arrays of the broadcast input shape, unit of kn, N/m for 2D).

    Attributes
    ----------
    K, G : ndarray
        Predicted bulk and shear moduli [N/m].
    K_mf, G_mf : ndarray
        Mean field (37) at the same Z, phi [N/m].
    error_K, error_G : ndarray
        Stated error of this prediction [N/m]: ``Q sqrt(1 + h / H_MEAN)`` times the modulus, with
        ``h`` the input's leverage; 90 % of the leave-one-protocol-out cases of the corpus lie
        within it.
    rel_error_K, rel_error_G : ndarray
        The same, relative [-].
    leverage_K, leverage_G : ndarray
        The input's leverage in the fitted design (feature-space distance from the data) [-].
    dz : ndarray
        Z - Z_iso [-].
    valid : ndarray of bool
        False where a flag applies.
    flags : ndarray of int8
        Bit mask: 1 outside the data, 2 at or below the isostatic point.
    reason : ndarray of str
        Text of the flags per entry (``"ok"`` when none; property).
    """

    K: np.ndarray
    G: np.ndarray
    K_mf: np.ndarray
    G_mf: np.ndarray
    error_K: np.ndarray
    error_G: np.ndarray
    rel_error_K: np.ndarray
    rel_error_G: np.ndarray
    leverage_K: np.ndarray
    leverage_G: np.ndarray
    dz: np.ndarray
    valid: np.ndarray
    flags: np.ndarray

    @property
    def reason(self) -> np.ndarray:
        """Text of the flags of each entry (``"ok"`` when none), shape of the inputs."""
        texts = np.array(["; ".join(t for bit, t in _REASONS if code & bit) or "ok"
                          for code in range(1 << len(_REASONS))], dtype=object)
        return texts[np.asarray(self.flags)]


def _check(name, a, lo, hi=np.inf, lo_open=False):
    a = np.asarray(a, dtype=float)
    bad = ~np.isfinite(a) | ((a <= lo) if lo_open else (a < lo)) | (a > hi)
    if np.any(bad):
        v = a.ravel()[np.flatnonzero(np.broadcast_to(bad, a.shape).ravel())[0]]
        raise ValueError(f"{name} must be finite and in {'(' if lo_open else '['}{lo:g}, {hi:g}]; got {v!r}")
    return a


def _leverage(X, cov):
    return np.einsum("...i,ij,...j->...", X, cov, X)


def predict_closure(nc, r=None, phi=0.84, kt_over_kn=1.0, dispersity=0.0, kn=1.0, sliding_fraction=None,
                    model=None) -> ClosurePrediction:
    """Moduli from statistics (all arguments broadcast together).

    Parameters
    ----------
    nc : array_like or NetworkStatistics
        Mean contacts per load-bearing particle (rattlers excluded), > 0; or the
        :class:`microhom.structural_sums.NetworkStatistics` of a network (``nc``, ``r``, ``phi`` and
        ``sliding_fraction`` are taken from it; ``kt_over_kn`` and ``dispersity`` stay arguments).
    r : array_like
        Contact-number fluctuation ``var(Nc)/Nc^2`` of the load-bearing particles, >= 0.
    phi : array_like
        Solid fraction, in (0, 1].
    kt_over_kn : array_like
        Tangential over normal contact stiffness, >= 0 (0: frictionless, Z_iso = 4).
    dispersity : array_like
        Radius spread: sqrt(3) std(R)/mean(R) (radii uniform in R (1 +- dispersity); the 50:50
        1:1.4 bidisperse mixture is 0.289), >= 0.
    kn : array_like
        Normal contact stiffness [N/m], > 0.
    sliding_fraction : array_like, optional
        Fraction of the load-bearing contacts at the Coulomb limit, in [0, 1) (default 0).
    model : dict, optional
        Override the stored model (keys ``coef_K``, ``coef_G``, ``cov_K``, ``cov_G``, ``Q``,
        ``h_mean``, ``h_max``; used by the refit study).

    The pressure enters through nc (the corpus spans p/kn from 1e-4 to 3e-2).

    Returns
    -------
    ClosurePrediction
        Arrays of the broadcast input shape [N/m]. Raises ``ValueError`` naming the parameter for
        input outside its range.
    """
    if hasattr(nc, "nc") and hasattr(nc, "r"):   # a NetworkStatistics
        st = nc
        if r is not None:
            raise ValueError("r must not be given with a NetworkStatistics (it carries its own r)")
        nc, r, phi = st.nc, st.r, st.phi
        if sliding_fraction is None:
            sliding_fraction = st.sliding_fraction
    if r is None:
        raise ValueError("r (contact-number fluctuation, >= 0) is required")
    nc = _check("nc", nc, 0.0, lo_open=True)
    r = _check("r", r, 0.0)
    phi = _check("phi", phi, 0.0, 1.0, lo_open=True)
    kr = _check("kt_over_kn", kt_over_kn, 0.0)
    d = _check("dispersity", dispersity, 0.0)
    kn = _check("kn", kn, 0.0, lo_open=True)
    s = _check("sliding_fraction", 0.0 if sliding_fraction is None else sliding_fraction, 0.0, 1.0)
    if np.any(s >= 1):
        raise ValueError("sliding_fraction must be in [0, 1); got 1")
    m = model or {}
    cK = np.asarray(m.get("coef_K", COEF_K), dtype=float)
    cG = np.asarray(m.get("coef_G", COEF_G), dtype=float)
    covK = np.asarray(m.get("cov_K", COV_K), dtype=float)
    covG = np.asarray(m.get("cov_G", COV_G), dtype=float)
    q = m.get("Q", Q)
    h_mean, h_max = m.get("h_mean", H_MEAN), m.get("h_max", H_MAX)
    X, dz = features(nc, kr, d, r, s)
    K_mf = nc * phi * kn / (2 * np.pi)
    G_mf = nc * phi * kn * (1 + kr) / (4 * np.pi)
    with np.errstate(over="ignore"):
        b = np.exp(np.clip(X @ cK, -50, 50))
        a = np.exp(np.clip(X @ cG, -50, 50))
    dzp = np.maximum(dz, 0.0)
    K = K_mf / (1 + b)
    G = G_mf * dzp / (dzp + a)
    hK, hG = _leverage(X, covK), _leverage(X, covG)
    eK = q["K"] * np.sqrt(1 + hK / h_mean)
    eG = q["G"] * np.sqrt(1 + hG / h_mean)
    box = np.zeros(K.shape, dtype=bool)
    for name, v in (("Z", nc), ("dispersity", d), ("r", r), ("phi", phi)):
        lo, hi = RANGES[name]
        box |= (v < lo - 1e-9) | (v > hi + 1e-9)
    klo, khi = RANGES["kt_over_kn"]
    box |= (kr > 0) & ((kr < klo - 1e-12) | (kr > khi + 1e-12))
    out = box | (np.maximum(hK, hG) > h_max)
    flags = (np.where(out, 1, 0) | np.where(dz < DZ_MIN, 2, 0)).astype(np.int8)
    flags = np.broadcast_to(flags, K.shape)
    return ClosurePrediction(K=K, G=G, K_mf=np.broadcast_to(K_mf, K.shape), G_mf=np.broadcast_to(G_mf, K.shape),
                             error_K=eK * np.abs(K), error_G=eG * np.abs(G), rel_error_K=eK, rel_error_G=eG,
                             leverage_K=hK, leverage_G=hG, dz=np.broadcast_to(dz, K.shape),
                             valid=flags == 0, flags=flags)
