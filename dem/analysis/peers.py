"""Elastic tensors in the conventions of peer codes, from positions and radii in one call.

:func:`jaxmd_elasticity` reproduces what ``jax_md.elasticity.athermal_moduli`` returns for a
packing of jax-md soft disks (``energy.soft_sphere``, harmonic by default): it builds the network
with :func:`microhom.network.from_overlaps` and the law :class:`microhom.laws.SoftSphere` (so the
forces ``fn`` are consistent with the stiffnesses ``kn``), solves the exact pre-stressed linear
response (:func:`dem.analysis.stiffness.stiffness`, ``prestress=True``) and converts the Cauchy-increment
tensor to jax-md's energy-density tensor (:mod:`microhom.conventions`: ``B = K - p/2``,
``G_U = G + p/2``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from microhom import conventions
from microhom.kinematics import stress0
from microhom.laws import SoftSphere
from microhom.network import ContactNetwork, from_overlaps
from microhom.results import Result
from microhom.tensors import isotropic_moduli, mandel_to_tensor

from .stiffness import StiffnessResult, stiffness

__all__ = ["PeerModuli", "jaxmd_elasticity"]


@dataclass(frozen=True, eq=False)
class PeerModuli(Result):
    """An elastic tensor in a peer's convention and ours, with the pre-stress that links them.

    Attributes
    ----------
    convention : str
        The peer (``"jax-md"``).
    C : (2, 2, 2, 2) array
        The peer's tensor ``C_ijkl`` [N/m] (jax-md: second derivative of ``U/V0`` with respect to
        the linear strain, non-affine relaxation included).
    C_mandel : (3, 3) array
        The same in Mandel form over ``[xx, yy, sqrt2 xy]`` [N/m].
    B, G : float
        The peer's isotropic moduli [N/m] (jax-md's ``extract_isotropic_moduli``).
    C_cauchy_mandel : (3, 3) array
        Our Cauchy-increment tensor [N/m] (:mod:`dem.analysis.stiffness`, pre-stress on).
    K, G_cauchy : float
        Our isotropic moduli [N/m]: ``K = B + p/2``, ``G_cauchy = G - p/2``.
    pressure : float
        ``p = -tr(sigma0)/2`` [N/m], compression positive.
    sigma0 : (2, 2) array
        Pre-stress [N/m], tension positive.
    n_particles, n_contacts : int
        Particles and overlapping pairs of the packing.
    n_rattlers, n_floppy, n_unstable : int
        From the stiffness solve (``n_unstable > 0``: the packing is not a stable minimum and no
        tensor is meaningful).
    network : microhom.network.ContactNetwork
        The contact network built (not exported).
    stiffness : dem.analysis.stiffness.StiffnessResult
        The full stiffness solve (not exported).
    """

    convention: str
    C: np.ndarray
    C_mandel: np.ndarray
    B: float
    G: float
    C_cauchy_mandel: np.ndarray
    K: float
    G_cauchy: float
    pressure: float
    sigma0: np.ndarray
    n_particles: int
    n_contacts: int
    n_rattlers: int
    n_floppy: int
    n_unstable: int
    network: ContactNetwork = field(repr=False, metadata={"export": False})
    stiffness: StiffnessResult = field(repr=False, metadata={"export": False})


def jaxmd_elasticity(positions, radii, box, *, epsilon=1.0, alpha=2.0, fractional_coordinates=False,
                     solver="splu") -> PeerModuli:
    """jax-md's elastic tensor of a periodic packing of soft disks, computed exactly.

    Parameters
    ----------
    positions : (N, 2) particle centres [m]; fractional (in [0, 1)^2) if ``fractional_coordinates``
        (jax-md's ``periodic_general`` default), Cartesian otherwise.
    radii : (N,) radii [m] (jax-md's ``sigma`` of a pair is ``r_i + r_j``), or a scalar.
    box : (2, 2) jax-md box, columns = cell vectors [m] (a scalar L means a square L x L box).
    epsilon : energy scale [J/m] > 0; alpha : soft-sphere exponent >= 2 (2 harmonic, 2.5 Hertzian).
    solver : passed to :func:`dem.analysis.stiffness.stiffness`.
    """
    box = np.asarray(box, dtype=float)
    if box.ndim == 0:
        box = np.eye(2) * float(box)
    if box.shape != (2, 2):
        raise ValueError(f"box must be a scalar or a (2, 2) matrix (columns = cell vectors), got shape {box.shape}")
    x = np.asarray(positions, dtype=float)
    if fractional_coordinates:
        x = x @ box.T
    net = from_overlaps(x, radii, box, law=SoftSphere(epsilon=epsilon, alpha=alpha))
    res = stiffness(net, prestress=True, solver=solver)
    s0 = stress0(net) if net.n_contacts else np.zeros((2, 2))
    Cu = conventions.energy_density_from_cauchy(res.C_mandel, s0)
    B, G = isotropic_moduli(Cu)
    return PeerModuli(convention="jax-md", C=mandel_to_tensor(Cu), C_mandel=Cu, B=B, G=G,
                      C_cauchy_mandel=np.array(res.C_mandel), K=res.K, G_cauchy=res.G,
                      pressure=conventions.pressure_of(s0), sigma0=s0, n_particles=net.n_particles,
                      n_contacts=net.n_contacts, n_rattlers=res.n_rattlers, n_floppy=res.n_floppy,
                      n_unstable=res.n_unstable, network=net, stiffness=res)
