"""Tests of dem.stiffness against closed forms and independent computations (never its own output)."""
import numpy as np
import pytest
from scipy.optimize import minimize

from dem.stiffness import (StiffnessResult, affine_stiffness, isotropic_moduli, mandel_to_strain,
                           mandel_to_tensor, mandel_to_voigt, stiffness, strain_to_mandel,
                           stress_increment, tensor_to_mandel, voigt_to_mandel)
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
    assert np.all(r.C_mandel @ np.zeros(3) == 0)
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
    # jax-md convention check: B = K - p/2, G_U = G + p/2 (energy-density moduli)
    p = -0.5 * np.trace(s0)
    assert res.K > 0 and res.G > 0 and p > 0
