"""2D stiffness tensors in Mandel, Voigt and full (2, 2, 2, 2) form, and their isotropic moduli.

Conventions (used throughout ``microhom`` and ``dem``): strains and stresses in Mandel form
``[xx, yy, sqrt2 xy]``, so that a (3, 3) Mandel stiffness ``C`` maps Mandel strain to Mandel
stress and the strain energy density is ``eps . C . eps / 2``. Voigt stiffness ``Cv`` maps
``[e11, e22, 2 e12]`` to ``[s11, s22, s12]``. The isotropic projection of a 2D stiffness is

    K = (C1111 + C2222 + 2 C1122) / 4,
    G = ((C1111 + C2222 - 2 C1122) / 4 + C1212) / 2,

the area-change (bulk) and orientation-averaged shear moduli (2D: N/m, force per length, the unit of kn).
"""
from __future__ import annotations

import numpy as np

__all__ = ["mandel_to_tensor", "tensor_to_mandel", "mandel_to_voigt", "voigt_to_mandel",
           "voigt_to_tensor", "tensor_to_voigt", "strain_to_mandel", "mandel_to_strain",
           "isotropic_moduli", "prestress_correction"]

_SQ2 = np.sqrt(2.0)
_W = np.array([1.0, 1.0, _SQ2])          # Mandel weights for [11, 22, 12]
_IDX = ((0, 0), (1, 1), (0, 1))


def mandel_to_tensor(m) -> np.ndarray:
    """(3, 3) Mandel matrix over [xx, yy, sqrt2 xy] -> (2, 2, 2, 2) tensor with minor symmetries."""
    m = np.asarray(m, dtype=float)
    c = np.zeros((2, 2, 2, 2))
    for a, (i, j) in enumerate(_IDX):
        for b, (k, l) in enumerate(_IDX):
            v = m[a, b] / (_W[a] * _W[b])
            c[i, j, k, l] = c[j, i, k, l] = c[i, j, l, k] = c[j, i, l, k] = v
    return c


def tensor_to_mandel(c) -> np.ndarray:
    """(2, 2, 2, 2) tensor -> (3, 3) Mandel matrix (minor-symmetrised)."""
    c = np.asarray(c, dtype=float)
    c = 0.25 * (c + c.transpose(1, 0, 2, 3) + c.transpose(0, 1, 3, 2) + c.transpose(1, 0, 3, 2))
    m = np.empty((3, 3))
    for a, (i, j) in enumerate(_IDX):
        for b, (k, l) in enumerate(_IDX):
            m[a, b] = c[i, j, k, l] * _W[a] * _W[b]
    return m


def mandel_to_voigt(m) -> np.ndarray:
    """Mandel stiffness -> Voigt stiffness ([s11, s22, s12] = Cv [e11, e22, 2 e12])."""
    return np.asarray(m, dtype=float) / np.outer(_W, _W)


def voigt_to_mandel(cv) -> np.ndarray:
    """Voigt stiffness ([s11, s22, s12] = Cv [e11, e22, 2 e12]) -> Mandel stiffness."""
    return np.asarray(cv, dtype=float) * np.outer(_W, _W)


def voigt_to_tensor(cv) -> np.ndarray:
    """Voigt stiffness (3, 3) -> (2, 2, 2, 2) tensor."""
    return mandel_to_tensor(voigt_to_mandel(cv))


def tensor_to_voigt(c) -> np.ndarray:
    """(2, 2, 2, 2) tensor -> Voigt stiffness (3, 3)."""
    return mandel_to_voigt(tensor_to_mandel(c))


def strain_to_mandel(e) -> np.ndarray:
    """Symmetric (2, 2) strain or stress -> Mandel vector [e11, e22, sqrt2 e12]."""
    e = np.asarray(e, dtype=float)
    return np.array([e[0, 0], e[1, 1], _SQ2 * 0.5 * (e[0, 1] + e[1, 0])])


def mandel_to_strain(v) -> np.ndarray:
    """Mandel vector [e11, e22, sqrt2 e12] -> symmetric (2, 2) tensor."""
    v = np.asarray(v, dtype=float)
    return np.array([[v[0], v[2] / _SQ2], [v[2] / _SQ2, v[1]]])


def isotropic_moduli(m) -> tuple[float, float]:
    """Isotropic projection (K, G) [unit of ``m``, N/m for stiffnesses] of a (3, 3) 2D Mandel
    stiffness ``m`` (formula in the module docstring)."""
    m = np.asarray(m, dtype=float)
    c1111, c2222, c1122, c1212 = m[0, 0], m[1, 1], 0.5 * (m[0, 1] + m[1, 0]), 0.5 * m[2, 2]
    k = (c1111 + c2222 + 2.0 * c1122) / 4.0
    g = ((c1111 + c2222 - 2.0 * c1122) / 4.0 + c1212) / 2.0
    return float(k), float(g)


def prestress_correction(sigma0) -> np.ndarray:
    """(3, 3) Mandel matrix of ``dE -> sym(sigma0 dE) - sigma0 tr(dE)``.

    Added to the stiffness of the energy density (the second derivative of U/V0 with respect to
    the linear strain, jax-md's ``athermal_moduli`` convention) it gives the Cauchy stress
    increment of a packing under the pre-stress ``sigma0`` (2, 2) [N/m, tension positive]. Its
    isotropic part is ``K = B + p/2``, ``G = G_U - p/2`` with ``p = -tr(sigma0)/2``.
    """
    sigma0 = np.asarray(sigma0, dtype=float)
    m = np.empty((3, 3))
    for b in range(3):
        e = mandel_to_strain(np.eye(3)[b])
        s = 0.5 * (sigma0 @ e + e @ sigma0) - sigma0 * np.trace(e)
        m[:, b] = strain_to_mandel(s)
    return m
