"""The relaxation hierarchy on sphere networks (3D) against the exact solver and closed forms.

Reference values never come from the hierarchy: the FCC closed form of docs/spheres.md (derived
by hand, checked against the assembly in tests/test_spheres.py), the exact sparse solve of
``dem.analysis.stiffness.stiffness`` and a dense pseudo-inverse of the assembled problem. The
disordered networks are compressed, jittered, polydisperse FCC packings (12 overlapping nearest
neighbours each, as ``tests/test_spheres.py::_jammed_like``), diluted at random towards the
isostatic point (Z = 6 frictionless, Z = 4 frictional), with per-contact stiffnesses and sliding
contacts drawn at random.
"""
import numpy as np
import pytest
import scipy.linalg as la

from dem.analysis.stiffness import stiffness
from microhom import lattices
from microhom.hierarchy import block_preconditioner, plan_memory, relaxation_hierarchy
from microhom.kinematics import assemble
from microhom.multilevel import dof_layout, near_null_space
from microhom.network import from_overlaps, from_pairs
from microhom.tensors import isotropic_moduli

SQ2 = np.sqrt(2.0)


def packing(seed, n=4, kt=0.0, keep=1.0, squeeze=0.92, jitter=0.03, sliding=0.0, kn_spread=0.0):
    """Compressed, jittered, polydisperse FCC (4 n^3 spheres, radii 0.47-0.53), with a random
    fraction ``keep`` of its contacts kept, kn in [1 - kn_spread, 1 + kn_spread], kt = kt kn and
    a random fraction ``sliding`` of contacts at the Coulomb limit; fn = the overlaps."""
    rng = np.random.default_rng(seed)
    lat = lattices.fcc(n, diameter=1.0)
    pos = lat.positions * squeeze + rng.normal(scale=jitter, size=lat.positions.shape)
    radii = rng.uniform(0.47, 0.53, size=lat.n_particles)
    full = from_overlaps(pos, radii, lat.cell * squeeze, kn=1.0, tolerance=0.0)
    sel = rng.random(full.n_contacts) < keep
    kn = 1.0 + kn_spread * rng.uniform(-1, 1, size=int(sel.sum()))
    return from_pairs(full.positions, full.radii, full.cell, full.pairs[sel],
                      shifts=full.image_shifts()[sel], kn=kn, kt=kt * kn,
                      sliding=rng.random(int(sel.sum())) < sliding, fn=full.overlaps[sel])


def cubic(c11, c12, c44):
    c = np.zeros((6, 6))
    c[:3, :3] = c12
    c[np.arange(3), np.arange(3)] = c11
    c[np.arange(3, 6), np.arange(3, 6)] = c44
    return c


def _psd(A, scale, tol=1e-9):
    return np.linalg.eigvalsh(0.5 * (A + A.T)).min() >= -tol * scale


def _check_against_exact(h, ex, rel=1e-9):
    """Exact K, G inside [lower, upper]; upper bounds non-increasing in the order; the Loewner
    order C_lower <= C_exact <= C_upper of the (6, 6) tensors."""
    scale = np.abs(ex.C_mandel).max()
    for name, e, exact in (("K", h.K, ex.K), ("G", h.G, ex.G)):
        assert e.upper >= exact - rel * scale, (name, e.upper, exact)
        assert e.lower is not None and e.lower <= exact + rel * scale, (name, e.lower, exact)
        assert abs(e.value - exact) <= e.error + rel * scale
    for seq in (h.K_orders, h.G_orders):
        assert np.all(np.diff(seq) <= 1e-12 * scale), seq
    assert h.C_orders.shape == (h.order + 1, 6, 6)
    for C in h.C_orders:                                  # every order is an upper bound
        assert _psd(C - ex.C_mandel, scale)
    assert _psd(ex.C_mandel - h.C_lower, scale)


# ---- building blocks ----------------------------------------------------------------------------
def test_near_null_space_is_rigid_in_3d():
    """Translations and the three rigid rotations (with their spins) deform no contact that does
    not cross the cell boundary (there the rotation of the periodic image differs); spins alone
    are unit spins; the layout names 6 unknowns per sphere."""
    net = packing(1, n=2, kt=0.5)
    asm = assemble(net, pin=False)
    part, comp = dof_layout(asm)
    assert np.array_equal(np.bincount(part, minlength=net.n_particles), np.full(net.n_particles, 6))
    assert np.array_equal(np.sort(np.unique(comp)), np.arange(6))
    B = near_null_space(asm)
    assert B.shape == (asm.ndof, 9)
    inner = np.repeat(~np.any(asm.net.image_shifts() != 0, axis=1), 3)
    assert inner.sum() > 0
    scale = np.abs(asm.Bs).max() * np.abs(B).max()
    assert np.abs((asm.Bs @ B[:, :6])[inner]).max() < 1e-13 * scale
    assert np.abs(asm.Bs @ B[:, :3]).max() < 1e-13 * scale      # translations: every contact
    # spins alone: exactly the rotation unknowns, one column per axis
    np.testing.assert_array_equal(B[:, 6:], (comp[:, None] == np.arange(3, 6)[None, :]).astype(float))


def test_block_preconditioner_has_6x6_particle_blocks():
    """M is H restricted to each sphere's own 6 unknowns (read off the dense H), M^-1 its inverse."""
    net = packing(2, n=2, kt=0.7)
    asm = assemble(net, pin=False)
    M, Minv, Msq, n_bad = block_preconditioner(asm)
    assert n_bad == 0
    part = dof_layout(asm)[0]
    Hd = asm.H.toarray()
    same = part[:, None] == part[None, :]
    np.testing.assert_array_equal(M.toarray(), np.where(same, Hd, 0.0))
    for p in np.unique(part)[:5]:
        idx = np.flatnonzero(part == p)
        assert idx.size == 6
        blk = Hd[np.ix_(idx, idx)]
        np.testing.assert_allclose(Minv.toarray()[np.ix_(idx, idx)], la.inv(blk), rtol=1e-10,
                                   atol=1e-12 * np.abs(la.inv(blk)).max())
        S = Msq.toarray()[np.ix_(idx, idx)]
        np.testing.assert_allclose(S @ blk @ S, np.eye(6), atol=1e-10)


def test_plan_memory_counts_six_unknowns_per_sphere():
    """2D figures unchanged; 3D: 6 unknowns per sphere, 36 (N + 2 Nc) non-zeros at the 3D
    bytes per non-zero (48 assembly, 80 multilevel: measured, docs/results/spheres.md)."""
    a = plan_memory(1000, 2000, max_order=4, soft_modes=0, dense=False)
    b = plan_memory(1000, 2000, max_order=4, soft_modes=0, dense=False, dim=2)
    assert a == b
    c = plan_memory(1000, 2000, max_order=4, soft_modes=0, dense=True, dim=3)
    assert c.dense == 24 * 6000 ** 2 and c.assembly == 48 * 36 * (1000 + 2 * 2000)
    assert c.preconditioner == 700 * 6000 * 2 + 80 * 36 * (1000 + 2 * 2000)
    # H read from the multilevel copy (issue 26): 70 bytes per non-zero, 3D only
    d = plan_memory(1000, 2000, max_order=4, soft_modes=0, dense=True, dim=3, shared_h=True)
    assert d.preconditioner == 700 * 6000 * 2 + 70 * 36 * (1000 + 2 * 2000) and d.assembly == c.assembly
    assert plan_memory(1000, 2000, max_order=4, soft_modes=0, dense=False, shared_h=True) == a
    with pytest.raises(ValueError, match="dim must be 2 or 3"):
        plan_memory(10, 10, dim=4)


def test_plan_memory_3d_against_the_measured_peak():
    """The 3D prediction holds the peak tracemalloc measures over a dual-bound run on the built
    FCC of the sphere benchmark, and is honest: not above 4 times it (measured: 2.0 times at 500,
    2000 and 4000 spheres; 1.5 times the resident peak at 1.08e5, docs/results/spheres.md)."""
    import tracemalloc
    import warnings
    from studies.bench_spheres import fcc_network
    net = fcc_network(500, keep=0.6, kt=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        relaxation_hierarchy(fcc_network(100, keep=0.6, kt=0.5), spectral_bound="none", dual_bound=True,
                             soft_modes=0)                # compile the kernels outside the measurement
        tracemalloc.start()
        try:
            h = relaxation_hierarchy(net, spectral_bound="none", dual_bound=True, soft_modes=0, max_order=60)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert h.certified
    p = plan_memory(net.n_particles, net.n_contacts, max_order=60, full=True, soft_modes=0, dense=False, dim=3)
    assert peak <= p.total <= 4 * peak, (peak, p.total)
    q = plan_memory(net.n_particles, net.n_contacts, max_order=60, full=True, soft_modes=0, dense=False, dim=3,
                    shared_h=True)            # this run read H from the multilevel copy (issue 26)
    assert peak <= q.total < p.total, (peak, q.total)


# ---- lattices: closed forms and flags -----------------------------------------------------------
@pytest.mark.parametrize("kn, kt", [(1.0, 1.0), (1.0, 0.0), (3.0, 0.4)])
def test_fcc_closed_form_exact_at_order_zero(kn, kt):
    """FCC relaxes nothing (docs/spheres.md): the hierarchy returns the closed form at order 0,
    as a zero-width certified interval."""
    D = 0.8
    h = relaxation_hierarchy(lattices.fcc(2, diameter=D, kn=kn, kt=kt))
    c11, c12, c44 = SQ2 * (kn + kt) / D, (kn - kt) / (SQ2 * D), SQ2 * (kn + kt) / D
    np.testing.assert_allclose(h.C_upper, cubic(c11, c12, c44), rtol=0, atol=1e-10 * kn / D)
    assert h.K.upper == pytest.approx((c11 + 2 * c12) / 3, rel=1e-10)
    assert h.G.upper == pytest.approx((c11 - c12 + 1.5 * c44) / 5, rel=1e-10)
    assert h.K.lower == pytest.approx(h.K.upper, rel=1e-10) and h.valid and h.order == 0


def test_jittered_fcc_relaxes_and_converges_to_the_lattice_limit():
    """A slightly jittered monodisperse FCC (not compressed: touching within 1e-4) is no longer
    affine; its exact moduli lie in the interval, and tend to the closed form as the jitter goes."""
    rng = np.random.default_rng(0)
    lat = lattices.fcc(3, diameter=1.0, kn=1.0, kt=0.5)
    pos = lat.positions + rng.normal(scale=1e-4, size=lat.positions.shape)
    net = from_pairs(pos, lat.radii, lat.cell, lat.pairs, shifts=lat.image_shifts(), kn=1.0, kt=0.5)
    h = relaxation_hierarchy(net, tol=1e-4)
    ex = stiffness(net)
    _check_against_exact(h, ex)
    assert h.valid and h.certified
    K0 = 2 * SQ2 / 3                                      # (c11 + 2 c12)/3 at kn = D = 1
    assert h.K.value == pytest.approx(K0, rel=1e-2)


def test_frictionless_simple_cubic_is_floppy():
    """Frictionless simple cubic: C44 = kt/D = 0, a shear costs no energy: flagged floppy."""
    h = relaxation_hierarchy(lattices.simple_cubic(3, kn=1.0, kt=0.0))
    assert h.floppy and not h.valid and any(r.startswith("floppy") for r in h.reasons)
    assert h.K.upper == pytest.approx(1.0 / 3.0, rel=1e-10)   # C11/3 at kn = D = 1, C12 = 0


def test_dilute_network_is_not_jammed():
    """Frictionless spheres at Z ~ 3 (below the 4 contacts that hold one): every sphere is a
    rattler, no backbone: flagged not jammed, never valid."""
    net = packing(3, n=3, kt=0.0, keep=0.25)
    h = relaxation_hierarchy(net)
    assert not h.jammed and not h.valid and h.empty
    assert any(r.startswith("not jammed") for r in h.reasons)
    assert h.C_upper.shape == (6, 6)


def test_hypostatic_backbone_is_not_jammed():
    """Frictionless at Z ~ 6 before the rattlers go (14 of 108 removed): a backbone remains
    (not empty) but it is hypostatic, the exact tensor vanishes with floppy modes; the hierarchy's
    upper bound vanishes too and the result is flagged not jammed, never valid."""
    net = packing(4, n=3, kt=0.0, keep=0.5)
    with pytest.warns(RuntimeWarning, match="not jammed"):
        ex = stiffness(net)
    assert ex.n_floppy > 0 and ex.n_rattlers < net.n_particles
    h = relaxation_hierarchy(net, max_order=60)
    assert not h.empty and not h.jammed and not h.valid
    assert any(r.startswith("not jammed: the upper bound") for r in h.reasons)
    assert abs(h.K.upper) < 1e-9 and abs(h.G.upper) < 1e-9


# ---- disordered packings against the exact solver -----------------------------------------------
CASES = {
    "frictionless dense": dict(kt=0.0, keep=1.0),
    "frictionless near isostatic": dict(kt=0.0, keep=0.66),
    "frictional": dict(kt=0.5, keep=0.55, sliding=0.1, kn_spread=0.5),
    "frictional near isostatic": dict(kt=0.5, keep=0.42),
    "kt > kn": dict(kt=5.0, keep=0.5),
}


@pytest.mark.parametrize("preconditioner", ["amg", "block"])
@pytest.mark.parametrize("case", list(CASES))
def test_disordered_spheres_exact_inside_the_interval(case, preconditioner):
    net = packing(10 + list(CASES).index(case), n=4, **CASES[case])       # 256 spheres
    ex = stiffness(net)
    h = relaxation_hierarchy(net, tol=1e-3, preconditioner=preconditioner, max_order=200)
    assert h.n_particles == 256 and h.n_dof > 0 and h.order >= 1
    assert h.spectral_bound_source in ("dense", "dense+companion", "inertia", "inertia+companion", "companion")
    _check_against_exact(h, ex)
    assert h.converged and h.certified, h.summary()
    assert h.K.rel_width <= 1e-3 and h.G.rel_width <= 1e-3
    # the relaxation is real: the exact moduli lie well below the affine ones
    assert ex.G < 0.98 * h.G_orders[0]


def test_prestressed_compressed_spheres():
    """With pre-stress (fn = the overlaps, geometric stiffness and the Cauchy-increment correction)
    on the dense packing, where H stays positive semi-definite."""
    net = packing(20, n=4, kt=0.5, keep=1.0, jitter=0.01)
    ex = stiffness(net, prestress=True)
    assert not ex.flags
    h = relaxation_hierarchy(net, prestress=True, tol=1e-4)
    _check_against_exact(h, ex)
    assert h.valid and h.prestress


@pytest.mark.slow
def test_larger_packing_certified_by_inertia():
    """2048 spheres (about 1.2e4 unknowns, above dense_max): the lower bound is certified by the
    sparse inertia count (microhom.spectral), the exact moduli lie inside."""
    net = packing(30, n=8, kt=0.5, keep=0.6)
    ex = stiffness(net)
    h = relaxation_hierarchy(net, tol=1e-3, soft_modes=0)
    assert h.n_dof > 3000 and h.K.lower is not None, h.summary()
    _check_against_exact(h, ex)


# ---- mean field and statistics in 3D ------------------------------------------------------------
def test_voigt_moduli_formula_by_sympy():
    """For any contact direction n on the unit sphere, the isotropic projection of the per-contact
    affine stiffness l^2 [kn nnnn + kt (sym(d nn) - nnnn)] is K = kn l^2/9, G = (2 kn + 3 kt) l^2/30
    (the formulas of sphere_statistics): the (6, 6) Mandel matrix is built from the energy
    1/2 [kn (n.E n)^2 + kt (|E n|^2 - (n.E n)^2)] l^2 and projected by 1.C.1/9, (tr C - 1.C.1/3)/10."""
    import sympy as sy
    th, ph, kn, kt, l = sy.symbols("theta phi k_n k_t l", positive=True)
    n = sy.Matrix([sy.sin(th) * sy.cos(ph), sy.sin(th) * sy.sin(ph), sy.cos(th)])
    e = sy.symbols("e0:6")
    r2 = 1 / sy.sqrt(2)
    E = sy.Matrix([[e[0], r2 * e[5], r2 * e[4]], [r2 * e[5], e[1], r2 * e[3]], [r2 * e[4], r2 * e[3], e[2]]])
    En = E * n
    nEn = (n.T * En)[0]
    W = sy.Rational(1, 2) * l ** 2 * (kn * nEn ** 2 + kt * ((En.T * En)[0] - nEn ** 2))
    C = sy.Matrix(6, 6, lambda a, b: sy.diff(W, e[a], e[b]))
    one = sy.Matrix([1, 1, 1, 0, 0, 0])
    q = (one.T * C * one)[0]
    K = sy.simplify(q / 9)
    G = sy.simplify((C.trace() - q / 3) / 10)
    assert sy.simplify(K - kn * l ** 2 / 9) == 0
    assert sy.simplify(G - (2 * kn + 3 * kt) * l ** 2 / 30) == 0


def test_fabric_tensor_matches_the_assembly_and_closed_forms():
    """fabric_affine_tensor (fourth-order fabric sums) against kinematics.affine_tensor (per-contact
    matrices) on both lattices and a disordered frictional packing with sliding contacts, and
    against the closed forms of docs/spheres.md; its K, G against the Voigt formulas."""
    from microhom.kinematics import affine_tensor
    from microhom.structural_sums import fabric_affine_tensor, sphere_statistics
    D, kn, kt = 0.8, 3.0, 0.4
    sc = lattices.simple_cubic(3, diameter=D, kn=kn, kt=kt)
    np.testing.assert_allclose(fabric_affine_tensor(sc), cubic(kn / D, 0.0, kt / D), atol=1e-12 * kn / D)
    f = lattices.fcc(2, diameter=D, kn=kn, kt=kt)
    c11, c12 = SQ2 * (kn + kt) / D, (kn - kt) / (SQ2 * D)
    np.testing.assert_allclose(fabric_affine_tensor(f), cubic(c11, c12, c11), atol=1e-12 * kn / D)
    st = sphere_statistics(f)
    assert st.K_affine == pytest.approx(2 * SQ2 * kn / (3 * D), rel=1e-12)     # (c11 + 2 c12)/3
    assert st.G_affine == pytest.approx(SQ2 * (2 * kn + 3 * kt) / (5 * D), rel=1e-12)
    net = packing(7, n=3, kt=0.6, keep=0.6, sliding=0.2, kn_spread=0.5)
    for sel in (None, np.random.default_rng(0).random(net.n_contacts) < 0.5):
        sub = net if sel is None else net.select_contacts(sel)
        C = fabric_affine_tensor(net, sel)
        ref = affine_tensor(sub)
        np.testing.assert_allclose(C, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    st = sphere_statistics(net)
    K, G = isotropic_moduli(st.C_affine)
    assert st.K_affine == pytest.approx(K, rel=1e-12) and st.G_affine == pytest.approx(G, rel=1e-12)
    h = relaxation_hierarchy(net, max_order=1)          # order 0 = the affine tensor of the backbone
    assert h.K_orders[0] == pytest.approx(st.K_affine, rel=1e-12)
    assert h.G_orders[0] == pytest.approx(st.G_affine, rel=1e-12)
    assert h.K_affine_all == pytest.approx(st.K_affine_all, rel=1e-12)


def test_sphere_statistics_coordination_and_fraction():
    """Z, r with and without rattlers against an explicit loop; phi of FCC = pi/(3 sqrt 2)."""
    from microhom.structural_sums import network_statistics, rattlers, sphere_statistics, SphereStatistics
    f = lattices.fcc(2, diameter=1.0, kn=1.0, kt=0.5)
    st = sphere_statistics(f)
    assert st.nc == 12 and st.nc_all == 12 and st.r == 0 and st.n_rattlers == 0
    assert st.phi == pytest.approx(np.pi / (3 * SQ2), rel=1e-12)
    for kt, keep in ((0.0, 0.55), (0.5, 0.35)):
        net = packing(8, n=3, kt=kt, keep=keep)
        st = network_statistics(net)
        assert isinstance(st, SphereStatistics)
        rat = rattlers(net)[0]
        # the rattler rule by hand: peel spheres with fewer than 2 (friction) / 4 contacts
        alive = np.ones(net.n_particles, bool)
        while True:
            cnt = {p: 0 for p in range(net.n_particles)}
            for i, j in net.pairs:
                if alive[i] and alive[j]:
                    cnt[i] += 1
                    cnt[j] += 1
            weak = [p for p in cnt if alive[p] and cnt[p] < (2 if kt > 0 else 4)]
            if not weak:
                break
            alive[weak] = False
        np.testing.assert_array_equal(~alive, rat)
        z = np.array([cnt[p] for p in range(net.n_particles) if alive[p]], float)
        z_all = np.array([np.sum(net.pairs == p) for p in range(net.n_particles)], float)
        assert st.n_rattlers == (~alive).sum() > 0
        assert st.nc == pytest.approx(z.mean(), rel=1e-14)
        assert st.r == pytest.approx(np.mean((z - z.mean()) ** 2) / z.mean() ** 2, rel=1e-12)
        assert st.nc_all == pytest.approx(z_all.mean(), rel=1e-14)
        assert st.r_all == pytest.approx(np.mean((z_all - z_all.mean()) ** 2) / z_all.mean() ** 2, rel=1e-12)
        assert st.phi == pytest.approx(np.sum(4 / 3 * np.pi * net.radii ** 3) / np.linalg.det(net.cell))


def test_2d_only_statistics_are_named_not_computed_in_3d():
    """rho and N-bar have no 3D meaning: not fields of SphereStatistics, listed with the reason;
    asking for them on a sphere network is an error naming the parameters."""
    from microhom.structural_sums import NOT_IN_3D, network_statistics, sphere_statistics
    st = network_statistics(lattices.fcc(2))
    assert not hasattr(st, "rho") and not hasattr(st, "nbar_phi") and not hasattr(st, "vbar")
    assert st.not_defined == NOT_IN_3D
    assert any(s.startswith("rho") for s in st.not_defined)
    assert any("N-bar" in s for s in st.not_defined)
    with pytest.raises(ValueError, match="nbar and rho_neighbours"):
        network_statistics(lattices.fcc(2), nbar=12)
    with pytest.raises(ValueError, match="sphere network"):
        sphere_statistics(lattices.triangular(4, 4))


def test_bench_spheres_runs_small(capsys):
    """The benchmark of docs/spheres.md on 256 spheres: its rows carry the exact solve beside the
    hierarchy's interval, and the exact moduli lie inside."""
    from studies import bench_spheres
    (row,) = bench_spheres.main(["--n", "200", "--exact", "yes", "--max-order", "20", "--tol", "1e-3"])
    assert row["N"] == 256 and "hierarchy" in capsys.readouterr().out
    for m in "KG":
        assert row[f"{m}_lower"] - 1e-9 <= row[f"{m}_exact"] <= row[f"{m}_upper"] + 1e-9


@pytest.mark.parametrize("chunk", [7, 1000, 1 << 22])
def test_particle_blocks_read_in_slices_equal_the_coo_selection(chunk):
    """``_own_blocks`` (slices of H's columns) gives, bit for bit, the entries of H whose row and
    column belong to the same particle, selected on a full COO copy (the former code)."""
    import scipy.sparse as sps
    from microhom.hierarchy import _own_blocks
    net = packing(3, n=3, kt=0.5, keep=0.5)          # with rattlers and two-contact spheres
    asm = assemble(net, pin=True)
    owner = dof_layout(asm)[0]
    H = asm.H.tocoo()
    keep = owner[H.row] == owner[H.col]
    M0 = sps.csr_matrix((H.data[keep], (H.row[keep], H.col[keep])), shape=H.shape)
    M1 = _own_blocks(asm.H, owner, chunk=chunk)
    assert M1.shape == M0.shape and M0.nnz > 0
    np.testing.assert_array_equal(M1.indptr, M0.indptr)
    np.testing.assert_array_equal(M1.indices, M0.indices)
    np.testing.assert_array_equal(M1.data, M0.data)


def test_every_order_with_its_margin_bounds_the_exact_tensor_when_cg_stagnates(monkeypatch):
    """The float32 V-cycle (an option, not the default) stagnates near its precision on this
    frictional case: the CG keeps stepping along nearly floppy directions, the iterate grows by
    three orders of magnitude and the energy's computed value drifts below the exact one
    (docs/results/spheres.md, "The multilevel setup"). The round-off margin of each order grows
    with it and covers the drift: ``C_orders[j] + margin_orders[j] I`` bounds the exact tensor at
    every order, and the reported upper bounds include the last margin."""
    import functools

    import microhom.hierarchy as hy
    import microhom.multilevel as ml
    monkeypatch.setattr(hy, "amg_preconditioner", functools.partial(ml.amg_preconditioner, dtype=np.float32))
    case = "frictional"
    net = packing(10 + list(CASES).index(case), n=4, **CASES[case])
    ex = stiffness(net)
    h = hy.relaxation_hierarchy(net, tol=1e-3, preconditioner="amg", max_order=23)
    scale = np.abs(ex.C_mandel).max()
    m = h.margin_orders
    assert m.shape == (h.order + 1,) and m[0] == 0.0 and np.all(m[1:] > 0)
    assert m[-1] > 1e4 * m[1]                             # the stagnating CG's margin grew
    for C, s in zip(h.C_orders, m):
        assert la.eigvalsh(C + s * np.eye(6) - ex.C_mandel).min() >= -1e-12 * scale
    assert np.allclose(h.C_upper, h.C_orders[-1] + m[-1] * np.eye(6), rtol=0, atol=1e-15 * scale)
    assert not h.certified                               # the margin, not a wrong bound, keeps it open


def test_memory_guard_says_where_its_3d_figures_overestimate():
    """A refused run on the lean 3D path (H read from the multilevel copy) says that the figures
    overestimate large sphere networks and what was measured; a 2D refusal does not."""
    from microhom.hierarchy import HierarchyMemoryError
    from studies.bench_spheres import fcc_network
    from studies.bench_stiffness import diluted_triangular
    with pytest.raises(HierarchyMemoryError, match=r"overestimate: 1e6 spheres peaked at 14.5 GiB"):
        relaxation_hierarchy(fcc_network(100, keep=0.6, kt=0.5), spectral_bound="none", dual_bound=True,
                             soft_modes=0, max_memory=1e5)
    with pytest.raises(HierarchyMemoryError) as e:
        relaxation_hierarchy(diluted_triangular(300, z=4.6, kt=0.5, seed=1), max_memory=1e5)
    assert "overestimate" not in str(e.value)
