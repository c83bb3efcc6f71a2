"""microhom.network and microhom.periodic on exact cases: lattices, images, sheared cells, errors."""
import numpy as np
import pytest

from microhom import lattices, periodic
from microhom.network import ContactNetwork, from_overlaps, from_pairs


def test_wrap_fractional_and_images_round_trip():
    rng = np.random.default_rng(0)
    h = np.array([[4.0, 1.5], [0.3, 3.0]])
    o = np.array([-1.0, 2.0])
    x = rng.uniform(-20, 20, (50, 2))
    xw, k = periodic.wrap(x, h, o)
    assert np.allclose(xw + k @ h.T, x, atol=1e-12)
    s = periodic.fractional(xw, h, o)
    assert np.all((s >= 0) & (s < 1))
    d = rng.uniform(-10, 10, (50, 2))
    m = periodic.minimum_image(d, h)
    assert np.all(np.abs(periodic.fractional(m, h)) <= 0.5 + 1e-12)
    k = periodic.image_shifts(m, d, h)                 # m is d moved by whole cell vectors
    assert np.allclose(d + k @ h.T, m, atol=1e-12)
    assert np.allclose(periodic.heights(np.diag([3.0, 5.0])), [3.0, 5.0])


def test_boundary_images_are_the_points_near_the_faces():
    h = np.diag([10.0, 8.0])
    x = np.array([[0.5, 4.0], [5.0, 4.0], [9.8, 7.9]])
    pts, owner = periodic.boundary_images(x, h, margin=1.0)
    assert np.array_equal(pts[:3], x) and np.array_equal(owner[:3], [0, 1, 2])
    # particle 0 near x = 0: one image at x + 10; particle 2 near the (10, 8) corner: 3 images
    assert sorted(owner[3:].tolist()) == [0, 2, 2, 2]
    assert np.allclose(pts[3:][owner[3:] == 0], [[10.5, 4.0]])
    many, _ = periodic.boundary_images(x, h, margin=100.0)   # beyond the heights: all 8 copies
    assert many.shape[0] == 9 * 3


@pytest.mark.parametrize("make,z", [(lattices.triangular, 6), (lattices.square, 4), (lattices.honeycomb, 3)])
def test_lattice_contacts_in_orthogonal_and_sheared_cells(make, z):
    net = make(angle=0.0)
    assert np.all(net.contact_counts() == z)
    assert np.allclose(net.lengths, 1.0, rtol=1e-12)
    # the same periodic structure described by a sheared cell (b -> b + a): same contacts
    cell = net.cell.copy()
    cell[:, 1] += cell[:, 0]
    sheared = from_overlaps(net.positions, 0.5, cell)
    assert np.array_equal(sheared.pairs, net.pairs)
    assert np.allclose(sheared.branch, net.branch, atol=1e-12)


def test_from_pairs_rejects_bad_input():
    lat = lattices.square(4, 4)
    with pytest.raises(ValueError, match="pairs must be a"):
        from_pairs(lat.positions, 0.5, lat.cell, np.array([0, 1]))
    with pytest.raises(ValueError, match="outside"):
        from_pairs(lat.positions, 0.5, lat.cell, [[0, 99]])
    with pytest.raises(ValueError, match="shifts must have shape"):
        from_pairs(lat.positions, 0.5, lat.cell, [[0, 1]], shifts=[[0, 0], [0, 0]])
    with pytest.raises(ValueError, match="ambiguous"):     # 1.5 x 1.5 cell, disks of diameter 1
        from_pairs([[0.0, 0.0], [1.0, 0.0]], 0.5, np.eye(2) * 1.5, [[0, 1]])
    two = from_pairs([[0.0, 0.0], [1.0, 0.0]], 0.5, np.eye(2) * 1.5, [[0, 1]], shifts=[[-1, 0]])
    assert np.allclose(two.branch, [[-0.5, 0.0]])
    with pytest.raises(ValueError, match="sliding has shape"):
        from_pairs(lat.positions, 0.5, lat.cell, [[0, 1]], sliding=[True, False])


def test_network_checks_per_contact_lengths():
    lat = lattices.square(4, 4)
    with pytest.raises(ValueError, match=rf"kn has shape \(3,\) but the network has {lat.n_contacts} contacts"):
        ContactNetwork(positions=lat.positions, radii=lat.radii, cell=lat.cell, pairs=lat.pairs,
                       branch=lat.branch, kn=np.ones(3), kt=1.0, sliding=False)
    assert np.all(lat.overlaps == pytest.approx(0.0, abs=1e-12))
