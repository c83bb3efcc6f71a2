"""Gas in the dislocations: the two readings of the paper.

Units: Pa, N/m per m of thickness. Tension positive.

* ``gas="interface"``: effective stress on the dislocation interfaces, sn' = sn + p_g in the
  strength check; once a crack opens its faces carry p_g until it opens more than
  ``gas_vent_opening`` (the gas has escaped). An active load only after failure.
* ``gas="eigenstrain"``: the paper's wording, "the zones of cracked coal seam are simulated by
  eigenstrains applied inside of the elements" (its eq. (1), the volume term with the eigenstrain
  mu). An isotropic eigenstrain whose eigenstress D:mu is p_g I puts, by the hybrid element's exact
  constant-strain part (A B^T D mu), the force p_g n_k L on every edge node k of each cell along
  a dislocation: an active load before any failure. It is part of the virgin equilibrium (the gas
  was there before the adit), so excavation releases it with the rest.
* ``gas="released"``: the same eigenstress, but released *with the excavation*: it is not in the
  virgin equilibrium and acts as (1 - g(t)) times its forces, g the Eshelby factor of the face
  (1 virgin, 0 excavated). The gas of the cracked zone pushes only as the face passes, so it is a
  load after excavation (the ``eigenstrain`` reading, inside the virgin equilibrium, drives
  nothing after it).
* ``gas="none"``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["interface_pressure", "gassy_cells", "eigenstrain_forces", "release_gas_with_excavation"]


def interface_pressure(p, is_disl):
    """(M,) gas pressure on each interface [Pa] for the interface reading, else zeros."""
    return np.where(is_disl & (p.gas == "interface"), p.gas_pressure, 0.0).astype(float)


def gassy_cells(n_cells, ci, cj, is_disl, is_coal):
    """(N,) bool: coal cells with at least one dislocation interface (the cracked zone)."""
    m = np.zeros(n_cells, bool)
    m[ci[is_disl]] = True
    m[cj[is_disl]] = True
    return m & is_coal


def eigenstrain_forces(cells, normals, L, p_g):
    """(N,12) edge forces [N/m] of the eigenstress p_g I in ``cells`` (bool (N,)): p_g n_k L on
    node k of each such cell, zero elsewhere. ``normals`` (6,2) outward edge normals, ``L`` edge
    length [m]."""
    f = np.zeros((len(cells), 12))
    f[cells, 0::2] = p_g * L * normals[None, :, 0]
    f[cells, 1::2] = p_g * L * normals[None, :, 1]
    return f


def release_gas_with_excavation(model, f_gas):
    """Apply the eigenstress forces ``f_gas`` (N,12) [N/m] of the excavated model as (1 - g(t)) f_gas:
    a dead load f_gas (booked in W_dead) plus wall loads -f_gas scaled by g(t) like the Eshelby forces
    (booked in W_E), so the energy accounts need nothing new. In place; returns the model."""
    c, r = np.nonzero((f_gas[:, 0::2] != 0.0) | (f_gas[:, 1::2] != 0.0))
    if not len(c):
        return model
    model.fext = model.fext + f_gas
    model.wc = np.concatenate([model.wc, c.astype(np.int64)])
    model.wk = np.concatenate([model.wk, r.astype(np.int64)])
    model.FE0 = np.concatenate([model.FE0, -np.stack([f_gas[c, 2 * r], f_gas[c, 2 * r + 1]], axis=1)])
    return model
