"""dem.measure against closed forms: a compressed triangular lattice, rotations, periodic images."""
import math

import numpy as np
import pytest
from dataclasses import replace

from dem import measure
from microhom import lattices
from microhom.network import from_overlaps


def compressed_triangular(angle=0.0, overlap=0.01, kn=1e4, nx=8, ny=8):
    """A triangular lattice of unit disks with centre spacing 1 - overlap; fn = kn * overlap."""
    lat = lattices.triangular(nx, ny, angle=angle)
    s = 1.0 - overlap
    net = from_overlaps(lat.positions * s, 0.5, lat.cell * s, kn=kn, kt=kn)
    fn = kn * (1.0 - net.lengths)
    return replace(net, fn=fn, ft=np.zeros_like(fn))


def test_triangular_lattice_pressure_closed_form():
    kn, ov = 1e4, 0.01
    net = compressed_triangular(overlap=ov, kn=kn)
    d = 1.0 - ov
    s = measure.stress(net)
    p_closed = math.sqrt(3) * kn * ov / d  # p = sqrt3 fn / d for the triangular lattice
    assert s[0, 0] == pytest.approx(-p_closed, rel=1e-12)
    assert s[1, 1] == pytest.approx(-p_closed, rel=1e-12)
    assert abs(s[0, 1]) < 1e-12 * p_closed
    assert measure.pressure(net) == pytest.approx(p_closed, rel=1e-12)
    # force balance: every particle's resultant is zero (unbalanced force 0)
    F = measure.contact_forces(net)
    res = np.zeros((net.n_particles, 2))
    np.add.at(res, net.pairs[:, 1], F)
    np.add.at(res, net.pairs[:, 0], -F)
    assert np.max(np.abs(res)) < 1e-12 * kn * ov


def test_rigid_rotation_rotates_stress_and_keeps_forces():
    a = compressed_triangular(angle=0.0)
    b = compressed_triangular(angle=0.7)
    assert np.allclose(np.sort(a.fn), np.sort(b.fn), rtol=1e-12)
    R = np.array([[math.cos(0.7), -math.sin(0.7)], [math.sin(0.7), math.cos(0.7)]])
    assert np.allclose(measure.stress(b), R @ measure.stress(a) @ R.T, atol=1e-9)


def test_translation_by_cell_vector_measures_the_same():
    rng = np.random.default_rng(0)
    net = compressed_triangular()
    pos = net.positions + rng.normal(scale=0.003, size=net.positions.shape)
    a = from_overlaps(pos, 0.5, net.cell)
    b = from_overlaps(pos + net.cell @ [1, -2], 0.5, net.cell)
    a = replace(a, fn=1e4 * (1 - a.lengths), ft=np.zeros(a.n_contacts))
    b = replace(b, fn=1e4 * (1 - b.lengths), ft=np.zeros(b.n_contacts))
    sa, sb = measure.summary(a).table(), measure.summary(b).table()
    for k, v in sa.items():
        if isinstance(v, float):
            assert sb[k] == pytest.approx(v, rel=1e-9, abs=1e-12), k


def test_delaunay_degree_is_six_and_psi6():
    rng = np.random.default_rng(2)
    L = 20.0
    for cell in (np.diag([L, L]), np.array([[L, 6.0], [0.0, L]])):
        net = from_overlaps(rng.uniform(0, L, (300, 2)), 0.5, cell)
        nb = measure.delaunay_neighbours(net)
        assert nb.mean_degree == pytest.approx(6.0, abs=1e-12)  # Euler: exactly 6 on a torus
        assert measure.hexatic_order(net, nb).psi6 < 0.2
    lat = lattices.triangular(8, 8, angle=0.3)
    assert measure.hexatic_order(lat).psi6 == pytest.approx(1.0, abs=1e-12)


def test_coordination_and_fabric_of_square_lattice():
    net = lattices.square(5, 5)
    c = measure.coordination(net)
    assert c.z == 4 and c.n_rattlers == 0 and c.hist[4] == 25
    f = measure.fabric(net)
    assert np.allclose(f.F, 0.5 * np.eye(2)) and abs(f.anisotropy) < 1e-12


def test_measurements_do_not_mutate():
    net = compressed_triangular()
    before = {k: np.array(getattr(net, k), copy=True) for k in ("positions", "fn", "branch")}
    measure.summary(net)
    for k, v in before.items():
        assert np.array_equal(getattr(net, k), v)
    assert not net.positions.flags.writeable


def test_forces_required():
    with pytest.raises(ValueError, match="fn"):
        measure.stress(lattices.triangular())
