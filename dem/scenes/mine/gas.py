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
* ``gas="none"``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["interface_pressure", "gassy_cells", "eigenstrain_forces"]


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
