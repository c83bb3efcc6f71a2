"""Conventions of peer codes (jax-md, LAMMPS, Kuhn's OVAL) and the conversions to and from ours.

Our stiffness tensors (``dem.analysis.stiffness.stiffness``, ``microhom.moduli``) are 2D Mandel matrices
over ``[xx, yy, sqrt2 xy]`` [N/m] of the **Cauchy stress increment** per linear strain increment
(tension positive), pre-stress included when ``prestress=True``: what a strain probe of the cell
measures. Their isotropic projection ``(K, G)`` is :func:`microhom.tensors.isotropic_moduli`.

jax-md (``jax_md.elasticity.athermal_moduli``) returns the **energy-density tensor**: the second
derivative of ``U/V0`` with respect to the linear strain, non-affine relaxation included, as a
full (2, 2, 2, 2) array ``C_ijkl``; ``extract_isotropic_moduli`` reduces it to ``B`` and ``G`` with
the same formulas as ours. The two differ by the pre-stress ``sigma0`` (2, 2) [N/m]:

    C_cauchy = C_energy + P(sigma0),   P: dE -> sym(sigma0 dE) - sigma0 tr(dE)

(:func:`microhom.tensors.prestress_correction`), whose isotropic part gives, with the pressure
``p = -tr(sigma0)/2`` (compression positive)::

    K = B + p/2,        G = G_U - p/2.

jax-md's harmonic soft disks (``energy.soft_sphere``, ``alpha=2``, ``sigma = r_i + r_j``) are
:func:`microhom.laws.harmonic`: ``kn = epsilon / (r_i + r_j)^2``, ``fn = kn * overlap``, no friction.
Its box is a matrix whose columns are the cell vectors, like ours; with
``periodic_general(box, fractional_coordinates=True)`` (its default) positions are fractional:
``x = box @ s``. Its solver defaults (a "tether" of 1e-10 on the Hessian diagonal instead of
rattler removal, a conjugate-gradient tolerance of 1e-7) limit the agreement with an exact solve to
about 1e-8 relative for ``B`` and 1e-6 for ``G``; tighter settings agree to 1e-11.

LAMMPS ``pair_style gran/hooke/history kn kt ...``: ``fn = kn delta`` (our convention), and
``kt = NULL`` means ``kt = 2/7 kn`` (:data:`LAMMPS_KT_RATIO`). ``gran/hertz/history`` is
:class:`microhom.laws.Hertz` with ``reff=True``.

Kuhn's OVAL / DEMPLA: the normal stiffness ``kn`` multiplies *half* the overlap, so the force per
unit overlap is ``kn/2`` (:func:`kn_from_oval`); moduli scaled by OVAL's ``kn`` are half those
scaled by ours.
"""
from __future__ import annotations

import numpy as np

from .tensors import mandel_to_tensor, prestress_correction, tensor_to_mandel

__all__ = ["LAMMPS_KT_RATIO", "pressure_of", "energy_density_from_cauchy", "cauchy_from_energy_density",
           "jaxmd_moduli", "moduli_from_jaxmd", "jaxmd_tensor", "tensor_from_jaxmd",
           "kn_from_oval", "kn_to_oval", "lammps_kt"]

#: LAMMPS ``gran/*`` default tangential-to-normal stiffness ratio (``kt = NULL``).
LAMMPS_KT_RATIO = 2.0 / 7.0


def _sigma(sigma0):
    s = np.asarray(sigma0, dtype=float)
    if s.shape != (2, 2) or not np.all(np.isfinite(s)):
        raise ValueError(f"sigma0 must be a finite (2, 2) stress [N/m], got shape {s.shape}")
    return s


def _mandel(C, name="C_mandel"):
    C = np.asarray(C, dtype=float)
    if C.shape != (3, 3) or not np.all(np.isfinite(C)):
        raise ValueError(f"{name} must be a finite (3, 3) Mandel matrix, got shape {C.shape}")
    return C


def pressure_of(sigma0) -> float:
    """2D pressure ``p = -tr(sigma0)/2`` [N/m], compression positive."""
    return float(-np.trace(_sigma(sigma0)) / 2) + 0.0   # + 0.0: no -0.0 for an unstressed packing


def energy_density_from_cauchy(C_mandel, sigma0) -> np.ndarray:
    """(3, 3) Mandel energy-density tensor (jax-md's) from our Cauchy-increment tensor and the
    pre-stress ``sigma0`` (2, 2) [N/m, tension positive]: ``C - P(sigma0)``."""
    return _mandel(C_mandel) - prestress_correction(_sigma(sigma0))


def cauchy_from_energy_density(C_energy, sigma0) -> np.ndarray:
    """(3, 3) Mandel Cauchy-increment tensor (ours) from an energy-density tensor: ``C_U + P(sigma0)``."""
    return _mandel(C_energy, "C_energy") + prestress_correction(_sigma(sigma0))


def jaxmd_moduli(K, G, p) -> tuple[float, float]:
    """jax-md's ``(B, G)`` from our Cauchy-increment ``(K, G)`` at pressure ``p`` [N/m]:
    ``B = K - p/2``, ``G_U = G + p/2``."""
    return float(K) - 0.5 * float(p), float(G) + 0.5 * float(p)


def moduli_from_jaxmd(B, G_U, p) -> tuple[float, float]:
    """Our ``(K, G)`` from jax-md's ``(B, G)`` at pressure ``p`` [N/m]: ``K = B + p/2``, ``G = G_U - p/2``."""
    return float(B) + 0.5 * float(p), float(G_U) - 0.5 * float(p)


def jaxmd_tensor(C_mandel, sigma0) -> np.ndarray:
    """(2, 2, 2, 2) tensor ``C_ijkl`` as ``jax_md.elasticity.athermal_moduli`` returns it, from our
    (3, 3) Mandel Cauchy-increment tensor and the pre-stress ``sigma0`` (2, 2) [N/m]."""
    return mandel_to_tensor(energy_density_from_cauchy(C_mandel, sigma0))


def tensor_from_jaxmd(C, sigma0) -> np.ndarray:
    """Our (3, 3) Mandel Cauchy-increment tensor from jax-md's (2, 2, 2, 2) ``C_ijkl`` and ``sigma0``."""
    C = np.asarray(C, dtype=float)
    if C.shape != (2, 2, 2, 2):
        raise ValueError(f"C must be jax-md's (2, 2, 2, 2) elastic tensor, got shape {C.shape}")
    return cauchy_from_energy_density(tensor_to_mandel(C), sigma0)


def kn_from_oval(kn_oval):
    """Force per unit overlap [N/m] of Kuhn's OVAL stiffness (which multiplies half the overlap)."""
    return 0.5 * np.asarray(kn_oval, dtype=float)


def kn_to_oval(kn):
    """OVAL's ``kn`` for a force per unit overlap ``kn`` [N/m] (inverse of :func:`kn_from_oval`)."""
    return 2.0 * np.asarray(kn, dtype=float)


def lammps_kt(kn, kt=None):
    """LAMMPS ``gran/*`` tangential stiffness [N/m]: ``kt``, or ``2/7 kn`` when ``kt`` is None (``NULL``);
    scalars or arrays of any shape (broadcast)."""
    return LAMMPS_KT_RATIO * np.asarray(kn, dtype=float) if kt is None else np.asarray(kt, dtype=float)
