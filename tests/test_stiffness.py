"""Tests of dem.analysis.stiffness against closed forms and independent computations (never its own output)."""
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

import dem.analysis.stiffness
from dem.analysis.stiffness import (StiffnessResult, affine_stiffness, count_modes, factorise, have_cholmod,
                           isotropic_moduli, mandel_to_tensor, mandel_to_voigt, reduce_system, relax,
                           relaxed_tensor, stiffness, strain_to_mandel, stress_increment)
from microhom.tensors import mandel_to_strain, tensor_to_mandel, voigt_to_mandel
from microhom.kinematics import assemble
from microhom import lattices
from microhom.network import ContactNetwork, from_overlaps

S3 = np.sqrt(3.0)
REL = 1e-10


def close(a, b, rel=REL, scale=None):
    scale = abs(b) if scale is None else scale
    return abs(a - b) <= rel * max(scale, 1e-300)


# ---- notation helpers ------------------------------------------------------------------------
def test_notation_roundtrip():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(3, 3))
    m = m + m.T
    assert np.allclose(tensor_to_mandel(mandel_to_tensor(m)), m)
    assert np.allclose(voigt_to_mandel(mandel_to_voigt(m)), m)
    c = mandel_to_tensor(m)
    e = rng.normal(size=(2, 2))
    e = e + e.T
    # sigma = C : e in tensor form equals Mandel product
    s_t = np.einsum("ijkl,kl->ij", c, e)
    assert np.allclose(strain_to_mandel(s_t), m @ strain_to_mandel(e))
    assert np.allclose(mandel_to_strain(strain_to_mandel(e)), e)
    # isotropic tensor: C1111 = K+G, C1122 = K-G, C1212 = G
    K, G = 2.0, 0.7
    iso = np.array([[K + G, K - G, 0], [K - G, K + G, 0], [0, 0, 2 * G]])
    assert np.allclose(isotropic_moduli(iso), (K, G))


# ---- perfect lattices: closed forms ----------------------------------------------------------
@pytest.mark.parametrize("kt", [1.0, 0.3, 0.0])
@pytest.mark.parametrize("angle", [0.0, 0.37])
def test_triangular(kt, angle):
    kn = 2.5
    r = stiffness(lattices.triangular(6, 6, kn=kn, kt=kt * kn, angle=angle))
    assert isinstance(r, StiffnessResult)
    assert close(r.K, S3 / 2 * kn)
    assert close(r.G, S3 / 4 * (kn + kt * kn))
    assert close(r.K_affine, S3 / 2 * kn) and close(r.G_affine, S3 / 4 * (kn + kt * kn))
    # isotropic: full tensor, not just the projection
    K, G = S3 / 2 * kn, S3 / 4 * kn * (1 + kt)
    iso = np.array([[K + G, K - G, 0], [K - G, K + G, 0], [0, 0, 2 * G]])
    assert np.abs(r.C_mandel - iso).max() <= REL * K
    assert r.n_floppy == 0 and r.n_rattlers == 0
    if kt == 0:   # Poisson ratio 1/3 (2D: nu = (K - G)/(K + G))
        assert close((r.K - r.G) / (r.K + r.G), 1 / 3)


@pytest.mark.parametrize("kt", [1.0, 0.3, 0.05])
def test_honeycomb_nonaffine(kt):
    kn = 1.0
    r = stiffness(lattices.honeycomb(4, 3, kn=kn, kt=kt, angle=0.2))
    assert close(r.K, kn / (2 * S3))
    assert close(r.G, kn * kt / (S3 * (kn + kt)))
    if kt != kn:   # the shear response is non-affine: spins and translations relax
        assert r.G < r.G_affine * (1 - 1e-3)
        assert np.abs(r.omega[2]).max() > 1e-3 and np.abs(r.u[2]).max() > 1e-3


def test_honeycomb_frictionless_floppy_shear():
    r = stiffness(lattices.honeycomb(4, 3, kn=1.0, kt=0.0))
    assert close(r.K, 1 / (2 * S3))
    assert abs(r.G) <= 1e-12 and abs(r.C_mandel[2, 2]) <= 1e-12
    assert r.n_floppy > 0 and r.n_spins == 0
    assert np.all(np.isfinite(r.C_mandel))


@pytest.mark.parametrize("kt", [1.0, 0.4])
def test_square(kt):
    kn = 3.0
    r = stiffness(lattices.square(5, 5, kn=kn, kt=kt * kn))
    C = r.C
    assert close(C[0, 0, 0, 0], kn) and close(C[1, 1, 1, 1], kn)
    assert abs(C[0, 0, 1, 1]) <= REL * kn
    assert close(C[0, 1, 0, 1], kt * kn / 2)
    assert r.n_floppy == 0


def test_square_frictionless_floppy():
    kn = 3.0
    r = stiffness(lattices.square(5, 6, kn=kn, kt=0.0))
    C = r.C
    assert np.all(np.isfinite(r.C_mandel))
    assert close(C[0, 0, 0, 0], kn) and close(C[1, 1, 1, 1], kn)
    assert abs(C[0, 1, 0, 1]) <= 1e-14 * kn and abs(C[0, 0, 1, 1]) <= 1e-14 * kn
    # rows slide (ny modes), columns slide (nx modes), minus the 2 pinned translations
    assert r.n_floppy == 5 + 6 - 2
    assert r.residual < 1e-12
    r2 = stiffness(lattices.square(5, 6, kn=kn, kt=0.0), count="rescale")
    assert r2.n_floppy == r.n_floppy


def test_sliding_is_frictionless():
    net = lattices.triangular(6, 6, kn=1.0, kt=1.0, sliding=True)
    r = stiffness(net)
    assert close(r.G, S3 / 4) and r.n_spins == 0


# ---- zero load, rigid rotation, fields -------------------------------------------------------
def test_zero_strain_and_rigid_rotation():
    net = _diluted(8, 8, z=4.5, kt=0.6, seed=3)
    r = stiffness(net)
    # zero strain: the named steps relax a zero load to exactly zero fields, and the tensor of
    # zero fields is the affine tensor of the kept contacts (a plain sum written here)
    asm = assemble(net)
    red = reduce_system(asm)
    f = factorise(red, "splu")
    Q0, res0, _ = relax(f, replace(red, F=np.zeros_like(red.F)), asm.F_scale)
    assert np.all(Q0 == 0) and res0 == 0
    c0, _ = relaxed_tensor(asm, np.zeros((asm.ndof, 3)), net.area)
    kept = asm.net
    D = np.zeros((kept.n_contacts, 2, 3))
    c = kept.branch
    D[:, 0, 0], D[:, 1, 1] = c[:, 0], c[:, 1]
    D[:, 0, 2], D[:, 1, 2] = c[:, 1] / np.sqrt(2), c[:, 0] / np.sqrt(2)
    caff = np.einsum("cai,cab,cbj->ij", D, kept.stiffness_tensors(), D) / net.area
    assert np.abs(c0 - caff).max() <= 1e-14 * np.abs(caff).max()
    assert np.all(r.C_mandel @ np.eye(3) == r.C_mandel) and r.K < r.K_affine
    assert np.all(stress_increment(net, np.zeros((2, 2))) == 0)
    th = 1e-3
    rot = np.array([[0.0, -th], [th, 0.0]])       # rigid rotation: particles spin with the cell
    s = stress_increment(net, rot, np.zeros((net.n_particles, 2)), np.full(net.n_particles, th))
    assert np.abs(s).max() <= 1e-15 * th * r.K_affine
    # a finite rigid rotation of the whole network leaves the tensor rotated, K and G unchanged
    net_r = lattices.triangular(6, 6, kn=1.0, kt=0.5, angle=0.9)
    assert close(stiffness(net_r).G, S3 / 4 * 1.5)


def test_relaxed_fields_reproduce_tensor():
    """stress computed contact by contact from the relaxed (u, omega) equals the tensor columns."""
    net = _diluted(8, 8, z=4.5, kt=0.6, seed=4)
    r = stiffness(net)
    assert r.n_rattlers > 0
    ratt = r.rattler_mask
    kept = net.select_contacts(~(ratt[net.pairs[:, 0]] | ratt[net.pairs[:, 1]]))
    for b in range(3):
        e = mandel_to_strain(np.eye(3)[b])
        s = stress_increment(kept, e, r.u[b], r.omega[b])
        assert np.abs(strain_to_mandel(s) - r.C_mandel[:, b]).max() <= 1e-10 * r.K_affine


# ---- disordered networks vs an independent dense computation ---------------------------------
def _diluted(nx, ny, z=4.3, kt=1.0, seed=0, jitter=0.2, poly=0.2):
    """Perturbed, polydisperse-armed, randomly diluted triangular network."""
    rng = np.random.default_rng(seed)
    base = lattices.triangular(nx, ny, kn=1.0, kt=1.0)
    sh = base.image_shifts()
    pos = base.positions + jitter * 0.5 * rng.uniform(-1, 1, base.positions.shape)
    rad = 0.5 * (1 + poly * rng.uniform(-1, 1, base.n_particles))
    i, j = base.pairs.T
    br = pos[j] + sh @ base.cell.T - pos[i]
    keep = rng.random(base.n_contacts) < z / 6
    m = int(keep.sum())
    return ContactNetwork(positions=pos, radii=rad, cell=base.cell, pairs=base.pairs[keep],
                          branch=br[keep], kn=rng.uniform(0.5, 2.0, m),
                          kt=kt * rng.uniform(0.5, 1.0, m), sliding=rng.random(m) < 0.1)


def _dense_reference(net):
    """C = C_aff - F^T H^+ F / A by a plain loop over contacts and a dense pseudo-inverse.

    Written independently: dofs [ux, uy, w] per particle, every particle, no pinning."""
    N = net.n_particles
    H = np.zeros((3 * N, 3 * N))
    F = np.zeros((3 * N, 3))
    Caff = np.zeros((3, 3))
    s2 = np.sqrt(2.0)
    for k in range(net.n_contacts):
        i, j = net.pairs[k]
        c = net.branch[k]
        L = np.hypot(*c)
        n = c / L
        t = np.array([-n[1], n[0]])
        kt = 0.0 if net.sliding[k] else net.kt[k]
        Kc = net.kn[k] * np.outer(n, n) + kt * (np.eye(2) - np.outer(n, n))
        ai = L * net.radii[i] / (net.radii[i] + net.radii[j])
        aj = L * net.radii[j] / (net.radii[i] + net.radii[j])
        Bk = np.zeros((2, 3 * N))
        Bk[:, 3 * i:3 * i + 2] -= np.eye(2)
        Bk[:, 3 * j:3 * j + 2] += np.eye(2)
        Bk[:, 3 * i + 2] -= ai * t
        Bk[:, 3 * j + 2] -= aj * t
        Dk = np.array([[c[0], 0.0, c[1] / s2], [0.0, c[1], c[0] / s2]])
        H += Bk.T @ Kc @ Bk
        F += Bk.T @ Kc @ Dk
        Caff += Dk.T @ Kc @ Dk
    A = abs(np.linalg.det(net.cell))
    Hp = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
    return (Caff - F.T @ Hp @ F) / A, Caff / A


@pytest.mark.parametrize("kt,seed", [(1.0, 0), (0.3, 1), (0.0, 2)])
def test_random_network_vs_dense(kt, seed):
    net = _diluted(6, 8, z=4.6 if kt > 0 else 5.2, kt=kt, seed=seed)
    # min_contacts=1: keep every particle that has a contact, so the dense reference (no
    # rattler removal at all) sees exactly the same mechanics; floppy modes stay in the problem
    r = stiffness(net, min_contacts=1)
    ref, ref_aff = _dense_reference(net)
    scale = np.abs(ref_aff).max()
    assert np.abs(r.C_affine_mandel - ref_aff).max() <= 1e-12 * scale
    assert np.abs(r.C_mandel - ref).max() <= 1e-10 * scale, (r.C_mandel, ref)
    # symmetric, and relaxed <= affine (positive semi-definite difference)
    assert np.abs(r.C_mandel - r.C_mandel.T).max() <= 1e-14 * scale
    assert np.linalg.eigvalsh(r.C_affine_mandel - r.C_mandel).min() >= -1e-12 * scale
    assert np.linalg.eigvalsh(r.C_mandel).min() >= -1e-12 * scale
    # default rattler removal (exact for frictional disks: a 1-contact disk carries nothing)
    if kt > 0:
        r2 = stiffness(net)
        assert np.abs(r2.C_mandel - ref).max() <= 1e-10 * scale
        assert r2.n_rattlers == int(np.sum(r2.rattler_mask))


def test_affine_function_and_errors():
    net = lattices.triangular(6, 6, kn=1.0, kt=0.2)
    assert np.allclose(affine_stiffness(net), stiffness(net).C_affine_mandel)
    with pytest.raises(ValueError):
        stiffness(from_overlaps(net.positions, net.radii, None))
    with pytest.raises(ValueError):
        stiffness(net, prestress=True)          # no fn


def test_all_rattlers_is_finite():
    net = lattices.triangular(6, 6).select_contacts(np.zeros(108, dtype=bool))
    with pytest.warns(RuntimeWarning, match=r"not jammed: every particle \(36\) is a rattler"):
        r = stiffness(net)
    assert r.n_rattlers == 36 and r.n_dof == 0 and np.all(r.C_mandel == 0)


# ---- frictionless harmonic disks with pre-stress vs finite-difference energy minimisation ----
def _energy(x, cell, rad, kn):
    """Harmonic soft disks: U = sum 1/2 kn overlap^2 (all pairs, minimum image, small N)."""
    N = rad.size
    p = x.reshape(N, 2)
    hinv = np.linalg.inv(cell)
    d = p[None, :, :] - p[:, None, :]
    s = d @ hinv.T
    d = (s - np.rint(s)) @ cell.T
    r = np.sqrt((d ** 2).sum(-1) + np.eye(N))
    ov = np.triu(np.clip(rad[:, None] + rad[None, :] - r, 0, None), 1)
    U = 0.5 * kn * (ov ** 2).sum()
    fmag = kn * (ov + ov.T)                              # repulsive force magnitude per pair
    g = (fmag[:, :, None] * d / r[:, :, None]).sum(axis=1)   # dU/dx_i
    return U, g.ravel(), d, r, ov


def _hessian(x, cell, rad, kn):
    N = rad.size
    _, _, d, r, ov = _energy(x, cell, rad, kn)
    Hm = np.zeros((2 * N, 2 * N))
    for i in range(N):
        for j in range(i + 1, N):
            if ov[i, j] <= 0:
                continue
            n = d[i, j] / r[i, j]
            T = -kn * ov[i, j]                            # tension
            k = kn * np.outer(n, n) + T / r[i, j] * (np.eye(2) - np.outer(n, n))
            for a, b, sgn in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
                Hm[2 * a:2 * a + 2, 2 * b:2 * b + 2] += sgn * k
    return Hm


def _relax(x, cell, rad, kn):
    res = minimize(lambda y: _energy(y, cell, rad, kn)[:2], x, jac=True, method="L-BFGS-B",
                   options=dict(maxiter=20000, gtol=1e-13, ftol=1e-300, maxcor=30))
    x = res.x
    for _ in range(30):                                   # Newton polish (pseudo-inverse)
        g = _energy(x, cell, rad, kn)[1]
        if np.abs(g).max() < 1e-15:
            break
        x = x - np.linalg.lstsq(_hessian(x, cell, rad, kn), g, rcond=1e-10)[0]
    return x


def _stress(x, cell, rad, kn):
    _, _, d, r, ov = _energy(x, cell, rad, kn)
    iu = np.nonzero(ov > 0)
    n = d[iu] / r[iu][:, None]
    fn = kn * ov[iu]
    return -(fn[:, None, None] * r[iu][:, None, None] * n[:, :, None] * n[:, None, :]).sum(0) / abs(
        np.linalg.det(cell))


def test_prestressed_frictionless_packing_vs_finite_differences():
    rng = np.random.default_rng(7)
    N, kn = 24, 1.0
    rad = np.where(np.arange(N) < N // 2, 0.5, 0.7)
    L = np.sqrt(np.pi * (rad ** 2).sum() / 0.90)
    cell = np.array([[L, 0.15 * L], [0.0, L]])
    x = _relax(rng.uniform(0, L, 2 * N), cell, rad, kn)
    _, _, d, r, ov = _energy(x, cell, rad, kn)
    gaps = (r - rad[:, None] - rad[None, :])[np.triu_indices(N, 1)]
    assert np.abs(gaps).min() > 1e-4            # no pair on the verge of touching
    pos = x.reshape(N, 2)
    net = from_overlaps(pos, rad, cell, kn=kn, kt=0.0)
    ov_c = rad[net.pairs[:, 0]] + rad[net.pairs[:, 1]] - net.lengths
    net = ContactNetwork(positions=net.positions, radii=net.radii, cell=net.cell, pairs=net.pairs,
                         branch=net.branch, kn=kn, kt=0.0, sliding=False, fn=kn * ov_c)
    res = stiffness(net, prestress=True)
    s0 = _stress(x, cell, rad, kn)
    assert np.allclose(res.stress0_mandel, strain_to_mandel(s0), rtol=1e-12, atol=0)
    fd = np.zeros((3, 3))
    h = 1e-6
    for b in range(3):
        sig = []
        for sgn in (1, -1):
            E = mandel_to_strain(sgn * h * np.eye(3)[b])
            F = np.eye(2) + E
            xs = _relax((pos @ F.T).ravel(), F @ cell, rad, kn)
            sig.append(strain_to_mandel(_stress(xs, F @ cell, rad, kn)))
        fd[:, b] = (sig[0] - sig[1]) / (2 * h)
    scale = np.abs(fd).max()
    assert np.abs(res.C_mandel - fd).max() <= 1e-6 * scale, (res.C_mandel, fd)
    assert res.n_unstable == 0
    # jax-md convention check: the energy-density moduli (second derivative of U/A0 in the
    # linear strain, relaxed: jax-md's athermal_moduli) are B = K - p/2, G_U = G + p/2; measured
    # here from finite differences of the relaxed energy itself, not from any stress
    p = -0.5 * np.trace(s0)
    A0 = abs(np.linalg.det(cell))
    h = 1e-4

    def d2U(e_mandel):
        U = []
        for sgn in (1, 0, -1):
            F = np.eye(2) + mandel_to_strain(sgn * h * np.asarray(e_mandel, float))
            xs = _relax((pos @ F.T).ravel(), F @ cell, rad, kn)
            U.append(_energy(xs, F @ cell, rad, kn)[0])
        return (U[0] - 2 * U[1] + U[2]) / (h * h * A0)

    B_U = d2U([1, 1, 0]) / 4
    G_U = (d2U([1, -1, 0]) / 4 + d2U([0, 0, np.sqrt(2)]) / 4) / 2
    assert p > 1e3 * 1e-6 * res.K                  # the conversion is far above the tolerance
    assert abs(B_U - (res.K - p / 2)) <= 1e-6 * res.K, (B_U, res.K, p)
    assert abs(G_U - (res.G + p / 2)) <= 1e-6 * res.K, (G_U, res.G, p)


# ---- named steps, solvers and degenerate input (issues 12.4 and 15 rows 7, 8, 17) -------------
@pytest.mark.skipif(not have_cholmod(), reason="scikit-sparse (CHOLMOD) not installed")
def test_cholmod_agrees_with_superlu():
    net = _diluted(12, 12, z=4.5, kt=0.6, seed=5)
    a, b = stiffness(net, solver="cholmod"), stiffness(net, solver="splu")
    assert a.solver == "cholmod" and b.solver == "splu"
    assert np.abs(a.C_mandel - b.C_mandel).max() <= 1e-12 * np.abs(b.C_mandel).max()
    assert a.n_floppy == b.n_floppy and a.n_rattlers == b.n_rattlers


def test_superlu_fallback_without_cholmod(monkeypatch):
    monkeypatch.setattr(dem.analysis.stiffness, "_cholmod", None)
    r = stiffness(lattices.triangular(6, 6, kn=1.0, kt=0.5))
    assert r.solver == "splu" and close(r.K, S3 / 2)
    with pytest.raises(RuntimeError, match="libsuitesparse-dev"):
        stiffness(lattices.triangular(6, 6), solver="cholmod")
    with pytest.raises(ValueError, match="solver"):
        stiffness(lattices.triangular(6, 6), solver="umfpack")


@pytest.mark.parametrize("solver", ["splu", "auto", "cholmod"])
def test_count_modes_step_on_the_frictionless_square(solver):
    """nx + ny - 2 sliding modes of the 5x6 frictionless square lattice, from the pivots of
    either factor, with each counting rule."""
    if solver == "cholmod" and not have_cholmod():
        pytest.skip("scikit-sparse (CHOLMOD) not installed")
    asm = assemble(lattices.square(5, 6, kn=3.0, kt=0.0))
    red = reduce_system(asm)
    for rule in ("pivots", "rescale", "auto"):
        f = factorise(red, solver, pairs=asm.net.pairs, n_particles=30)
        m = count_modes(f, red, rule)
        assert m.n_floppy == 5 + 6 - 2 and m.n_unstable == 0, (rule, m)
        Q, res, _ = relax(m.factor or f, red, asm.F_scale)     # the factor to solve with
        assert res < 1e-12


@pytest.mark.parametrize("ratio", [1e4, 1e7, 1e8])
def test_stiffness_ratio_keeps_the_floppy_count(ratio):
    """Row 7: kt/kn up to 1e8 gives the floppy count of kt/kn = 1 (kt > 0 everywhere: the same
    rigidity) and is flagged beyond 1e6; beyond 1e9 it is refused with the reason."""
    net = _diluted(10, 10, z=3.6, kt=1.0, seed=2)
    ref = stiffness(net)
    assert ref.n_floppy == 3 and ref.ok
    stiff = net.with_stiffness(kt=net.kt * ratio)
    if ratio > 1e6:
        with pytest.warns(RuntimeWarning, match="ill-conditioned"):
            r = stiffness(stiff)
        assert any("ill-conditioned" in f for f in r.flags)
    else:
        r = stiffness(stiff)
    assert r.n_floppy == ref.n_floppy and r.residual < 1e-12
    with pytest.raises(ValueError, match="stiffness ratio"):
        stiffness(net.with_stiffness(kt=net.kt * 1e10))


@pytest.mark.parametrize("scale", [1e300, 1e-300])
def test_extreme_stiffness_units_scale_exactly(scale, recwarn):
    """Row 7: kn = 1e300 overflowed (NaN residual); the solve now runs on kn / 2^k."""
    net = _diluted(8, 8, z=4.5, kt=0.6, seed=3)
    ref = stiffness(net)
    r = stiffness(net.with_stiffness(kn=net.kn * scale, kt=net.kt * scale))
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert np.abs(r.C_mandel / scale - ref.C_mandel).max() <= 1e-13 * np.abs(ref.C_mandel).max()
    assert r.n_floppy == ref.n_floppy and np.isfinite(r.residual) and r.residual < 1e-12


def test_lattice_in_tension_is_flagged_unstable():
    """Row 8: fn = -10 (tension) on a triangular lattice: K = sqrt3/2 kn - p... < 0; the tensor
    has a negative eigenvalue although the Hessian has none: flagged, with a warning."""
    t = lattices.triangular(6, 6, kn=1.0, kt=0.0)
    net = replace(t, fn=np.full(t.n_contacts, -10.0))
    with pytest.warns(RuntimeWarning, match="unstable"):
        r = stiffness(net, prestress=True)
    # closed form: stress-free K = sqrt3/2 kn, geometric and pre-stress terms with p = -10 sqrt3 ... < 0
    assert r.K < 0 and np.linalg.eigvalsh(0.5 * (r.C_mandel + r.C_mandel.T)).min() < 0
    assert r.n_unstable == 0 and not r.ok
    assert any(f.startswith("unstable") for f in r.flags)


def test_gas_frame_is_flagged_not_jammed():
    """Row 17: a gas (few contacts, every particle a rattler) -> C = 0 flagged 'not jammed';
    a sparse network whose kept part is floppy -> the same flag with the floppy count."""
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 40, (200, 2))
    gas = from_overlaps(pos, np.full(200, 0.5), np.diag([40.0, 40.0]), kn=1.0, kt=0.0)
    with pytest.warns(RuntimeWarning, match="not jammed"):
        r = stiffness(gas)
    assert any("not jammed" in f for f in r.flags) and np.all(r.C_mandel == 0)
    sparse = _diluted(10, 10, z=2.6, kt=0.0, seed=2)
    with pytest.warns(RuntimeWarning, match="not jammed"):
        r = stiffness(sparse, min_contacts=1)
    assert r.n_floppy > 0 and abs(r.K) <= 1e-10 * r.K_affine
    assert any(f.startswith("not jammed") and "floppy" in f for f in r.flags)


def test_floppy_is_flagged_without_a_warning(recwarn):
    r = stiffness(lattices.square(5, 6, kn=3.0, kt=0.0))
    assert [f for f in r.flags if f.startswith("floppy")] and not r.ok
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_result_exports():
    r = stiffness(lattices.triangular(6, 6, kn=1.0, kt=0.5))
    d = r.as_dict()
    assert d["K"] == r.K and "u" not in d and d["flags"] == [] and r.ok
    with pytest.raises(Exception):
        r.K = 0.0                                # frozen


# ---- PARDISO (the default where the mkl wheel loads) and the memory guard (issue 22 items 4, 5) --
needs_pardiso = pytest.mark.skipif(not dem.analysis.stiffness.have_pardiso(), reason="mkl wheel not installed")


@needs_pardiso
@pytest.mark.parametrize("kt", [0.6, 0.0])
def test_pardiso_agrees_with_superlu(kt):
    net = _diluted(14, 14, z=4.4 if kt else 5.5, kt=kt, seed=5)
    a, b = stiffness(net, solver="pardiso"), stiffness(net, solver="splu", count="rescale")
    assert a.solver == "pardiso" and b.solver == "splu" and a.count_method == "inertia"
    assert np.abs(a.C_mandel - b.C_mandel).max() <= 1e-11 * np.abs(b.C_mandel).max()
    assert a.n_floppy == b.n_floppy and a.n_rattlers == b.n_rattlers and a.residual < 1e-12


@needs_pardiso
def test_pardiso_floppy_count_of_the_frictionless_square():
    """nx + ny - 2 sliding modes (closed form) from the inertia of LDL^T(H - eta diag H)."""
    asm = assemble(lattices.square(5, 6, kn=3.0, kt=0.0))
    red = reduce_system(asm)
    f = factorise(red, "pardiso")
    m = count_modes(f, red, psd=False)
    assert (m.n_floppy, m.n_unstable, m.method) == (5 + 6 - 2, 0, "inertia")
    Q, res, _ = relax(f, red, asm.F_scale)
    assert res < 1e-12
    r = stiffness(lattices.square(5, 6, kn=3.0, kt=0.0), solver="pardiso")
    assert r.n_floppy == 9 and abs(r.C_mandel[2, 2]) <= 1e-12 * 3.0


@needs_pardiso
def test_pardiso_counts_negative_modes_under_prestress():
    """A compressed frictionless triangular lattice whose pre-stress exceeds what the lattice
    carries: the negative modes of the pencil (H, diag H) counted by a dense eigen-solve,
    against the PARDISO inertia and SuperLU's pivots."""
    t = lattices.triangular(6, 6, kn=1.0, kt=0.0)
    net = replace(t, fn=np.full(t.n_contacts, 0.8))     # 33 negative modes, none near zero
    asm = assemble(net, prestress=True)
    red = reduce_system(asm)
    d = red.d
    w = np.linalg.eigvalsh((red.H / np.sqrt(np.outer(d, d))).toarray())
    n_neg, n_zero = int((w < -1e-9).sum()), int((np.abs(w) <= 1e-9).sum())
    assert n_neg > 0
    with pytest.warns(RuntimeWarning, match="unstable"):
        a = stiffness(net, prestress=True, solver="pardiso")
    with pytest.warns(RuntimeWarning, match="unstable"):
        b = stiffness(net, prestress=True, solver="splu")
    assert a.n_unstable == b.n_unstable == n_neg
    assert a.n_floppy == b.n_floppy == n_zero + red.n_zero
    assert np.abs(a.C_mandel - b.C_mandel).max() <= 1e-9 * np.abs(b.C_mandel).max()


@pytest.mark.skipif(not have_cholmod(), reason="scikit-sparse (CHOLMOD) not installed")
def test_cholmod_falls_back_to_superlu_under_negative_modes():
    """CHOLMOD refuses the pre-stressed lattice with negative modes (not positive definite);
    SuperLU's pivots then count them, as many as a dense eigen-solve of the pencil (H, diag H)."""
    t = lattices.triangular(6, 6, kn=1.0, kt=0.0)
    net = replace(t, fn=np.full(t.n_contacts, 0.8))
    red = reduce_system(assemble(net, prestress=True))
    w = np.linalg.eigvalsh((red.H / np.sqrt(np.outer(red.d, red.d))).toarray())
    with pytest.warns(RuntimeWarning, match="unstable"):
        r = stiffness(net, prestress=True, solver="cholmod")
    assert r.solver == "splu" and r.n_unstable == int((w < -1e-9).sum()) > 0


def test_memory_guard_refuses_before_assembling(monkeypatch):
    """Item 5: a predicted peak above max_memory is refused with the figure, before the
    assembly allocates anything."""
    net = _diluted(8, 8, seed=1)

    def boom(*a, **k):
        raise AssertionError("assemble must not run")

    monkeypatch.setattr(dem.analysis.stiffness, "assemble", boom)
    with pytest.raises(dem.analysis.stiffness.MemoryGuardError, match=r"predicted .* GB, available .* GB"):
        stiffness(net, max_memory=1e6)
    with pytest.raises(ValueError, match="max_memory"):
        stiffness(net, max_memory=-1.0)


def test_predicted_memory_covers_the_measured_peaks():
    """The prediction against peaks measured by studies.bench_stiffness (docs/stiffness.md):
    1e5 disks (295 246 unknowns) 0.68 GB with PARDISO, 1.2-2.0 GB with SuperLU; 1e6 disks 5.3 GB
    with CHOLMOD; and a 4e6-disk network is refused on a 23 GB machine."""
    pm = dem.analysis.stiffness.predicted_memory
    assert 0.68e9 <= pm(99_960, 295_246, "pardiso") <= 3 * 0.68e9
    assert 2.0e9 <= pm(99_960, 295_246, "splu") <= 3 * 2.0e9
    assert 5.3e9 <= pm(999_750, 2_955_742, "cholmod") <= 3 * 5.3e9
    assert pm(4_000_000, 12_000_000, "pardiso") > 23e9


@needs_pardiso
def test_pardiso_stiffness_ratio_keeps_the_floppy_count():
    """Row 7 with PARDISO's inertia count: kt/kn up to 1e8 keeps the 3 floppy modes of kt/kn = 1
    (counted by SuperLU's pivots in test_stiffness_ratio_keeps_the_floppy_count)."""
    net = _diluted(10, 10, z=3.6, kt=1.0, seed=2)
    ref = stiffness(net, solver="splu")
    for ratio in (1.0, 1e4, 1e8):
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            r = stiffness(net.with_stiffness(kt=net.kt * ratio), solver="pardiso")
        said = [str(w.message).split(":")[0] for w in rec if issubclass(w.category, RuntimeWarning)]
        assert said == (["ill-conditioned"] if ratio > 1e6 else []), said   # RATIO_WARN = 1e6
        assert r.count_method == "inertia" and r.n_floppy == ref.n_floppy == 3 and r.residual < 1e-12
