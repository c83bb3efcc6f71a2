"""Statistics-only closure: the moduli of a frictional random disk packing from numbers a user
can know, with the closure's measured error returned with every prediction.

Where the seed's first-order formula (:func:`microhom.moduli.predict_moduli`, kept unchanged)
misses the non-affine relaxation (docs/results/kuhn.md, sweep.md), this closure is fitted to the
exact linear response of our own DEM packings. It is an empirical closure, not a derivation:

    log(K / K_mf) = c_K . f,     log(G / G_mf) = c_G . f,
    K_mf = Z phi kn / (2 pi),    G_mf = Z phi (kn + kt) / (4 pi)          (mean field (37))

with the features ``f`` of :func:`features` — the distance to frictional isostaticity
``dZ = Z - 3`` (``Z``: mean contacts per load-bearing particle, rattlers excluded), ``kt/kn``, the
radius dispersity and the seed's contact-number fluctuation ``r`` — because the relaxation is controlled by how far the contact network is
from isostaticity (G vanishes there) and by the tangent stiffness. ``COEF_K``, ``COEF_G``,
``RANGES`` and ``ERROR`` are produced by ``python -m studies.closure_fit`` (data and provenance in
docs/results/hierarchy.md): fitted on 16 packings x 4 kt/kn (N = 500), validated on 10 other
packings (N = 3000).

Flags (``valid = False`` with a reason, never silent): inputs outside the fitted range
(``RANGES``), near-isostatic packings (``dZ < RANGES['dz'][0]``, where G -> 0 and the relative error
is unbounded), frictionless contacts (kt = 0: a different isostatic point, not fitted).

Vectorised numpy: >= 1e6 parameter sets per second (``studies.bench_hierarchy stats``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .limits import as_float_array
from .results import Result

__all__ = ["features", "predict_closure", "ClosurePrediction", "FEATURES", "COEF_K", "COEF_G",
           "RANGES", "ERROR"]

FEATURES = ("1", "log dZ", "log kt/kn", "(log kt/kn)^2", "dispersity", "log dZ * log kt/kn", "r",
            "(log dZ)^2")
# --- fitted by studies.closure_fit (see docs/results/hierarchy.md for the data) ---------------
COEF_K = np.array([-0.088102, 0.080908, 0.030167, -0.013855, 0.188994, -0.028783, -2.484779, -0.035279])
COEF_G = np.array([-0.015899, 0.367636, -0.154042, -0.122054, -0.008414, -0.014654, -10.392498, -0.284773])
RANGES = {"dz": (0.2, 2.52), "kt_over_kn": (0.1, 1.0), "dispersity": (0.0, 0.2), "r": (0.015, 0.07)}
ERROR = {"K": 0.034, "G": 0.055}   # rms relative error on the 9 validation packings in range
# -------------------------------------------------------------------------------------------------

#: The largest solid fraction accepted: above 1 a measured phi counts the overlaps twice; up to
#: 1.1 that is a squeezed packing (flagged), beyond it not a packing fraction (refused).
PHI_INFLATED_MAX = 1.1

_REASONS = (
    (1, "outside the fitted range of Z - 3, kt/kn, dispersity or r"),
    (2, "near isostatic (Z - 3 below the fitted range): G -> 0, relative error unbounded"),
    (4, "frictionless contacts (kt = 0): not covered by the closure"),
    (8, "phi above 1 (overlaps inflate it): outside the fitted range; the moduli scale with phi"),
)


def features(nc, kt_over_kn, dispersity, r):
    """(..., 8) design matrix of the closure (columns named in ``FEATURES``).

    nc: mean contacts per load-bearing particle; kt_over_kn > 0; dispersity >= 0; r = var(Nc)/Nc^2
    over the load-bearing particles (the seed's contact-number fluctuation). dZ = nc - 3 is
    floored at 1e-3 and kt/kn at 1e-6 so that the matrix stays finite for flagged inputs.
    """
    nc, kr, d, r = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (nc, kt_over_kn, dispersity, r)))
    lz = np.log(np.maximum(nc - 3.0, 1e-3))
    lk = np.log(np.maximum(kr, 1e-6))
    return np.stack([np.ones_like(lz), lz, lk, lk * lk, d, lz * lk, r, lz * lz], axis=-1)


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
        The closure's measured rms relative error on packings it was not fitted to (``ERROR``), as
        absolute values (``ERROR * modulus``) [N/m].
    valid : ndarray of bool
        False where a flag applies.
    flags : ndarray of int8
        Bit mask: 1 outside the fitted range, 2 near-isostatic, 4 frictionless (kt = 0),
        8 phi above 1 (overlap-inflated, as ``predict_from_network`` flags it).
    reason : ndarray of str
        Text of the flags per entry (``"ok"`` when none; property).
    """

    K: np.ndarray
    G: np.ndarray
    K_mf: np.ndarray
    G_mf: np.ndarray
    error_K: np.ndarray
    error_G: np.ndarray
    valid: np.ndarray
    flags: np.ndarray

    @property
    def reason(self) -> np.ndarray:
        """Text of the flags of each entry (``"ok"`` when none), shape of the inputs."""
        texts = np.array(["; ".join(t for bit, t in _REASONS if code & bit) or "ok"
                          for code in range(1 << len(_REASONS))], dtype=object)
        return texts[np.asarray(self.flags)]


def _check(name, a, lo, hi=np.inf, lo_open=False):
    a = as_float_array(name, a)
    bad = ~np.isfinite(a) | ((a <= lo) if lo_open else (a < lo)) | (a > hi)
    if np.any(bad):
        v = float(a.ravel()[np.flatnonzero(np.broadcast_to(bad, a.shape).ravel())[0]])
        raise ValueError(f"{name} must be finite and in {'(' if lo_open else '['}{lo:g}, {hi:g}]; got {v!r}")
    return a


def predict_closure(nc, r, phi=0.84, kt_over_kn=1.0, dispersity=0.0, kn=1.0,
                    coef_K=None, coef_G=None) -> ClosurePrediction:
    """Moduli from statistics (all arguments broadcast together).

    Parameters
    ----------
    nc : array_like
        Mean contacts per load-bearing particle (rattlers excluded), > 0.
    r : array_like
        Contact-number fluctuation ``var(Nc)/Nc^2`` of the load-bearing particles, >= 0.
    phi : array_like
        Solid fraction, in (0, 1.1]; in (1, 1.1] (overlap-inflated, as packings squeezed to
        p/kn ~ 1e-2 measure it) the result is flagged (bit 8) rather than refused.
    kt_over_kn : array_like
        Tangential over normal contact stiffness, >= 0.
    dispersity : array_like
        Radius spread (radii uniform in r (1 +- dispersity)), >= 0.
    kn : array_like
        Normal contact stiffness [N/m], > 0.
    coef_K, coef_G : array_like, optional
        Override the stored coefficients (used by the refit study).

    The pressure enters through nc (fitted and validated for p/kn in [1e-4, 5e-2]).

    Returns
    -------
    ClosurePrediction
        Arrays of the broadcast input shape [N/m]. Raises ``ValueError`` naming the parameter for
        input outside its range.
    """
    nc = _check("nc", nc, 0.0, lo_open=True)
    r = _check("r", r, 0.0)
    phi = _check("phi", phi, 0.0, PHI_INFLATED_MAX, lo_open=True)   # (1, 1.1]: flagged (8)
    kr = _check("kt_over_kn", kt_over_kn, 0.0)
    d = _check("dispersity", dispersity, 0.0)
    kn = _check("kn", kn, 0.0, lo_open=True)
    cK = COEF_K if coef_K is None else np.asarray(coef_K, dtype=float)
    cG = COEF_G if coef_G is None else np.asarray(coef_G, dtype=float)
    X = features(nc, kr, d, r)
    K_mf = nc * phi * kn / (2 * np.pi)
    G_mf = nc * phi * kn * (1 + kr) / (4 * np.pi)
    K = K_mf * np.exp(X @ cK)
    G = G_mf * np.exp(X @ cG)
    dz = nc - 3.0
    (zlo, zhi), (klo, khi), (dlo, dhi), (rlo, rhi) = (RANGES[k] for k in ("dz", "kt_over_kn", "dispersity", "r"))
    tol = 1e-9
    out = ((dz > zhi + tol) | (kr < klo - tol) | (kr > khi + tol) | (d < dlo - tol) | (d > dhi + tol)
           | (r < rlo - tol) | (r > rhi + tol))
    flags = (np.where(out & (kr > 0), 1, 0) | np.where(dz < zlo, 2, 0) | np.where(kr == 0, 4, 0)
             | np.where(phi > 1.0, 8, 0))
    flags = np.broadcast_to(flags, K.shape).astype(np.int8)
    return ClosurePrediction(K=K, G=G, K_mf=np.broadcast_to(K_mf, K.shape), G_mf=np.broadcast_to(G_mf, K.shape),
                             error_K=ERROR["K"] * np.abs(K), error_G=ERROR["G"] * np.abs(G),
                             valid=flags == 0, flags=flags)
