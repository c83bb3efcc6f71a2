"""Structural sums and statistics on hand-built networks with known answers."""
import math

import numpy as np
import pytest

from microhom import lattices
from microhom.moduli import predict_from_network
from microhom.network import ContactNetwork, from_overlaps
from microhom.structural_sums import isotropic_fit, network_statistics, particle_sums, rattlers


def _stress_moduli_from_A4(A4_mean, area_per_particle):
    """Mean-field stiffness sigma_rq = (2v)^-1 A_rijq E_ij -> C (2,2,2,2), by a plain loop."""
    C = np.zeros((2, 2, 2, 2))
    for r in range(2):
        for q in range(2):
            for i in range(2):
                for j in range(2):
                    C[r, q, i, j] = A4_mean[r, i, j, q] / (2 * area_per_particle)
    # strains are symmetric: only the minor-symmetric part acts (and sigma is symmetrised)
    C = 0.5 * (C + C.transpose(0, 1, 3, 2))
    return 0.5 * (C + C.transpose(1, 0, 2, 3))


@pytest.mark.parametrize("kt", [0.0, 0.3, 1.0])
@pytest.mark.parametrize("angle", [0.0, 0.37])
def test_triangular_lattice_odd_sums_vanish_and_mean_field_exact(kt, angle):
    net = lattices.triangular(6, 6, kn=1.0, kt=kt, angle=angle)
    ps = particle_sums(net)
    assert np.max(np.abs(ps.A3)) < 1e-13
    assert np.max(np.abs(ps.W)) < 1e-14 and np.max(np.abs(ps.V)) < 1e-13
    v = net.area / net.n_particles
    C = _stress_moduli_from_A4(ps.A4.mean(axis=0), v)
    K = (C[0, 0, 0, 0] + C[1, 1, 1, 1] + 2 * C[0, 0, 1, 1]) / 4
    G = ((C[0, 0, 0, 0] + C[1, 1, 1, 1] - 2 * C[0, 0, 1, 1]) / 4 + C[0, 1, 0, 1]) / 2
    assert K == pytest.approx(math.sqrt(3) / 2, rel=1e-12)
    assert G == pytest.approx(math.sqrt(3) / 4 * (1 + kt), rel=1e-12)
    # the lattice's A4 is exactly the isotropic mean (37) with Nc = 6
    vb, eb = isotropic_fit(ps.A4.mean(axis=0))
    assert vb == pytest.approx(6 * (1 + 3 * kt) / 8, rel=1e-12)
    assert eb == pytest.approx(6 * (1 - kt) / 8, abs=1e-12)
    assert np.allclose(ps.B, -6 * kt, rtol=1e-12, atol=1e-13)
    p = predict_from_network(net)
    assert float(p.K) == pytest.approx(math.sqrt(3) / 2, rel=1e-12)  # r = 0: correction vanishes


def test_square_lattice_sums():
    net = lattices.square(5, 5, kn=2.0, kt=0.5)
    ps = particle_sums(net)
    A = ps.A4[0]
    assert A[0, 0, 0, 0] == pytest.approx(2 * 2.0)  # two horizontal contacts, K_11 = kn, c1^2 = 1
    assert A[0, 0, 1, 1] == pytest.approx(2 * 0.5)  # two vertical contacts, K_11 = kt
    assert A[0, 1, 0, 1] == pytest.approx(0.0, abs=1e-15)
    C = _stress_moduli_from_A4(ps.A4.mean(axis=0), 1.0)
    assert C[0, 0, 0, 0] == pytest.approx(2.0) and C[0, 0, 1, 1] == pytest.approx(0.0, abs=1e-15)
    assert C[0, 1, 0, 1] == pytest.approx(0.5 / 2)  # C1212 = kt/2 (affine = exact for this lattice)
    st = network_statistics(net)
    assert st.nc == 4 and st.r == 0 and st.n_rattlers == 0


def test_one_sided_particle_by_hand():
    # particle 0 touched by two disks at +-60 degrees on its right side only; kt = 0
    D = 1.0
    n1 = np.array([0.5, math.sqrt(3) / 2])
    n2 = np.array([0.5, -math.sqrt(3) / 2])
    pos = np.array([[0.0, 0.0], D * n1, D * n2])
    net = ContactNetwork(positions=pos, radii=np.full(3, 0.5), cell=None, pairs=[[0, 1], [0, 2]],
                         branch=[D * n1, D * n2], kn=3.0, kt=0.0, sliding=False)
    ps = particle_sums(net)
    A3 = ps.A3[0]
    assert A3[0, 0, 0] == pytest.approx(3.0 * D * 2 / 8)  # kn D sum n1^3 = kn D/4
    assert A3[0, 1, 1] == pytest.approx(3.0 * D * 2 * 0.5 * 0.75)  # kn D sum n1 n2^2
    assert A3[1, 1, 0] == pytest.approx(A3[0, 1, 1]) and A3[1, 0, 1] == pytest.approx(A3[0, 1, 1])
    assert abs(A3[1, 1, 1]) < 1e-15 and abs(A3[0, 0, 1]) < 1e-15
    assert np.allclose(ps.W[0], [1 / math.pi, 0.0])
    assert np.allclose(ps.W[1], -n1 / math.pi) and np.allclose(ps.W[2], -n2 / math.pi)
    # V of particle 0: neighbours 1, 2 have one contact each -> V = W (Nc^nu = 1)
    assert np.allclose(ps.V[0], ps.W[0])
    assert np.allclose(ps.V[1], 2 * ps.W[1])  # its neighbour (particle 0) has 2 contacts
    assert abs(ps.B[0]) < 1e-14  # kt = 0: no moment coupling
    assert np.allclose(ps.Z[0], np.einsum("pstk->pkst", ps.A4[0]))  # singular B: Z = A


def test_Z_equals_direct_spin_relaxation():
    """Z E must equal the stress of a particle whose spin minimises its contact energy."""
    rng = np.random.default_rng(3)
    for trial in range(5):
        m = 5
        ang = rng.uniform(0, 2 * np.pi, m)
        n = np.stack([np.cos(ang), np.sin(ang)], 1)
        c = n * rng.uniform(0.9, 1.1, (m, 1))
        kn = rng.uniform(0.5, 2, m)
        kt = rng.uniform(0.1, 1, m)
        pos = np.vstack([[0, 0], c])
        net = ContactNetwork(positions=pos, radii=np.full(m + 1, 0.5), cell=None,
                             pairs=np.stack([np.zeros(m, int), np.arange(1, m + 1)], 1), branch=c,
                             kn=kn, kt=kt, sliding=False)
        Z = particle_sums(net).Z[0]
        E = rng.normal(size=(2, 2))
        E = E + E.T
        eps = np.array([[0.0, 1.0], [-1.0, 0.0]])

        def contact_forces(omega):
            f = []
            for k in range(m):
                K = kn[k] * np.outer(n[k], n[k]) + kt[k] * (np.eye(2) - np.outer(n[k], n[k]))
                delta = (E + eps * omega) @ c[k]
                f.append(K @ delta)
            return np.array(f)

        def energy(omega):
            return sum(0.5 * ((E + eps * omega) @ c[k]) @ f for k, f in enumerate(contact_forces(omega)))

        e0, e1, em = energy(0.0), energy(1.0), energy(-1.0)
        omega = -(e1 - em) / (2 * (e1 + em - 2 * e0))  # vertex of the parabola
        f = contact_forces(omega)
        sigma = sum(np.outer(f[k], c[k]) for k in range(m))  # sum K Delta (x) c
        assert np.allclose(np.einsum("pkst,st->pk", Z, E), sigma, rtol=1e-10, atol=1e-12)


def test_rattlers_iterative():
    # a chain 0-1-2-3 hanging off a rigid triangle 4-5-6 (each triangle node has 2 triangle contacts)
    pairs = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [4, 6]])
    pos = np.arange(14, dtype=float).reshape(7, 2)
    net = ContactNetwork(positions=pos, radii=np.full(7, 0.5), cell=None, pairs=pairs,
                         branch=np.tile([1.0, 0.0], (7, 1)), kn=1.0, kt=1.0, sliding=False)
    rat, active = rattlers(net, min_contacts=2)
    assert list(rat) == [True, True, True, True, False, False, False]  # peeled one by one
    assert list(active) == [False, False, False, False, True, True, True]
    st = network_statistics(net, min_contacts=2)
    assert st.n_rattlers == 4 and st.nc == 2.0 and st.r == 0.0
    assert st.nc_all == pytest.approx(2 * 7 / 7)


def test_periodic_wrap_and_sheared_cell():
    L = 4.0
    pos = np.array([[0.05, 2.0], [L - 0.9, 2.0], [2.0, 2.0]])
    net = from_overlaps(pos, 0.5, np.diag([L, L]), kn=1.0)
    assert net.n_contacts == 1
    assert np.allclose(net.branch[0], [-0.95, 0.0])  # from particle 0 to the image of 1 on its left
    assert np.array_equal(net.image_shifts()[0], [-1, 0])
    # the same physical contact in a sheared cell description of the same lattice of images
    h = np.array([[L, 1.3], [0.0, L]])
    net2 = from_overlaps(pos, 0.5, h, kn=1.0)
    assert net2.n_contacts == 1 and np.allclose(net2.branch, net.branch)


def test_translation_by_cell_vector_changes_nothing():
    net = lattices.triangular(6, 6, kn=1.0, kt=0.5)
    rng = np.random.default_rng(0)
    pos = net.positions + rng.normal(scale=0.02, size=net.positions.shape)
    a = from_overlaps(pos, 0.5 * 1.02, net.cell)
    b = from_overlaps(pos + net.cell[:, 0] + 2 * net.cell[:, 1], 0.5 * 1.02, net.cell)
    assert a.n_contacts == b.n_contacts > 0
    assert np.allclose(a.branch, b.branch)
    sa, sb = network_statistics(a), network_statistics(b)
    for k in ("nc", "r", "rho", "vbar", "ebar"):
        assert getattr(sa, k) == pytest.approx(getattr(sb, k), rel=1e-12, abs=1e-15)


def test_polydisperse_uses_own_branch_vectors():
    pos = np.array([[0.0, 0.0], [0.7, 0.0]])
    net = from_overlaps(pos, np.array([0.3, 0.45]), None, kn=1.0, kt=0.0, branch_length="radii")
    assert net.n_contacts == 1 and net.lengths[0] == pytest.approx(0.75)
    ps = particle_sums(net)
    assert ps.A4[0, 0, 0, 0, 0] == pytest.approx(0.75 ** 2)


def test_bad_network_inputs():
    with pytest.raises(ValueError, match="kn"):
        ContactNetwork(positions=np.zeros((2, 2)), radii=[1, 1], cell=None, pairs=[[0, 1]],
                       branch=[[1.0, 0]], kn=-1.0, kt=0.0, sliding=False)
    with pytest.raises(ValueError, match="radii"):
        from_overlaps(np.zeros((2, 2)), -1.0)
    with pytest.raises(ValueError, match="cell too small"):
        from_overlaps(np.zeros((2, 2)) + 0.5, 0.5, np.diag([1.5, 1.5]))
    with pytest.raises(ValueError, match="positions"):
        from_overlaps(np.array([[0.0, np.nan]]), 0.5)


@pytest.mark.parametrize("tilt", [0.0, 2.5, -7.0])
def test_from_overlaps_matches_brute_force(tilt):
    rng = np.random.default_rng(5)
    L = 12.0
    h = np.array([[L, tilt], [0.0, L * 0.9]])
    pos = rng.uniform(-3, 15, (150, 2))
    radii = rng.uniform(0.4, 0.6, 150)
    net = from_overlaps(pos, radii, h)
    found = {(int(i), int(j), *np.round(b, 9)) for (i, j), b in zip(net.pairs, net.branch)}
    brute = set()
    iu, ju = np.triu_indices(150, 1)
    for a in range(-3, 4):
        for b in range(-3, 4):
            d = pos[ju] + h @ [a, b] - pos[iu]
            hit = np.hypot(d[:, 0], d[:, 1]) <= (radii[iu] + radii[ju]) * (1 + 1e-9)
            brute |= {(int(i), int(j), *np.round(dd, 9)) for i, j, dd in zip(iu[hit], ju[hit], d[hit])}
    assert found == brute and len(found) > 50


# ---- typed statistics, the near neighbourhood of (39) and the rho definitions (issue 16) ----------
LEGACY_KEYS = ["n_particles", "n_contacts", "n_rattlers", "rattler_fraction", "nc_all", "r_all", "rho_all", "nc",
               "r", "rho", "phi", "nbar_phi", "diameter", "sliding_fraction", "vbar", "ebar", "vbar_theory",
               "ebar_theory", "odd_norm", "rho_nbar", "rho_note"]  # the last two appended by issue 25


def _disordered(seed=0, side=12, noise=0.04, grow=1.03):
    lat = lattices.triangular(side, side)
    rng = np.random.default_rng(seed)
    pos = lat.positions + rng.normal(scale=noise, size=lat.positions.shape)
    return from_overlaps(pos, 0.5 * grow, lat.cell, kn=1.0, kt=1.0)


def test_network_statistics_is_a_frozen_result_with_the_old_keys():
    import dataclasses
    import json

    st = network_statistics(_disordered())
    assert list(st.as_dict()) == LEGACY_KEYS  # the CLI's JSON/CSV keys, in order
    json.dumps(st.as_dict())
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.nc = 1.0
    assert st.to_frame().shape == (1, len(LEGACY_KEYS))
    assert st.rho_neighbours == "near"  # the paper's definition is the default
    assert st.rho_nbar == 6.0 and "close packing" in st.rho_note  # overlaps: phi = 0.96 > pi/(2 sqrt 3)
    with pytest.raises(ValueError, match="rho_neighbours"):
        network_statistics(_disordered(), rho_neighbours="delaunay")


def _brute_gaps(net):
    """All pair gaps by the minimum image over the 3x3 images (a second method, O(N^2))."""
    n = net.n_particles
    out = {}
    shifts = [net.cell @ np.array([a, b]) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    for i in range(n):
        for j in range(i + 1, n):
            d = min(np.hypot(*(net.positions[j] + s - net.positions[i])) for s in shifts)
            out[(i, j)] = d - net.radii[i] - net.radii[j]
    return out


@pytest.mark.parametrize("shear", [0.0, 2.3])
def test_near_neighbours_are_the_smallest_gaps(shear):
    from microhom.neighbourhood import near_neighbours

    rng = np.random.default_rng(5)
    L = 9.0
    cell = np.array([[L, shear], [0.0, L]])
    pos = rng.uniform(0, 1, (70, 2)) @ cell.T
    radii = rng.uniform(0.4, 0.6, 70)
    net = from_overlaps(pos, radii, cell)
    nb = near_neighbours(net, nbar=4.5)
    brute = _brute_gaps(net)
    m = int(round(70 * 4.5 / 2))
    want = sorted(brute.values())[:m]
    assert len(nb.pairs) == m and nb.degree.sum() == 2 * m
    assert np.allclose(np.sort(nb.gap), want, rtol=0, atol=1e-12)
    for (i, j), g in zip(map(tuple, np.sort(nb.pairs, axis=1)), nb.gap):
        assert brute[(i, j)] == pytest.approx(g, abs=1e-12)
    assert np.allclose(np.hypot(*nb.branch.T) - radii[nb.pairs[:, 0]] - radii[nb.pairs[:, 1]], nb.gap)
    assert nb.mean_degree == pytest.approx(4.5, abs=1 / 70)


def test_near_neighbours_of_the_triangular_lattice_are_its_six_contacts():
    from microhom.neighbourhood import nbar_from_phi, near_neighbours

    net = lattices.triangular(8, 8, kn=1.0, kt=1.0)
    assert float(nbar_from_phi(net.solid_fraction)) == pytest.approx(6.0, rel=1e-9)
    nb = near_neighbours(net)  # Nbar from phi = pi/(2 sqrt 3): 6
    assert np.all(nb.degree == 6)
    assert {tuple(sorted(p)) for p in nb.pairs} == {tuple(sorted(p)) for p in net.pairs}
    st = network_statistics(net, rho_neighbours="near")
    assert st.rho == 0.0  # V = W = 0 on a perfect lattice


def test_neighbour_vector_counts_non_touching_neighbours():
    from microhom.structural_sums import neighbour_vector

    # particle 0 touches 1 (on +x); 2 sits on -x at a gap, not touching; counts 3 and 5
    counts = np.array([1, 3, 5])
    pairs = np.array([[0, 1], [0, 2]])
    branch = np.array([[1.0, 0.0], [-1.2, 0.0]])
    V = neighbour_vector(counts, pairs, branch)
    assert np.allclose(V[0], [(3 - 5) / math.pi, 0.0])  # both neighbours count, touching or not
    assert np.allclose(V[1], [-1 / math.pi, 0.0]) and np.allclose(V[2], [1 / math.pi, 0.0])


def test_rho_definitions_exact_cases_and_consistency():
    from microhom.structural_sums import rho_definitions

    # every particle keeps its 6 contacts: V = Nc W exactly, so rho(contacts) = 1, and shuffling
    # equal contact numbers changes nothing: null = rho, spread 0
    net = _disordered(noise=0.01, grow=1.05)
    assert np.all(net.contact_counts() == 6)
    res = rho_definitions(net, nbar=6.0, n_null=3)  # phi > pi/(2 sqrt 3) (overlaps): Nbar given
    assert res.rho["contacts"] == pytest.approx(1.0, rel=1e-12)
    for name in ("contacts", "near"):
        assert res.null_mean[name] == pytest.approx(res.rho[name], rel=1e-12)
        assert res.null_std[name] == pytest.approx(0.0, abs=1e-12)
    # a disordered packing: the two definitions agree with network_statistics
    net = _disordered(seed=3, noise=0.06, grow=1.02)
    res = rho_definitions(net, nbar=5.0, n_null=4, seed=1)
    assert res.rho["contacts"] == pytest.approx(network_statistics(net, rho_neighbours="contacts").rho, rel=1e-12)
    assert res.rho["near"] == pytest.approx(network_statistics(net, rho_neighbours="near", nbar=5.0).rho, rel=1e-12)
    assert res.null_std["contacts"] > 0 and res.mean_degree["near"] == pytest.approx(res.nbar, abs=1 / 144)
    assert set(res.as_dict()) >= {"rho", "null_mean", "null_std", "nbar"}
    with pytest.raises(ValueError, match="n_null"):
        rho_definitions(net, n_null=1)


def test_near_outside_the_phi_range_says_what_it_used():
    # phi = 3 (pi/4)/100 < pi/4: Nbar(phi) does not exist; Nbar = 4 is used and the result says so
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 5.0]])
    net = from_overlaps(pos, 0.5, np.diag([10.0, 10.0]))
    st = network_statistics(net)   # 3 particles in the cell: no Nbar = 4 neighbourhood; says both
    assert st.rho_nbar is None and st.rho_neighbours == "contacts"
    assert "below pi/4" in st.rho_note and "contacting neighbours used" in st.rho_note
    assert st.as_dict()["rho_note"] == st.rho_note
    with pytest.raises(ValueError, match="cell is too small"):
        network_statistics(net, nbar=4.0)   # an explicit nbar is never replaced
    # on a loose periodic packing: the substitute is exactly an explicit nbar = 4, which leaves no note
    rng = np.random.default_rng(2)
    L = 12.0
    pos = rng.uniform(0, L, (80, 2))
    loose = from_overlaps(pos, 0.5, np.diag([L, L]))
    assert loose.solid_fraction < np.pi / 4
    a, b = network_statistics(loose), network_statistics(loose, nbar=4.0)
    assert a.rho == b.rho and a.rho_nbar == b.rho_nbar == 4.0 and not b.rho_note
    assert "below pi/4" in a.rho_note and "Nbar = 4" in a.rho_note
    c = network_statistics(loose, rho_neighbours="contacts")
    assert c.rho_nbar is None and c.rho_note == ""
    # above close packing (overlaps inflate phi): Nbar = 6, said
    dense = _disordered(noise=0.01, grow=1.05)
    assert dense.solid_fraction > np.pi / (2 * np.sqrt(3))
    d = network_statistics(dense)
    assert d.rho_nbar == 6.0 and "close packing" in d.rho_note


def test_moduli_and_structural_sums_import_each_other_without_a_cycle():
    import subprocess
    import sys

    for first, second in (("microhom.structural_sums", "microhom.moduli"), ("microhom.moduli", "microhom.structural_sums")):
        code = f"import {first}, {second}; from microhom.moduli import nbar_from_phi, PHI_MAX, PHI_MIN_NBAR"
        subprocess.run([sys.executable, "-c", code], check=True)
    import ast
    import inspect

    from microhom import moduli, neighbourhood, structural_sums
    for mod in (moduli, structural_sums, neighbourhood):
        for node in ast.walk(ast.parse(inspect.getsource(mod))):
            if isinstance(node, ast.FunctionDef):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.ImportFrom) and sub.level > 0:
                        raise AssertionError(f"{mod.__name__}.{node.name} imports .{sub.module} inside a function")
