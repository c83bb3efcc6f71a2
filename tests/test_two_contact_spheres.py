"""Frictional spheres with exactly two contacts carry stiffness (the finding of LAMMPS's 3D strain
probes, docs/spheres.md "What the probes found"), checked on a closed form without LAMMPS.

A periodic straight chain of frictional spheres along x (three spheres per cell, each touching its
two neighbours, one of them across the cell boundary: two contacts per sphere, branch length l): every sphere can twist about the
chain's axis (the one free motion of a sphere between two contacts), but the chain transmits the
axial force, C_xx = kn l^2 Nc / V, while the default 3D rattler rule (fewer than 3 contacts with
friction) removes every sphere and returns no stiffness at all."""
import warnings

import numpy as np
import pytest

from dem.analysis.stiffness import stiffness
from microhom.network import from_overlaps


def test_a_chain_of_two_contact_spheres_carries_its_axial_stiffness():
    l, side, kn = 0.999, 5.0, 2.0
    x = np.array([[0.0, 1.0, 1.0], [l, 1.0, 1.0], [2 * l, 1.0, 1.0]])
    net = from_overlaps(x, np.full(3, 0.5), np.diag([3 * l, side, side]), kn=kn, kt=kn, tolerance=0.0)
    assert net.n_contacts == 3 and np.all(np.bincount(net.pairs.ravel()) == 2)
    closed = kn * l ** 2 * 3 / (3 * l * side * side)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # floppy in every other direction, flagged
        kept = stiffness(net, min_contacts=2)
        default = stiffness(net)
    assert kept.n_rattlers == 0 and kept.C_mandel[0, 0] == pytest.approx(closed, rel=1e-12)
    assert default.n_rattlers == 3 and np.all(default.C_mandel == 0)
