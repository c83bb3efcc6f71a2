"""3D (spheres): the kinematics assembly against closed forms, rigid motions and energy finite
differences that share no code with it.

Closed forms (derived by hand in docs/spheres.md): a simple cubic lattice of diameter D,
    C11 = kn/D, C12 = 0, C44 = kt/D   (Mandel, so C44 = 2 c44 of Voigt),
and a face-centred cubic lattice,
    C11 = sqrt2 (kn + kt)/D, C12 = (kn - kt)/(sqrt2 D), C44 = sqrt2 (kn + kt)/D.
Both are centrosymmetric and their fabric is cubic, so neither translations nor rotations relax:
the exact tensor is the affine one.
"""
import numpy as np
import pytest
import scipy.linalg as la
from scipy.optimize import minimize

from microhom import lattices, tensors
from microhom.kinematics import affine_tensor, assemble, contact_matrices, stress0
from microhom.network import from_overlaps, from_pairs
from microhom.structural_sums import rattlers

SQ2 = np.sqrt(2.0)


def relaxed(net, prestress=False):
    """C_aff - F^T H^+ F / V with a dense pseudo-inverse (small systems only): the relaxation of
    the assembled problem, without the Cauchy-increment pre-stress correction [Pa]."""
    a = assemble(net, prestress=prestress)
    c_aff = affine_tensor(a.net, prestress)
    if a.ndof == 0:
        return c_aff, a
    H = a.H.toarray()
    X = la.lstsq(H, a.F, cond=1e-12)[0]
    return c_aff - a.F.T @ X / net.volume, a


def cubic(c11, c12, c44):
    c = np.zeros((6, 6))
    c[:3, :3] = c12
    c[np.arange(3), np.arange(3)] = c11
    c[np.arange(3, 6), np.arange(3, 6)] = c44
    return c


@pytest.mark.parametrize("kn, kt", [(1.0, 1.0), (1.0, 0.3), (2.5, 0.7)])
def test_simple_cubic_closed_form(kn, kt):
    D = 1.3
    net = lattices.simple_cubic(3, diameter=D, kn=kn, kt=kt)
    expected = cubic(kn / D, 0.0, kt / D)
    np.testing.assert_allclose(affine_tensor(net), expected, rtol=0, atol=1e-12 * kn / D)
    C, a = relaxed(net)
    assert a.ndof == 27 * 6 - 3 and not a.rattlers.any()
    np.testing.assert_allclose(C, expected, rtol=0, atol=1e-10 * kn / D)


@pytest.mark.parametrize("kn, kt", [(1.0, 1.0), (1.0, 0.0), (3.0, 0.4)])
def test_fcc_closed_form(kn, kt):
    D = 0.8
    net = lattices.fcc(2, diameter=D, kn=kn, kt=kt)
    expected = cubic(SQ2 * (kn + kt) / D, (kn - kt) / (SQ2 * D), SQ2 * (kn + kt) / D)
    np.testing.assert_allclose(affine_tensor(net), expected, rtol=0, atol=1e-12 * kn / D)
    C, a = relaxed(net)
    np.testing.assert_allclose(C, expected, rtol=0, atol=1e-10 * kn / D)
    K, G = tensors.isotropic_moduli(C)
    c11, c12, c44 = expected[0, 0], expected[0, 1], expected[3, 3]
    assert K == pytest.approx((c11 + 2 * c12) / 3, rel=1e-12)
    assert G == pytest.approx((c11 - c12 + 1.5 * c44) / 5, rel=1e-12)   # (tr C - 1.C.1/3)/10
    if kt == 0:           # frictionless: no rotation unknowns
        assert a.n_spins == 0


def test_rigid_motions_deform_no_contact():
    """A rigid rotation (u = w x c at j relative to i, every particle turned by w) and a rigid
    translation leave every contact undeformed: B q = 0 contact by contact."""
    rng = np.random.default_rng(3)
    net = _jammed_like(rng, kt=0.6)
    m = contact_matrices(net)
    w = rng.normal(size=3)
    c = net.branch
    q = np.zeros((net.n_contacts, 12))
    q[:, 3:6] = w                       # omega_i
    q[:, 6:9] = np.cross(w, c)          # u_j - u_i = w x c
    q[:, 9:12] = w                      # omega_j
    delta = np.einsum("cal,cl->ca", m.B, q)
    assert np.abs(delta).max() < 1e-13 * np.abs(c).max() * np.abs(w).max()
    t = rng.normal(size=3)
    q = np.zeros((net.n_contacts, 12))
    q[:, 0:3] = t
    q[:, 6:9] = t
    assert np.abs(np.einsum("cal,cl->ca", m.B, q)).max() < 1e-15 * np.abs(t).max() * 10
    # zero strain: no load, no stress change
    a = assemble(net)
    assert np.allclose(a.F @ np.zeros(6), 0)


def test_spin_column_is_the_cross_product():
    """Delta of contact point j relative to i for a spin of i alone: -(a_i omega) x n."""
    net = lattices.fcc(2, diameter=1.0, kn=1.0, kt=1.0)
    m = contact_matrices(net)
    n = net.normals
    w = np.array([0.3, -1.1, 0.7])
    ai = 0.5 * net.lengths
    got = np.einsum("cal,l->ca", m.B[:, :, 3:6], w)
    np.testing.assert_allclose(got, -ai[:, None] * np.cross(w, n), atol=1e-15)


def test_rattler_rule_in_3d():
    """Frictionless spheres need d + 1 = 4 contacts, frictional ones d = 3 (docs: two frictional
    contacts leave a rolling mode); a sphere with 2 frictional contacts is a rattler."""
    D = 1.0
    pos = np.array([[0.0, 0, 0], [D, 0, 0], [0, D, 0], [5, 5, 5]])
    net = from_pairs(pos, 0.5, None, [[0, 1], [0, 2]], kn=1.0, kt=1.0)
    ratt, _ = rattlers(net)
    assert ratt[0] and ratt.all()
    # the rolling mode of a sphere held by two frictional contacts, in the element matrices
    m = contact_matrices(net)
    n1, n2 = net.normals
    a = 0.5
    w = a * n1 - a * n2
    u = -a * np.cross(w, n1)
    for k in range(2):      # particle 0 is i of both contacts; neighbours fixed
        q = np.concatenate([u, w, np.zeros(6)])
        assert np.abs(m.B[k] @ q).max() < 1e-15


def _jammed_like(rng, kt=0.0, n=2, squeeze=0.92, jitter=0.01):
    """A compressed, jittered FCC packing of polydisperse harmonic spheres (radii 0.47-0.53, every
    nearest-neighbour pair overlaps): a disordered, pre-stressed network with 12 contacts each."""
    lat = lattices.fcc(n, diameter=1.0)
    pos = lat.positions * squeeze + rng.normal(scale=jitter, size=lat.positions.shape)
    radii = rng.uniform(0.47, 0.53, size=lat.n_particles)
    return from_overlaps(pos, radii, lat.cell * squeeze, kn=1.0, kt=kt, tolerance=0.0)


class Harmonic:
    """Energy U = sum 1/2 kn (D - |x_j + h s - x_i|)^2 over a fixed contact list with image
    shifts (written here without microhom: the independent check)."""

    def __init__(self, net):
        self.i, self.j = net.pairs.T
        self.s = net.image_shifts()
        self.h0 = net.cell.copy()
        self.x0 = net.positions.copy()
        self.rs = net.radii[self.i] + net.radii[self.j]
        self.kn = net.kn.copy()

    def energy_grad(self, xflat, F):
        x = xflat.reshape(-1, 3)
        h = F @ self.h0
        c = x[self.j] + self.s @ h.T - x[self.i]
        L = np.linalg.norm(c, axis=1)
        ov = self.rs - L
        U = 0.5 * np.sum(self.kn * ov ** 2)
        dUdc = (-(self.kn * ov) / L)[:, None] * c
        g = np.zeros_like(x)
        np.add.at(g, self.j, dUdc)
        np.add.at(g, self.i, -dUdc)
        return U, g.ravel()

    def relaxed_energy(self, F, x_start):
        res = minimize(self.energy_grad, x_start.ravel(), args=(F,), jac=True, method="L-BFGS-B",
                       options={"gtol": 1e-13, "ftol": 1e-300, "maxiter": 20000, "maxcor": 50})
        return res.fun, res.x.reshape(-1, 3)


def test_energy_finite_differences_frictionless_spheres():
    """The relaxed stiffness of the energy density (pre-stress geometric terms included) equals
    the second derivative of min_u U(E)/V0 by central differences, for a disordered, compressed
    packing of frictionless harmonic spheres."""
    rng = np.random.default_rng(7)
    net0 = _jammed_like(rng)
    model = Harmonic(net0)
    # bring it to force balance first: the formula is for an equilibrium state
    _, x_eq = model.relaxed_energy(np.eye(3), net0.positions)
    net = from_overlaps(x_eq, net0.radii, net0.cell, kn=1.0, kt=0.0, tolerance=0.0)
    assert net.n_contacts == net0.n_contacts
    fn = net.kn * net.overlaps
    net = from_pairs(net.positions, net.radii, net.cell, net.pairs, shifts=net.image_shifts(),
                     kn=1.0, kt=0.0, fn=fn)
    C, a = relaxed(net, prestress=True)
    assert a.rattlers.sum() == 0
    model = Harmonic(net)
    V0 = net.volume
    h = 2e-4
    idx = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]

    def strain(v):
        E = np.zeros((3, 3))
        for a_, (p, q) in enumerate(idx):
            if p == q:
                E[p, p] += v[a_]
            else:
                E[p, q] += v[a_] / SQ2
                E[q, p] += v[a_] / SQ2
        return E

    def W(v):
        F = np.eye(3) + strain(v)
        return model.relaxed_energy(F, net.positions @ F.T)[0] / V0

    W0 = W(np.zeros(6))
    fd = np.zeros((6, 6))
    for p in range(6):
        for q in range(p, 6):
            ep, eq = np.eye(6)[p] * h, np.eye(6)[q] * h
            if p == q:
                fd[p, p] = (W(ep) - 2 * W0 + W(-ep)) / h ** 2
            else:
                fd[p, q] = fd[q, p] = (W(ep + eq) - W(ep - eq) - W(-ep + eq) + W(-ep - eq)) / (4 * h ** 2)
    scale = np.abs(C).max()
    assert np.abs(fd - C).max() < 1e-6 * scale, (np.abs(fd - C).max() / scale)
    # the check has teeth: relaxation and geometric terms are far above its tolerance
    assert np.abs(affine_tensor(a.net, True) - C).max() > 1e-4 * scale    # 100x the tolerance
    assert np.abs(relaxed(net, prestress=False)[0] - C).max() > 1e-3 * scale
    # the pre-stress is the first derivative: sigma0 = dW/dE at E = 0 (tension positive)
    s0 = tensors.strain_to_mandel(stress0(net))
    g = np.array([(W(np.eye(6)[p] * h) - W(-np.eye(6)[p] * h)) / (2 * h) for p in range(6)])
    np.testing.assert_allclose(g, s0, atol=1e-7 * np.abs(s0).max())


def test_frictional_rotations_match_a_direct_minimisation():
    """With tangential springs the rotations relax: the assembled tensor equals the minimum over
    translations and rotations of the incremental energy
    1/2 sum Delta.K.Delta / V, Delta = u_j - u_i + E c - (a_i w_i + a_j w_j) x n, written here with
    cross products and minimised by L-BFGS (no microhom matrices)."""
    rng = np.random.default_rng(11)
    net = _jammed_like(rng, kt=0.5, jitter=0.03)
    C, a = relaxed(net)
    assert a.n_spins == net.n_particles and not a.rattlers.any()
    i, j = net.pairs.T
    c, n, L = net.branch, net.normals, net.lengths
    ai = L * net.radii[i] / (net.radii[i] + net.radii[j])
    aj = L - ai
    K = net.stiffness_tensors()
    N = net.n_particles

    def energy(z, E):
        u, w = z[:3 * N].reshape(N, 3), z[3 * N:].reshape(N, 3)
        d = u[j] - u[i] + c @ E.T - np.cross(ai[:, None] * w[i] + aj[:, None] * w[j], n)
        f = np.einsum("cab,cb->ca", K, d)
        gu = np.zeros((N, 3))
        np.add.at(gu, j, f)
        np.add.at(gu, i, -f)
        # d/dw_i of -(a_i w_i x n).f = -a_i (n x f)
        g_w = np.zeros((N, 3))
        nxf = np.cross(n, f)
        np.add.at(g_w, i, -ai[:, None] * nxf)
        np.add.at(g_w, j, -aj[:, None] * nxf)
        return 0.5 * np.sum(d * f), np.concatenate([gu.ravel(), g_w.ravel()])

    def W(E):
        res = minimize(energy, np.zeros(6 * N), args=(E,), jac=True, method="L-BFGS-B",
                       options={"gtol": 1e-14, "ftol": 1e-300, "maxiter": 50000, "maxcor": 50})
        return res.fun / net.volume

    idx = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
    for p in range(6):
        E = np.zeros((3, 3))
        a_, b_ = idx[p]
        E[a_, b_] = E[b_, a_] = 1.0 if a_ == b_ else 1 / SQ2
        # W = 1/2 e.C.e for the unit Mandel strain e_p: the diagonal of C
        assert 2 * W(E) == pytest.approx(C[p, p], rel=1e-7)
    # the check has teeth: the relaxation is far above its tolerance
    assert affine_tensor(net)[3, 3] - C[3, 3] > 1e-3 * C[3, 3]


def test_exact_solver_on_spheres_matches_closed_forms_and_the_dense_relaxation():
    """dem.analysis.stiffness on 3D networks: the FCC closed form, and on a disordered frictional
    packing (rotations relax) the dense pseudo-inverse above, with and without pre-stress."""
    from dem.analysis.stiffness import stiffness
    D, kn, kt = 0.8, 3.0, 0.4
    r = stiffness(lattices.fcc(2, diameter=D, kn=kn, kt=kt))
    expected = cubic(SQ2 * (kn + kt) / D, (kn - kt) / (SQ2 * D), SQ2 * (kn + kt) / D)
    np.testing.assert_allclose(r.C_mandel, expected, rtol=0, atol=1e-10 * kn / D)
    assert r.C_mandel.shape == (6, 6) and r.u.shape == (6, 32, 3) and r.omega.shape == (6, 32, 3)
    assert r.n_floppy == 0 and not r.flags
    rng = np.random.default_rng(5)
    net = _jammed_like(rng, kt=0.5, jitter=0.03)
    net = from_pairs(net.positions, net.radii, net.cell, net.pairs, shifts=net.image_shifts(),
                     kn=1.0, kt=0.5, fn=net.overlaps)
    for pre in (False, True):
        C, _ = relaxed(net, prestress=pre)
        if pre:
            C = C + tensors.prestress_correction(stress0(net))
        got = stiffness(net, prestress=pre)
        np.testing.assert_allclose(got.C_mandel, C, rtol=0, atol=1e-9 * np.abs(C).max())
        K, G = tensors.isotropic_moduli(C)
        assert got.K == pytest.approx(K, rel=1e-9) and got.G == pytest.approx(G, rel=1e-9)


def test_dem_analyse_on_a_lammps_3d_dump(capsys):
    """dem analyse on a 3D file written by LAMMPS: the exact (6, 6) tensor in Pa, the 3D statistics
    with the Voigt mean field, and the 2D-only sections refused with the reason (never a 2D formula
    on a 3D network). The end-to-end run on a LAMMPS packing is tests/test_analyse_3d.py."""
    from pathlib import Path

    from dem.analysis.analyse import ONLY_2D, SectionError, analyse_file, format_table
    from microhom.structural_sums import SphereStatistics
    res = analyse_file(Path(__file__).parent / "data" / "sph3d_tri.dump", hierarchy=False)
    assert np.shape(res.stiffness.C_mandel) == (6, 6) and res.stiffness.K > 0 and res.stiffness.G > 0
    for section in (res.theory, res.closure, res.stress):
        assert isinstance(section, SectionError) and section.message == ONLY_2D
    assert isinstance(res.structural, SphereStatistics)
    # the two affine routes agree (the fabric's over every contact, the per-contact matrices'); the
    # mean field is over the load-bearing contacts, and here 7 rattlers hold a contact each
    st = res.structural
    assert st.K_affine_all == pytest.approx(res.stiffness.K_affine, rel=1e-12)
    assert st.G_affine_all == pytest.approx(res.stiffness.G_affine, rel=1e-12)
    assert st.n_rattlers == 7 and st.K_affine < st.K_affine_all
    assert res.comparison.K_mf_over_exact == pytest.approx(res.structural.K_affine / res.stiffness.K, rel=1e-15)
    text = format_table(res)
    assert "moduli (3D, force/area)" in text and "K [Pa]" in text and "mean field (Voigt, fabric)" in text
    assert "hierarchy: n/a (not computed)" in text
