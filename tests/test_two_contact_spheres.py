"""Frictional spheres with exactly two contacts carry stiffness (the finding of LAMMPS's 3D strain
probes, docs/spheres.md "What the probes found"), checked on a closed form without LAMMPS.

A periodic straight chain of frictional spheres along x (three spheres per cell, each touching its
two neighbours, one of them across the cell boundary: two contacts per sphere, branch length l): every sphere can twist about the
chain's axis (the one free motion of a sphere between two contacts), but the chain transmits the
axial force, C_xx = kn l^2 Nc / V, which the rattler rule (fewer than 2 contacts with friction)
keeps, while the former 3D rule (fewer than 3) removed every sphere and returned no stiffness."""
import dataclasses
import warnings

import numpy as np
import pytest

from dem.analysis.stiffness import stiffness
from microhom.kinematics import assemble
from microhom.network import from_overlaps


def test_a_chain_of_two_contact_spheres_carries_its_axial_stiffness():
    l, side, kn = 0.999, 5.0, 2.0
    x = np.array([[0.0, 1.0, 1.0], [l, 1.0, 1.0], [2 * l, 1.0, 1.0]])
    net = from_overlaps(x, np.full(3, 0.5), np.diag([3 * l, side, side]), kn=kn, kt=kn, tolerance=0.0)
    assert net.n_contacts == 3 and np.all(np.bincount(net.pairs.ravel()) == 2)
    closed = kn * l ** 2 * 3 / (3 * l * side * side)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # floppy in every other direction, flagged
        default = stiffness(net)                 # the rule: frictional particles need 2 contacts
        old = stiffness(net, min_contacts=3)     # the former 3D rule (d = 3) removed every sphere
    assert default.n_rattlers == 0 and default.C_mandel[0, 0] == pytest.approx(closed, rel=1e-12)
    assert old.n_rattlers == 3 and np.all(old.C_mandel == 0)


def _zigzag(dim, beta, fn=1e-3, l=0.999):
    """Periodic zigzag chain along x (4 particles per cell, radius 0.5, branch l at +-beta from x),
    every particle with two contacts; compressive normal force fn on every contact."""
    x = np.array([[k * l * np.cos(beta), (k % 2) * l * np.sin(beta), 1.0] for k in range(4)])[:, :dim]
    cell = np.diag([4 * l * np.cos(beta), 6.0, 6.0][:dim])
    net = from_overlaps(x + 2.0, np.full(4, 0.5), cell, kn=1.0, kt=1.0, tolerance=0.0)
    return dataclasses.replace(net, fn=np.full(net.n_contacts, fn))


def _block(net, p, prestress):
    """The Hessian of particle p alone, its neighbours held fixed: translations, then rotations."""
    asm = assemble(net, prestress=prestress, pin=False)
    d, r, n = net.dim, (3 if net.dim == 3 else 1), net.n_particles
    idx = asm.dof_map[np.r_[d * p + np.arange(d), d * n + r * p + np.arange(r)]]
    return asm.H.toarray()[np.ix_(idx, idx)]


@pytest.mark.parametrize("beta", [0.0, 0.3])
def test_the_one_free_motion_of_a_two_contact_sphere_and_its_prestress_curvature(beta):
    """Sphere 1 between fixed neighbours at n1 = (-cos b, -sin b, 0), n2 = (cos b, -sin b, 0), arm
    a = l/2: its one zero mode is the turn about the chord (omega = x, u = a sin b z), and the
    solver's pre-stress term (normal forces only) gives it the curvature -rho^2 sum fn/l,
    rho = a sin b (docs/spheres.md, "Rattlers in 3D"); zero for opposite contacts (b = 0)."""
    l, fn = 0.999, 1e-3
    net = _zigzag(3, beta, fn, l)
    q = np.r_[0.0, 0.0, l / 2 * np.sin(beta), 1.0, 0.0, 0.0]
    H0, Hp = _block(net, 1, False), _block(net, 1, True)
    ev = np.linalg.eigvalsh(H0)
    assert abs(ev[0]) < 1e-12 and ev[1] > 0.1                  # one zero mode, rank 5
    assert np.abs(H0 @ q).max() < 1e-12                          # ... and it is the turn about the chord
    rho = l / 2 * np.sin(beta)
    assert q @ Hp @ q == pytest.approx(-rho ** 2 * 2 * fn / l, rel=1e-12, abs=1e-15)
    assert (np.linalg.eigvalsh(Hp)[0] < 0) == (beta > 0)


def test_the_2d_analogue_a_compressed_two_contact_disk_is_held_rigid():
    """A frictional disk with two contacts under the same compression: no zero mode and no negative
    one (three unknowns, four contact constraints of rank 3; the geometric term fn/l is 1e-3 of kt)."""
    net = _zigzag(2, 0.3)
    ev0, evp = np.linalg.eigvalsh(_block(net, 1, False)), np.linalg.eigvalsh(_block(net, 1, True))
    assert ev0[0] > 0.1 and evp[0] > 0.1 and abs(evp[0] - ev0[0]) < 2 * 2e-3 / 0.999


def test_the_finite_turn_about_the_chord_presses_both_contacts():
    """The same turn done finitely (Rodrigues rotation by phi about the chord through the contact
    points c_k = a n_k, neighbours' centres fixed at l_k n_k): the centre distances obey the closed
    form d_k^2 = l_k^2 - 2 rho^2 (1 - cos phi) (l_k / a - 1), rho = a |n_1 + n_2| / 2, so both
    overlaps grow at second order (docs/spheres.md, "Rattlers in 3D")."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        n1, n2 = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
        a, ls, phi = 0.5, (0.9, 1.1), rng.uniform(-1, 1)
        c1, c2 = a * n1, a * n2
        e = (c1 - c2) / np.linalg.norm(c1 - c2)
        K = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
        R = np.eye(3) + np.sin(phi) * K + (1 - np.cos(phi)) * K @ K
        centre = R @ (-c1) + c1
        rho = a * np.linalg.norm(n1 + n2) / 2
        for n, l in ((n1, ls[0]), (n2, ls[1])):
            d2 = np.sum((l * n - centre) ** 2)
            assert d2 == pytest.approx(l ** 2 - 2 * rho ** 2 * (1 - np.cos(phi)) * (l / a - 1), rel=1e-12)


def test_the_certificate_preconditioner_shifts_only_the_turns():
    """block_preconditioner(floppy_shift=True): each two-contact sphere's singular block gets a
    positive eigenvalue on its turn (a null vector of H without pre-stress), nothing else changes."""
    from microhom.hierarchy import block_preconditioner
    net = _zigzag(3, 0.3)
    asm = assemble(net, pin=False)
    M0, _, _, bad0 = block_preconditioner(asm)
    M1, _, _, bad1 = block_preconditioner(asm, floppy_shift=True)
    assert bad0 == 4 and bad1 == 0
    assert np.linalg.eigvalsh(M1.toarray())[0] > 0.1
    dM = (M1 - M0).toarray()
    w, V = np.linalg.eigh(dM)
    turns = V[:, w > 1e-9]
    assert turns.shape[1] == 4 and np.all(w > -1e-12)
    assert np.abs(asm.H @ turns).max() < 1e-12                    # the shifted directions are floppy
