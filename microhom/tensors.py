"""Stiffness tensors in Mandel, Voigt and full (d, d, d, d) form, and their isotropic moduli (2D and 3D).

Conventions (used throughout ``microhom`` and ``dem``): strains and stresses in Mandel form
``[xx, yy, sqrt2 xy]``, so that a (3, 3) Mandel stiffness ``C`` maps Mandel strain to Mandel
stress and the strain energy density is ``eps . C . eps / 2``. Voigt stiffness ``Cv`` maps
``[e11, e22, 2 e12]`` to ``[s11, s22, s12]``. The isotropic projection of a 2D stiffness is

    K = (C1111 + C2222 + 2 C1122) / 4,
    G = ((C1111 + C2222 - 2 C1122) / 4 + C1212) / 2,

the area-change (bulk) and orientation-averaged shear moduli (2D: N/m, force per length, the unit of kn).

In 3D (spheres) the Mandel order is ``[xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy]`` (Voigt's order),
a (6, 6) Mandel stiffness, and the isotropic projection ``K = 1.C.1/9``, ``G = (tr C - 1.C.1/3)/10``
(Pa). Every function takes the dimension from the shape of its argument.
"""
from __future__ import annotations

import numpy as np

__all__ = ["mandel_to_tensor", "tensor_to_mandel", "mandel_to_voigt", "voigt_to_mandel",
           "voigt_to_tensor", "tensor_to_voigt", "strain_to_mandel", "mandel_to_strain",
           "isotropic_moduli", "prestress_correction"]

_SQ2 = np.sqrt(2.0)
#: Mandel components per dimension: 2D [11, 22, 12]; 3D [11, 22, 33, 23, 13, 12] (Voigt's order)
_IDX = {2: ((0, 0), (1, 1), (0, 1)),
        3: ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))}
_W = {2: np.array([1.0, 1.0, _SQ2]), 3: np.array([1.0, 1.0, 1.0, _SQ2, _SQ2, _SQ2])}
_DIM_OF_SIZE = {3: 2, 6: 3}


def _dim_of_mandel(m) -> int:
    """Dimension of a Mandel matrix or vector: 3 components -> 2D, 6 -> 3D."""
    try:
        return _DIM_OF_SIZE[np.shape(m)[0]]
    except (KeyError, IndexError):
        raise ValueError(f"a Mandel matrix is (3, 3) in 2D or (6, 6) in 3D (a vector (3,) or (6,)), "
                         f"got shape {np.shape(m)}") from None


def mandel_to_tensor(m) -> np.ndarray:
    """(3, 3) Mandel matrix over [xx, yy, sqrt2 xy] (2D) or (6, 6) over
    [xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy] (3D) -> (d, d, d, d) tensor with minor symmetries."""
    m = np.asarray(m, dtype=float)
    d = _dim_of_mandel(m)
    idx, w = _IDX[d], _W[d]
    c = np.zeros((d, d, d, d))
    for a, (i, j) in enumerate(idx):
        for b, (k, l) in enumerate(idx):
            v = m[a, b] / (w[a] * w[b])
            c[i, j, k, l] = c[j, i, k, l] = c[i, j, l, k] = c[j, i, l, k] = v
    return c


def tensor_to_mandel(c) -> np.ndarray:
    """(d, d, d, d) tensor -> (3, 3) (2D) or (6, 6) (3D) Mandel matrix (minor-symmetrised)."""
    c = np.asarray(c, dtype=float)
    d = c.shape[0]
    if c.shape not in ((2, 2, 2, 2), (3, 3, 3, 3)):
        raise ValueError(f"a stiffness tensor is (2, 2, 2, 2) or (3, 3, 3, 3), got {c.shape}")
    idx, w = _IDX[d], _W[d]
    c = 0.25 * (c + c.transpose(1, 0, 2, 3) + c.transpose(0, 1, 3, 2) + c.transpose(1, 0, 3, 2))
    m = np.empty((len(idx), len(idx)))
    for a, (i, j) in enumerate(idx):
        for b, (k, l) in enumerate(idx):
            m[a, b] = c[i, j, k, l] * w[a] * w[b]
    return m


def mandel_to_voigt(m) -> np.ndarray:
    """Mandel stiffness -> Voigt stiffness (2D ``[s11, s22, s12] = Cv [e11, e22, 2 e12]``; 3D
    ``[s11, s22, s33, s23, s13, s12] = Cv [e11, e22, e33, 2 e23, 2 e13, 2 e12]``)."""
    w = _W[_dim_of_mandel(m)]
    return np.asarray(m, dtype=float) / np.outer(w, w)


def voigt_to_mandel(cv) -> np.ndarray:
    """Voigt stiffness (2D ``[s11, s22, s12] = Cv [e11, e22, 2 e12]``, 3D likewise) -> Mandel."""
    w = _W[_dim_of_mandel(cv)]
    return np.asarray(cv, dtype=float) * np.outer(w, w)


def voigt_to_tensor(cv) -> np.ndarray:
    """Voigt stiffness (3, 3) or (6, 6) -> (d, d, d, d) tensor."""
    return mandel_to_tensor(voigt_to_mandel(cv))


def tensor_to_voigt(c) -> np.ndarray:
    """(d, d, d, d) tensor -> Voigt stiffness (3, 3) or (6, 6)."""
    return mandel_to_voigt(tensor_to_mandel(c))


def strain_to_mandel(e) -> np.ndarray:
    """Symmetric (2, 2) strain or stress -> Mandel vector [e11, e22, sqrt2 e12]; (3, 3) ->
    [e11, e22, e33, sqrt2 e23, sqrt2 e13, sqrt2 e12]."""
    e = np.asarray(e, dtype=float)
    if e.shape == (3, 3):
        return np.array([e[0, 0], e[1, 1], e[2, 2], _SQ2 * 0.5 * (e[1, 2] + e[2, 1]),
                         _SQ2 * 0.5 * (e[0, 2] + e[2, 0]), _SQ2 * 0.5 * (e[0, 1] + e[1, 0])])
    return np.array([e[0, 0], e[1, 1], _SQ2 * 0.5 * (e[0, 1] + e[1, 0])])


def mandel_to_strain(v) -> np.ndarray:
    """Mandel vector (3,) [e11, e22, sqrt2 e12] -> symmetric (2, 2) tensor; (6,) -> (3, 3)."""
    v = np.asarray(v, dtype=float)
    if _dim_of_mandel(v) == 3:
        return np.array([[v[0], v[5] / _SQ2, v[4] / _SQ2],
                         [v[5] / _SQ2, v[1], v[3] / _SQ2],
                         [v[4] / _SQ2, v[3] / _SQ2, v[2]]])
    return np.array([[v[0], v[2] / _SQ2], [v[2] / _SQ2, v[1]]])


def isotropic_moduli(m) -> tuple[float, float]:
    """Isotropic projection (K, G) [unit of ``m``] of a Mandel stiffness ``m``: (3, 3) in 2D
    (formula in the module docstring; N/m for 2D stiffnesses), (6, 6) in 3D (Pa):
    ``K = 1.C.1 / 9`` and ``G = (tr C - 1.C.1 / 3) / 10`` with ``1 = [1, 1, 1, 0, 0, 0]``, the
    projections on the volumetric and the five deviatoric Mandel modes."""
    m = np.asarray(m, dtype=float)
    if _dim_of_mandel(m) == 3:
        s = float(m[:3, :3].sum())
        return s / 9.0, float((np.trace(m) - s / 3.0) / 10.0)
    c1111, c2222, c1122, c1212 = m[0, 0], m[1, 1], 0.5 * (m[0, 1] + m[1, 0]), 0.5 * m[2, 2]
    k = (c1111 + c2222 + 2.0 * c1122) / 4.0
    g = ((c1111 + c2222 - 2.0 * c1122) / 4.0 + c1212) / 2.0
    return float(k), float(g)


def prestress_correction(sigma0) -> np.ndarray:
    """(3, 3) (2D) or (6, 6) (3D) Mandel matrix of ``dE -> sym(sigma0 dE) - sigma0 tr(dE)``.

    Added to the stiffness of the energy density (the second derivative of U/V0 with respect to
    the linear strain, jax-md's ``athermal_moduli`` convention) it gives the Cauchy stress
    increment of a packing under the pre-stress ``sigma0`` (d, d) [N/m in 2D, Pa in 3D, tension
    positive]. In 2D its isotropic part is ``K = B + p/2``, ``G = G_U - p/2`` with
    ``p = -tr(sigma0)/2``.
    """
    sigma0 = np.asarray(sigma0, dtype=float)
    nm = 6 if sigma0.shape == (3, 3) else 3
    m = np.empty((nm, nm))
    for b in range(nm):
        e = mandel_to_strain(np.eye(nm)[b])
        s = 0.5 * (sigma0 @ e + e @ sigma0) - sigma0 * np.trace(e)
        m[:, b] = strain_to_mandel(s)
    return m
