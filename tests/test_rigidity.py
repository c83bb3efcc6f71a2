"""The pebble game (``microhom.rigidity``) against the numerical rank of the rigidity matrix.

Every count of :func:`pebble_game` (floppy modes, redundant bars) is checked against the singular
values of :func:`rigidity_matrix` (assembled by ``microhom.kinematics``), an independent method:
random bar networks in the plane and on the torus (where the game tracks the lattice shifts of the
cycles), lattices with known counts, the small frameworks of the issue, and two patches of real
packings of the corpus (``tests/data/pebble_patch*.npz``: the disks within 8 mean diameters of
the centre of a polydisperse frictional packing, mu_prep = 1 at p/kn = 1e-4 with two sliding
contacts, and of an energy-minimised frictionless one). Rigid clusters are checked against the
null space: each cluster moves only rigidly in every zero mode, and adding any neighbour breaks
that. The identical-disk lattices and mixed sliding/sticking frames where the frictional count is
not generic are pinned as such (the game gives the generic count).
"""
from pathlib import Path

import numpy as np
import pytest

from microhom import lattices
from microhom.network import from_pairs
from microhom.rigidity import RigidityResult, numerical_floppy_modes, pebble_game, rigidity_matrix

DATA = Path(__file__).parent / "data"


def _counts(net):
    r = pebble_game(net, min_contacts=0)
    return (r.n_floppy, r.n_redundant), numerical_floppy_modes(net, min_contacts=0)


def _random_network(rng, periodic, kt=0.0):
    n = int(rng.integers(4, 25))
    L = 10.0
    pos = rng.uniform(0, L, (n, 2))
    pairs = set()
    for _ in range(int(rng.integers(n, 3 * n))):
        a, b = rng.choice(n, 2, replace=False)
        pairs.add((min(a, b), max(a, b)))
    pairs = np.array(sorted(pairs))
    kw = {}
    if periodic:
        kw["shifts"] = rng.integers(-1, 2, (len(pairs), 2)) * (rng.random((len(pairs), 1)) < 0.3)
    return from_pairs(pos, rng.uniform(0.2, 0.5, n), np.eye(2) * L if periodic else None, pairs, kn=1.0, kt=kt,
                      **kw)


@pytest.mark.parametrize("periodic", [False, True])
def test_random_bar_networks_match_the_rank(periodic):
    rng = np.random.default_rng(1 + periodic)
    for _ in range(60):
        game, numeric = _counts(_random_network(rng, periodic))
        assert game == numeric


@pytest.mark.parametrize("periodic", [False, True])
def test_random_frictional_networks(periodic):
    """All contacts sticking, polydisperse, abstract random frames (contacts of any length). The
    game's count is the generic rank, so it can only find fewer floppy modes than the numerical
    rank, never more, and the two differ only where the disk geometry is special: on 300 frames,
    5 in the plane and 2 on the torus (gears: a bipartite ring of sticking contacts counter-rotates,
    omega_i = +-omega / r_i, whatever the positions; parallel equivalent bars), each by one mode.
    On the corpus packings the counts equal the exact solver's on 519 of 525 rows, the others
    kt = 0 rows outside the closure's domain (studies.closure_rigidity; docs/results/closure.md)."""
    rng = np.random.default_rng(4 if periodic else 3)
    res = [_counts(_random_network(rng, periodic, kt=1.0)) for _ in range(300)]
    diff = [(m[0] - g[0], m[1] - g[1]) for g, m in res if g != m]
    assert all(d[0] >= 0 and d[0] == d[1] for d in diff)
    assert len(diff) == (2 if periodic else 5) and all(d == (1, 1) for d in diff)


def test_gear_mode_of_two_disks_touching_twice_on_the_torus():
    """Two disks touching through two periodic images: the (3, 3) count calls the pair rigid, but
    the disks roll on each other (omega_A r_A = -omega_B r_B, no translation): one floppy mode."""
    net = from_pairs(np.array([[1.0, 1.0], [2.0, 1.3]]), np.array([0.4, 0.6]), np.eye(2) * 5.0,
                     np.array([[0, 1], [0, 1]]), shifts=np.array([[0, 0], [-1, 0]]), kn=1.0, kt=1.0)
    assert pebble_game(net, min_contacts=0).n_floppy == 0
    assert numerical_floppy_modes(net, min_contacts=0) == (1, 1)


def _patch(name, kt):
    z = np.load(DATA / name)
    return from_pairs(z["positions"], z["radii"], None, z["pairs"], kn=1.0, kt=kt, sliding=z["sliding"])


@pytest.mark.parametrize("name,kt,expected", [
    ("pebble_patch.npz", 1.0, (9, 3)),               # frictional, 2 sliding contacts
    ("pebble_patch_frictionless.npz", 0.0, (0, 27)),
    ("pebble_patch_frictionless.npz", 1.0, (0, 243)),
])
def test_real_packing_patches(name, kt, expected):
    net = _patch(name, kt)
    r = pebble_game(net)
    assert (r.n_floppy, r.n_redundant) == expected
    assert numerical_floppy_modes(net) == expected


def test_triangular_lattice_is_rigid():
    for kt, red in ((0.0, 36 + 2), (1.0, 3 * 36 + 2)):      # E - (dof - 2): 3N - 2N + 2, 6N - 3N + 2
        net = lattices.triangular(6, 6, kt=kt)
        r = pebble_game(net)
        assert (r.n_floppy, r.n_redundant) == (0, red) == numerical_floppy_modes(net)
        assert r.largest_cluster == 36 and r.n_clusters == 1 and r.largest_cluster_fraction == 1.0
        assert np.all(r.contact_cluster == 0) and np.all(r.particle_cluster == 0)


def _finite(pos, pairs, kt=0.0, radii=None):
    pos = np.asarray(pos, float)
    radii = np.full(len(pos), 0.3) if radii is None else radii
    return from_pairs(pos, radii, None, np.asarray(pairs), kn=1.0, kt=kt)


def test_square_patch_central_bars():
    """n x n square grid of bars: 2 n^2 dof, 2 n (n - 1) independent bars, 2n - 3 floppy modes
    besides the 3 rigid motions; every bar its own rigid cluster."""
    n = 5
    idx = np.arange(n * n).reshape(n, n)
    pos = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2) * 1.0
    pairs = [(idx[a, b], idx[a + 1, b]) for a in range(n - 1) for b in range(n)]
    pairs += [(idx[a, b], idx[a, b + 1]) for a in range(n) for b in range(n - 1)]
    net = _finite(pos, pairs)
    r = pebble_game(net, min_contacts=0)
    assert (r.n_floppy, r.n_redundant) == (2 * n - 3, 0) == numerical_floppy_modes(net, min_contacts=0)
    assert r.n_clusters == len(pairs) and r.largest_cluster == 2
    assert len(set(r.contact_cluster)) == len(pairs)


def test_periodic_square_lattice_is_not_generic():
    """The straight rows of the periodic square lattice carry self-stresses (2L - 2 floppy modes
    on the fixed torus) that the generic count cannot see; any noise restores the generic count,
    which the game gives."""
    net = lattices.square(5, 5, kt=0.0)
    r = pebble_game(net)
    assert (r.n_floppy, r.n_redundant) == (0, 2)
    assert numerical_floppy_modes(net) == (2 * 5 - 2, 2 * 5)
    rng = np.random.default_rng(0)
    noisy = from_pairs(net.positions + rng.normal(0, 0.01, net.positions.shape), net.radii, net.cell, net.pairs,
                       shifts=net.image_shifts(), kn=1.0, kt=0.0)
    assert numerical_floppy_modes(noisy) == (0, 2) == (pebble_game(noisy).n_floppy, pebble_game(noisy).n_redundant)


def test_frictional_non_generic_frames_are_pinned():
    """Where disk geometry is special the (3, 3) count is the generic one, not the rank: two equal
    disks sharing three two-contact neighbours (the three equivalent bars are parallel), and the
    even ring of identical sticking disks (counter-rotating gears)."""
    pos = [(0, 0), (0, 2), (-1, 1), (0.2, 1), (1.3, 1.1)]
    net = _finite(pos, [(0, 2), (1, 2), (0, 3), (1, 3), (0, 4), (1, 4)], kt=1.0, radii=np.array([.5, .5, .4, .3, .6]))
    assert pebble_game(net, min_contacts=0).n_floppy == 0
    assert numerical_floppy_modes(net, min_contacts=0) == (1, 1)
    sq = lattices.square(6, 6, kt=1.0)        # bipartite sticking graph: one gear mode
    assert pebble_game(sq).n_floppy == 0 and numerical_floppy_modes(sq) == (1, 39)


def test_triangle_with_dangling_bar():
    net = _finite([(0, 0), (1, 0), (0.4, 0.9), (2.1, 0.3)], [(0, 1), (1, 2), (0, 2), (1, 3)])
    r = pebble_game(net, min_contacts=0)
    assert (r.n_floppy, r.n_redundant) == (1, 0) == numerical_floppy_modes(net, min_contacts=0)
    lab = r.contact_cluster
    assert lab[0] == lab[1] == lab[2] != lab[3] >= 0
    assert r.largest_cluster == 3 and r.n_clusters == 2
    assert r.particle_cluster[1] == lab[0] and r.particle_cluster[3] == lab[3]


def test_two_rigid_clusters_joined_by_a_hinge():
    """Bow tie: two triangles sharing one joint (1 floppy mode: the hinge); the frictional version,
    two triangles of bodies joined by one sticking contact (a pin), also 1 floppy mode."""
    pos = [(0, 0), (1, 0.1), (0.5, 0.9), (1.6, 1.0), (2.1, 0.2)]
    net = _finite(pos, [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (2, 4)])
    r = pebble_game(net, min_contacts=0)
    assert (r.n_floppy, r.n_redundant) == (1, 0) == numerical_floppy_modes(net, min_contacts=0)
    lab = r.contact_cluster
    assert lab[0] == lab[1] == lab[2] != lab[3] == lab[4] == lab[5]
    assert r.n_clusters == 2 and r.largest_cluster == 3 and list(r.cluster_sizes) == [3, 3]
    pos = [(0, 0), (1, 0.1), (0.5, 0.9), (3.6, 1.0), (4.1, 0.2), (3.2, 0.1)]
    pairs = [(0, 1), (1, 2), (0, 2), (3, 4), (4, 5), (3, 5), (1, 5)]
    fr = _finite(pos, pairs, kt=1.0, radii=np.array([.3, .35, .4, .45, .5, .55]))
    r = pebble_game(fr, min_contacts=0)
    assert (r.n_floppy, r.n_redundant) == (1, 0) == numerical_floppy_modes(fr, min_contacts=0)
    assert r.n_bodies == 6 and r.contact_cluster[6] == -1
    assert r.contact_cluster[0] == r.contact_cluster[1] == r.contact_cluster[2] != r.contact_cluster[3]
    assert list(r.cluster_sizes) == [3, 3]


def _null_space(net):
    R, _ = rigidity_matrix(net, min_contacts=0)
    A = R.toarray()
    u, s, vt = np.linalg.svd(A)
    rank = int((s > 1e-9 * s[0]).sum())
    return vt[rank:].T


def _moves_rigidly(net, members, body, Z, col):
    """Every zero mode restricted to ``members`` is a rigid motion of them (plane)."""
    cols, triv = [], []
    for p in members:
        cols += [col[2 * p], col[2 * p + 1]] + ([col[2 * net.n_particles + p]] if body[p] else [])
        x, y = net.positions[p]
        triv += [[1, 0, -y], [0, 1, x]] + ([[0, 0, 1]] if body[p] else [])
    T = np.array(triv, float)
    Zs = Z[cols]
    P = Zs - T @ np.linalg.lstsq(T, Zs, rcond=None)[0]
    return np.abs(P).max() < 1e-8 if P.size else True


@pytest.mark.parametrize("case", ["random", "patch"])
def test_clusters_are_rigid_and_maximal(case):
    rng = np.random.default_rng(7)
    nets = [_random_network(rng, False) for _ in range(15)] if case == "random" else \
        [_patch("pebble_patch.npz", 1.0), _patch("pebble_patch_frictionless.npz", 0.0)]
    for net in nets:
        mc = 0 if case == "random" else None
        r = pebble_game(net, min_contacts=mc)
        R, _ = rigidity_matrix(net, min_contacts=mc)
        A = R.toarray()
        u, s, vt = np.linalg.svd(A)
        Z = vt[int((s > 1e-9 * s[0]).sum()):].T
        # column of each (particle dof): translations of load-bearing particles, then spins of bodies
        act = ~r.rattlers[net.pairs].any(axis=1)
        lb = ~r.rattlers & (np.bincount(net.pairs[act].ravel(), minlength=net.n_particles) > 0)
        body = np.zeros(net.n_particles, bool)
        stick = (net.effective_kt > 0) & act
        body[net.pairs[stick].ravel()] = True
        col = np.full(3 * net.n_particles, -1)
        t = np.flatnonzero(lb)
        col[2 * t], col[2 * t + 1] = 2 * np.arange(t.size), 2 * np.arange(t.size) + 1
        col[2 * net.n_particles + np.flatnonzero(body)] = 2 * t.size + np.arange(body.sum())
        for c in range(len(r.cluster_sizes)):
            ks = np.flatnonzero(r.contact_cluster == c)
            members = np.unique(net.pairs[ks]) if ks.size else np.flatnonzero(r.particle_cluster == c)
            assert len(members) == r.cluster_sizes[c]
            assert _moves_rigidly(net, members, body, Z, col)
            nb = set(net.pairs[np.isin(net.pairs, members).any(axis=1)].ravel()) - set(members)
            for w in sorted(nb)[:4]:
                if lb[w]:
                    assert not _moves_rigidly(net, np.append(members, w), body, Z, col)


def test_result_and_bad_input():
    r = pebble_game(lattices.triangular(6, 6, kt=0.0))
    assert isinstance(r, RigidityResult)
    d = r.as_dict()
    assert d["n_floppy"] == 0 and "contact_cluster" not in d
    assert r.periodic and not r.frictional and r.n_trivial == 2
    with pytest.raises(ValueError, match="2D"):
        pebble_game(lattices.simple_cubic(3))
    with pytest.raises(TypeError, match="ContactNetwork"):
        pebble_game(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="min_contacts"):
        pebble_game(lattices.triangular(6, 6), min_contacts=-1)
    empty = from_pairs(np.array([[0.0, 0.0], [3.0, 0.0]]), 0.5, None, np.zeros((0, 2), int), kn=1.0, kt=0.0)
    e = pebble_game(empty)
    assert (e.n_floppy, e.n_redundant, e.largest_cluster, e.n_trivial) == (0, 0, 0, 0)


def _unwrapped(net, members, contacts):
    """Positions of ``members`` unwrapped along ``contacts`` (the cluster's), and whether the
    cluster wraps around the torus (a member reached at two different images)."""
    x = {int(members[0]): net.positions[members[0]]}
    wraps, changed = False, True
    while changed:
        changed = False
        for k in contacts:
            a, b = (int(v) for v in net.pairs[k])
            for p, q, sign in ((a, b, 1.0), (b, a, -1.0)):
                if p in x:
                    y = x[p] + sign * net.branch[k]
                    if q not in x:
                        x[q], changed = y, True
                    elif not np.allclose(x[q], y):
                        wraps = True
    return np.array([x[int(m)] for m in members]), wraps


def _rigid_on_torus(net, members, contacts, body, Z, col):
    pos, wraps = _unwrapped(net, members, contacts)
    cols, triv = [], []
    for p, (x, y) in zip(members, pos):
        cols += [col[2 * p], col[2 * p + 1]] + ([col[2 * net.n_particles + p]] if body[p] else [])
        rot = [[-y], [x]] + ([[1]] if body[p] else [])
        t = [[1, 0], [0, 1]] + ([[0, 0]] if body[p] else [])
        triv += [tt + ([] if wraps else rr) for tt, rr in zip(t, rot)]
    T = np.array(triv, float)
    Zs = Z[cols]
    P = Zs - T @ np.linalg.lstsq(T, Zs, rcond=None)[0]
    return np.abs(P).max() < 1e-8


@pytest.mark.parametrize("kt", [0.0, 1.0])
def test_clusters_on_the_torus(kt):
    """Periodic frames: each cluster moves rigidly in every zero mode (only translations if it
    wraps around the torus, a rotation too otherwise), and no neighbour moves with it. Frictional
    frames with a gear (counts off the rank) are skipped; the rest are checked."""
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(25):
        net = _random_network(rng, True, kt=kt)
        r = pebble_game(net, min_contacts=0)
        if (r.n_floppy, r.n_redundant) != numerical_floppy_modes(net, min_contacts=0):
            continue
        R, _ = rigidity_matrix(net, min_contacts=0)
        u, s, vt = np.linalg.svd(R.toarray())
        Z = vt[int((s > 1e-9 * s[0]).sum()):].T
        lb = np.bincount(net.pairs.ravel(), minlength=net.n_particles) > 0
        body = np.zeros(net.n_particles, bool)
        body[net.pairs[net.effective_kt > 0].ravel()] = True
        col = np.full(3 * net.n_particles, -1)
        t = np.flatnonzero(lb)
        col[2 * t], col[2 * t + 1] = 2 * np.arange(t.size), 2 * np.arange(t.size) + 1
        col[2 * net.n_particles + np.flatnonzero(body)] = 2 * t.size + np.arange(body.sum())
        for c in range(len(r.cluster_sizes)):
            ks = np.flatnonzero(r.contact_cluster == c)
            if ks.size == 0:
                continue
            members = np.unique(net.pairs[ks])
            assert _rigid_on_torus(net, members, ks, body, Z, col)
            for k in np.flatnonzero(np.isin(net.pairs, members).sum(axis=1) == 1)[:4]:
                w = int(np.setdiff1d(net.pairs[k], members)[0])
                assert not _rigid_on_torus(net, np.append(members, w), np.append(ks, k), body, Z, col)
        checked += 1
    assert checked >= 20


@pytest.mark.parametrize("name", ["jaxmd_2d_N64_Lp-4.0_0.csv", "jaxmd_2d_N64_Lp-1.0_0.csv"])
def test_maxwell_count_is_linear_in_the_distance_to_isostaticity(name):
    """The Maxwell term of docs/results/closure.md section 2: on a periodic packing whose every
    load-bearing disk has a sticking contact, the game's global count (constraints - dof + 2) / N
    equals (1 - x_r)(Z - Z_iso)(2 - s)/2 + 2/N at kt > 0 and (1 - x_r)(Z - Z_iso)/2 + 2/N at
    kt = 0, with Z, x_r, s of microhom.structural_sums.network_statistics (an independent count)
    and Z_iso of microhom.closure (the algebra checked by sympy). jax-md's 64-disk packings
    (tests/data/heldout), frictionless, frictional, and frictional with 5 % of the contacts sliding."""
    import sympy as sp
    from dem.analysis.analyse import load_network
    from microhom.closure import isostatic_point
    from microhom.structural_sums import network_statistics
    Z, s = sp.symbols("Z s")
    assert sp.simplify(Z * (2 - s) / 2 - 3 - (2 - s) / 2 * (Z - 6 / (2 - s))) == 0   # 3 dof, 2 - s bars per contact
    assert sp.simplify(Z / 2 - 2 - (Z - 4) / 2) == 0                                   # 2 dof, 1 bar per contact
    net, _ = load_network(DATA / "heldout" / "jaxmd" / name, kn=1.0, kt_ratio=1.0)
    rng = np.random.default_rng(1)
    for kt, sliding in ((0.0, False), (1.0, False), (1.0, rng.random(net.n_contacts) < 0.05)):
        nk = net.with_stiffness(kn=1.0, kt=kt, sliding=sliding)
        r, st = pebble_game(nk), network_statistics(nk)
        factor = (2 - st.sliding_fraction) / 2 if kt > 0 else 0.5
        count = (r.n_constraints - r.n_dof + r.n_trivial) / r.n_particles
        dz = st.nc - float(isostatic_point(kt, st.sliding_fraction))
        assert r.n_trivial == 2 and count == pytest.approx((1 - st.rattler_fraction) * dz * factor + 2 / r.n_particles,
                                                             abs=1e-12)
        assert count == pytest.approx(r.redundant_density - r.floppy_density, abs=1e-12)
