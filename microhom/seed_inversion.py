"""Inversion of the seed's first-order correction: which r, rho or N̄ would reproduce given drops?

The corrected moduli (50)-(51) (:func:`microhom.moduli.predict_moduli`) are

    drop_K = 1 - K/K_mf = 4/(3 + t) x,        drop_G = 1 - G/G_mf = 2 (2 + t)/(3 + t) x,

with ``t = kt/kn`` and the single combination ``x = r (N̄/Nc) rho`` of the three statistics. So
each measured drop fixes ``x`` in closed form,

    x_K = (3 + t) drop_K / 4,                 x_G = (3 + t) drop_G / (2 (2 + t)),

and with two of (r, rho, N̄) held at their measured values the third follows, e.g.
``r_K = x_K Nc / (N̄ rho)``. Because r, rho and N̄ enter only through ``x``, *any* one of them
fitted to K and to G differs between the two moduli by the same factor

    mismatch = x_G / x_K = [drop_G / drop_K] / [(2 + t)/2],

the measured shear-to-bulk drop ratio over the theory's fixed ratio ``(2 + t)/2`` (3/2 at
kt = kn, (55)). One parameter can fit both moduli only where ``mismatch = 1``; this is the
criterion :class:`SeedInversion` reports. (A N̄ that also changes the neighbourhood rho is
measured over is the study's business: ``studies.seed_inversion``; here rho is held fixed.)

The closed forms are checked by a round trip (predict with a known r, invert, recover it) in
``tests/test_seed_inversion.py``, and against sympy's solve of (50)-(51) in the same test.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .results import Result

__all__ = ["invert_seed_correction", "SeedInversion"]


@dataclass(frozen=True)
class SeedInversion(Result):
    """What the seed's correction (50)-(51) needs to reproduce given drops (:func:`invert_seed_correction`).

    Every field is an array of the broadcast input shape (0-d for scalars); dimensionless.
    Suffix ``_K``: fitted to the bulk drop; ``_G``: to the shear drop.

    Attributes
    ----------
    x_K, x_G : ndarray
        The combination ``x = r (N̄/Nc) rho`` each drop needs.
    x_measured : ndarray
        ``x`` at the measured r, N̄, rho, Nc.
    r_K, r_G : ndarray
        Contact-number fluctuation needed, N̄ and rho at their measured values.
    rho_K, rho_G : ndarray
        Correlation factor needed, r and N̄ at their measured values (inf where r N̄ = 0).
    nbar_K, nbar_G : ndarray
        Mean number of near neighbours needed, r and rho at their measured values, rho held
        fixed (inf where r rho = 0; non-positive where rho < 0).
    factor_K, factor_G : ndarray
        ``x_K / x_measured`` and ``x_G / x_measured``: by how much the correction must grow
        (the same factor for r, rho or N̄, since they enter only through x).
    ratio_measured, ratio_theory : ndarray
        ``drop_G / drop_K`` given, and the theory's ``(2 + t)/2``.
    mismatch : ndarray
        ``x_G / x_K = ratio_measured / ratio_theory``: 1 where one parameter fits both moduli.
    """

    x_K: np.ndarray
    x_G: np.ndarray
    x_measured: np.ndarray
    r_K: np.ndarray
    r_G: np.ndarray
    rho_K: np.ndarray
    rho_G: np.ndarray
    nbar_K: np.ndarray
    nbar_G: np.ndarray
    factor_K: np.ndarray
    factor_G: np.ndarray
    ratio_measured: np.ndarray
    ratio_theory: np.ndarray
    mismatch: np.ndarray


def _arr(name, v, lo=None, lo_open=False, hi=None):
    a = np.asarray(v, dtype=np.float64)
    bad = ~np.isfinite(a)
    if lo is not None:
        bad |= (a <= lo) if lo_open else (a < lo)
    if hi is not None:
        bad |= a >= hi
    if np.any(bad):
        rng = f"{'(' if lo_open or lo is None else '['}{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'})"
        raise ValueError(f"{name} must be finite and in {rng}; got {a.ravel()[np.flatnonzero(bad.ravel())[0]]!r}")
    return a


def invert_seed_correction(drop_K, drop_G, *, kt_over_kn, nc, r, nbar, rho) -> SeedInversion:
    """The x, r, rho and N̄ the seed's correction (50)-(51) needs to give ``drop_K`` and ``drop_G``.

    All array arguments broadcast together; everything is dimensionless.

    Parameters
    ----------
    drop_K, drop_G : array_like
        Fraction changes ``1 - modulus / mean field`` to reproduce (e.g. the exact DEM moduli over
        the theory's mean field at the measured Nc and phi), each < 1.
    kt_over_kn : array_like
        Tangential over normal contact stiffness t, >= 0 (the effective one for sliding contacts).
    nc : array_like
        Mean coordination number Nc, > 0.
    r : array_like
        Measured contact-number fluctuation ``var(Nc)/Nc^2``, >= 0.
    nbar : array_like
        Mean number of near neighbours N̄, > 0.
    rho : array_like
        Measured correlation factor ``Nc sum V.W / sum V^2`` (any sign, finite).

    Returns
    -------
    SeedInversion
        The needed x, r, rho, N̄ per modulus, the growth factor and the mismatch ``x_G / x_K``.
    """
    dK = _arr("drop_K", drop_K, hi=1.0)
    dG = _arr("drop_G", drop_G, hi=1.0)
    t = _arr("kt_over_kn", kt_over_kn, 0.0)
    nc = _arr("nc", nc, 0.0, lo_open=True)
    r = _arr("r", r, 0.0)
    nb = _arr("nbar", nbar, 0.0, lo_open=True)
    rho = _arr("rho", rho)
    xK = (3.0 + t) * dK / 4.0
    xG = (3.0 + t) * dG / (2.0 * (2.0 + t))
    xm = r * nb / nc * rho
    with np.errstate(divide="ignore", invalid="ignore"):
        out = dict(x_K=xK, x_G=xG, x_measured=xm,
                   r_K=xK * nc / (nb * rho), r_G=xG * nc / (nb * rho),
                   rho_K=xK * nc / (r * nb), rho_G=xG * nc / (r * nb),
                   nbar_K=xK * nc / (r * rho), nbar_G=xG * nc / (r * rho),
                   factor_K=xK / xm, factor_G=xG / xm,
                   ratio_measured=dG / dK, ratio_theory=(2.0 + t) / 2.0, mismatch=xG / xK)
    b = np.broadcast_arrays(*out.values())
    return SeedInversion(**{k: np.array(v) for k, v in zip(out, b)})
