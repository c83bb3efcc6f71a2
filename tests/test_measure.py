"""dem.analysis.measure against closed forms: a compressed triangular lattice, rotations, periodic images."""
import math

import numpy as np
import pytest
from dataclasses import replace

from dem.analysis import measure
from microhom import lattices
from microhom.network import from_overlaps, from_pairs


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
    # an anisotropic state: jittered positions, random normal and tangential forces, rotated as a
    # whole (the lattice's isotropic stress would be unchanged by any rotation)
    rng = np.random.default_rng(4)
    pos = a.positions + rng.normal(scale=0.002, size=a.positions.shape)
    net = from_overlaps(pos, 0.5, a.cell)
    net = replace(net, fn=rng.uniform(0.5, 2.0, net.n_contacts), ft=rng.normal(size=net.n_contacts))
    R = np.array([[math.cos(0.7), -math.sin(0.7)], [math.sin(0.7), math.cos(0.7)]])
    rot = from_pairs(pos @ R.T, 0.5, R @ net.cell, net.pairs, shifts=net.image_shifts(), fn=net.fn, ft=net.ft)
    s = measure.stress(net, symmetric=False)
    assert abs(s[0, 0] - s[1, 1]) > 1e-3 * abs(s[0, 0]) and abs(s[0, 1] - s[1, 0]) > 1e-6 * abs(s[0, 0])
    assert np.allclose(measure.stress(rot, symmetric=False), R @ s @ R.T, rtol=0, atol=1e-13 * np.abs(s).max())


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


def test_force_statistics_and_shear_of_the_lattice_are_exact():
    kn, ov = 1e4, 0.01
    net = compressed_triangular(overlap=ov, kn=kn)
    fs = measure.force_statistics(net)
    assert fs.fn_mean == pytest.approx(kn * ov, rel=1e-12) and fs.fn_std < 1e-12 * kn * ov
    assert fs.fn_max == pytest.approx(kn * ov, rel=1e-12)
    assert fs.tension_contacts == 0 and fs.sliding_fraction == 0.0 and fs.ft_over_fn_mean == 0.0
    table = measure.summary(net).table()
    assert table["shear_stress"] < 1e-12 * table["pressure"]
    assert table["nbar_delaunay"] == pytest.approx(6.0, abs=1e-12)
    assert table["nbar_near_0.1D"] == pytest.approx(6.0, abs=1e-12)   # all six neighbours touch
    assert table["psi6"] == pytest.approx(1.0, abs=1e-12)


def test_summary_table_keys_are_those_of_the_csv():
    """packing_summary.csv's 'measure' rows: the statistics, then these keys in this order
    (``sliding_fraction`` of the force statistics overwrites the statistics' entry in place)."""
    table = measure.summary(compressed_triangular()).table()
    tail = ["sxx", "syy", "sxy", "pressure", "shear_stress", "fn_mean", "fn_std", "fn_max",
            "ft_over_fn_mean", "tension_contacts", "fraction_above_mean",
            "fabric_anisotropy", "nbar_delaunay", "nbar_near_0.1D", "psi6", "psi6_local"]
    keys = list(table)
    assert keys[-len(tail):] == tail and "sliding_fraction" in keys
    assert all(np.isscalar(v) or v is None for v in table.values())


def test_fabric_of_a_chain_rotates_with_it():
    """Contacts along one direction only: F = e e, anisotropy 2, major direction = the chain's."""
    for angle in (0.0, 0.3, -1.1):
        net = lattices.square(5, 5, angle=angle)
        along = np.abs(net.normals @ [np.cos(angle), np.sin(angle)]) > 0.5
        f = measure.fabric(net.select_contacts(along))
        e = np.array([np.cos(angle), np.sin(angle)])
        assert np.allclose(f.F, np.outer(e, e), atol=1e-14)
        assert f.anisotropy == pytest.approx(2.0, abs=1e-14)
        assert np.isclose(np.sin(f.direction - angle), 0.0, atol=1e-12)
    assert np.isnan(measure.fabric(net.select_contacts(np.zeros(net.n_contacts, bool))).F).all()


def test_coordination_with_a_rattler_is_exact():
    """Square lattice (frictional: rattler threshold 2) with particle 0 left one contact of four:
    it is the one rattler; its three former neighbours keep 3 contacts, the fourth loses one."""
    net = lattices.square(5, 5)
    on0 = np.flatnonzero((net.pairs == 0).any(axis=1))
    keep = np.ones(net.n_contacts, bool)
    keep[on0[1:]] = False
    c = measure.coordination(net.select_contacts(keep))
    assert c.n_rattlers == 1 and c.rattler_fraction == pytest.approx(1 / 25)
    assert c.z_all == pytest.approx(2 * 47 / 25) and c.z == pytest.approx(2 * 46 / 24)
    assert c.hist_all.tolist() == [0, 1, 0, 3, 21] and c.hist.tolist() == [0, 0, 0, 4, 20]
    d = c.as_dict()
    assert d["hist"] == [0, 0, 0, 4, 20] and c.to_frame().shape[0] == 1
