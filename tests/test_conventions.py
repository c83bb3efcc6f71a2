"""Peers' conventions and per-contact laws: a jax-md-style tensor from positions and radii in one
call, checked against independent computations (a sympy closed form on a lattice and finite
differences of the relaxed energy of a random packing), never against the code under test."""
import math

import numpy as np
import pytest
import sympy
from scipy.optimize import minimize

from dem.analysis.peers import jaxmd_elasticity
from microhom import conventions, laws, lattices
from microhom.network import from_overlaps, from_pairs
from microhom.tensors import isotropic_moduli, mandel_to_strain, prestress_correction


# ---- closed form: compressed triangular lattice of harmonic soft disks -----------------------
def _lattice_energy_tensor(d, sigma, eps, angle):
    """Mandel second derivative of U/V0 w.r.t. the linear strain (sympy), triangular lattice of
    spacing d, harmonic soft-sphere pairs U = eps/2 (1 - r/sigma)^2: 3 bonds per particle, cell
    area sqrt3/2 d^2 per particle. The lattice is centro-symmetric: no non-affine relaxation."""
    e = sympy.symbols("e0:3", real=True)
    E = sympy.Matrix([[e[0], e[2] / sympy.sqrt(2)], [e[2] / sympy.sqrt(2), e[1]]])
    U = 0
    for k in range(3):
        th = angle + k * sympy.pi / 3
        c = sympy.Matrix([d * sympy.cos(th), d * sympy.sin(th)])
        r = sympy.sqrt(((sympy.eye(2) + E) * c).dot((sympy.eye(2) + E) * c))
        U += eps / 2 * (1 - r / sigma) ** 2
    W = U / (sympy.sqrt(3) / 2 * d ** 2)
    H = sympy.hessian(W, e).subs({x: 0 for x in e})
    return np.array(H.evalf(30), dtype=float)


@pytest.mark.parametrize("angle", [0.0, 0.4])
def test_jaxmd_tensor_of_triangular_lattice_closed_form(angle):
    overlap, eps = 0.02, 3.0                        # disks of diameter 1, spacing 0.98
    lat = lattices.triangular(6, 6, angle=angle)
    s = 1.0 - overlap
    res = jaxmd_elasticity(lat.positions * s, 0.5, lat.cell * s, epsilon=eps)
    closed = _lattice_energy_tensor(sympy.Rational(98, 100), 1, eps, sympy.Float(angle, 30))
    assert res.n_contacts == 3 * lat.n_particles and res.n_unstable == 0
    assert np.allclose(res.C_mandel, closed, rtol=0, atol=1e-12 * np.abs(closed).max())
    # the pressure of the lattice: p = sqrt3 fn / d with fn = (eps/sigma^2) overlap
    assert res.pressure == pytest.approx(math.sqrt(3) * eps * overlap / s, rel=1e-12)
    # jax-md's B, G and our K, G differ by exactly p/2
    assert res.K == pytest.approx(res.B + res.pressure / 2, rel=1e-12)
    assert res.G_cauchy == pytest.approx(res.G - res.pressure / 2, rel=1e-12)


# ---- finite differences: relaxed energy of a random bidisperse packing -------------------------
def _energy(x, cell, rad, eps):
    """Harmonic soft disks, all pairs by minimum image: U = sum eps/2 (1 - r/sigma)^2, its gradient."""
    N = rad.size
    p = x.reshape(N, 2)
    d = p[None, :, :] - p[:, None, :]
    s = np.linalg.solve(cell, d.reshape(-1, 2).T).T
    d = ((s - np.rint(s)) @ cell.T).reshape(N, N, 2)
    r = np.sqrt((d ** 2).sum(-1) + np.eye(N))
    sig = rad[:, None] + rad[None, :]
    ov = np.clip(1.0 - r / sig, 0.0, None) * (1 - np.eye(N))
    U = 0.25 * eps * (ov ** 2).sum()                 # each pair counted twice
    dU_dr = -eps * ov / sig
    g = -(dU_dr[:, :, None] * d / r[:, :, None]).sum(axis=1)
    return U, g.ravel()


def _relaxed_energy(x0, cell, rad, eps):
    res = minimize(lambda y: _energy(y, cell, rad, eps), x0, jac=True, method="L-BFGS-B",
                   options=dict(maxiter=50000, gtol=1e-11, ftol=1e-300, maxcor=10))
    return res.fun, res.x


def test_jaxmd_tensor_of_random_packing_vs_energy_finite_differences():
    rng = np.random.default_rng(11)
    N, eps = 24, 1.0
    rad = np.where(np.arange(N) < N // 2, 0.5, 0.7)
    L = np.sqrt(np.pi * (rad ** 2).sum() / 0.92)
    cell = np.array([[L, 0.1 * L], [0.0, L]])
    U0, x = _relaxed_energy(rng.uniform(0, L, 2 * N), cell, rad, eps)
    pos = x.reshape(N, 2)

    # the one call. This small packing, relaxed in a fixed cell, is not stable under a controlled
    # stress: the symmetric part of its Cauchy-increment tensor has a negative eigenvalue (the
    # energy-density tensor is positive definite), and the solver says so; the finite
    # differences below confirm it independently
    with pytest.warns(RuntimeWarning, match=r"unstable: the tensor has a negative eigenvalue"):
        res = jaxmd_elasticity(pos, rad, cell, epsilon=eps)
    assert res.n_unstable == 0 and res.n_contacts > 2 * N

    V0 = abs(np.linalg.det(cell))
    h = 2e-5

    def W(v):
        F = np.eye(2) + mandel_to_strain(v)
        return _relaxed_energy((pos @ F.T).ravel(), F @ cell, rad, eps)[0] / V0

    e = np.eye(3)
    fd = np.zeros((3, 3))
    for a in range(3):
        fd[a, a] = (W(h * e[a]) - 2 * U0 / V0 + W(-h * e[a])) / h ** 2
        for b in range(a):
            fd[a, b] = fd[b, a] = (W(h * (e[a] + e[b])) - W(h * (e[a] - e[b])) - W(h * (e[b] - e[a]))
                                   + W(-h * (e[a] + e[b]))) / (4 * h ** 2)
    scale = np.abs(fd).max()
    assert np.abs(res.C_mandel - fd).max() < 1e-5 * scale, (res.C_mandel, fd)
    # the warning is true of the energy itself: the finite-difference tensor is positive definite,
    # its Cauchy-increment form (pre-stress added) is not (measured -0.0140 against 0.016 and 0.79)
    c_fd = conventions.cauchy_from_energy_density(fd, res.sigma0)
    assert np.linalg.eigvalsh(fd).min() > 0.01 * scale
    assert np.linalg.eigvalsh(0.5 * (c_fd + c_fd.T)).min() < -0.01 * scale
    # and the relaxation matters here: the affine tensor is measurably stiffer
    assert res.stiffness.K_affine > 1.01 * res.stiffness.K
    # fractional coordinates (jax-md's default) give the same tensor
    with pytest.warns(RuntimeWarning, match=r"unstable: the tensor has a negative eigenvalue"):
        frac = jaxmd_elasticity(np.linalg.solve(cell, pos.T).T, rad, cell, epsilon=eps,
                                fractional_coordinates=True)
    assert np.allclose(frac.C_mandel, res.C_mandel, rtol=0, atol=1e-10 * scale)


# ---- the conversions --------------------------------------------------------------------------
def test_isotropic_prestress_shift_is_p_over_2():
    p = 0.37
    dk, dg = isotropic_moduli(prestress_correction(-p * np.eye(2)))
    assert dk == pytest.approx(p / 2, rel=1e-14) and dg == pytest.approx(-p / 2, rel=1e-14)
    assert conventions.moduli_from_jaxmd(*conventions.jaxmd_moduli(2.0, 1.0, p), p) == pytest.approx((2.0, 1.0))
    assert conventions.jaxmd_moduli(2.0, 1.0, p) == pytest.approx((2.0 - p / 2, 1.0 + p / 2))


def test_tensor_conversions_round_trip():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(3, 3))
    C = A @ A.T
    s0 = rng.normal(size=(2, 2))
    s0 = s0 + s0.T
    assert np.allclose(conventions.tensor_from_jaxmd(conventions.jaxmd_tensor(C, s0), s0), C, atol=1e-14)
    assert np.allclose(conventions.cauchy_from_energy_density(
        conventions.energy_density_from_cauchy(C, s0), s0), C, atol=1e-14)
    with pytest.raises(ValueError, match="sigma0"):
        conventions.energy_density_from_cauchy(C, np.eye(3))
    assert conventions.kn_from_oval(conventions.kn_to_oval(3.0)) == 3.0
    assert conventions.kn_from_oval(2.0) == 1.0
    assert conventions.lammps_kt(7.0) == pytest.approx(2.0)
    assert conventions.lammps_kt(7.0, 5.0) == 5.0


# ---- laws: fn = dU/d overlap, kn = d fn / d overlap (central differences) -----------------------
@pytest.mark.parametrize("law", [laws.Linear(kn=2.0), laws.harmonic(3.0), laws.SoftSphere(2.0, 2.5),
                                 laws.Hertz(kh=5.0), laws.Hertz(kh=5.0, reff=True)])
def test_law_force_and_stiffness_are_derivatives(law):
    ri, rj, ov, h = np.array([0.5, 0.7]), np.array([0.6, 0.4]), np.array([0.01, 0.03]), 1e-6
    fd_f = (law.energy(ri, rj, ov + h) - law.energy(ri, rj, ov - h)) / (2 * h)
    fd_k = (law.force(ri, rj, ov + h) - law.force(ri, rj, ov - h)) / (2 * h)
    assert np.allclose(law.force(ri, rj, ov), fd_f, rtol=1e-8)
    assert np.allclose(law.stiffness(ri, rj, ov), fd_k, rtol=1e-8)
    assert np.all(law.force(ri, rj, -ov) == 0) and np.all(law.stiffness(ri, rj, -ov) == 0)


def test_law_values():
    assert laws.harmonic(2.0).stiffness(0.5, 0.75, 0.01) == pytest.approx(2.0 / 1.25 ** 2)
    assert laws.Hertz(4.0, reff=True).force(1.0, 1.0, 0.04) == pytest.approx(4.0 * math.sqrt(0.5 * 0.04) * 0.04)
    with pytest.raises(ValueError, match="alpha"):
        laws.SoftSphere(alpha=1.5)
    with pytest.raises(ValueError, match="kn"):
        laws.Linear(kn=-1.0)


# ---- per-contact stiffness: functions, caller-aligned arrays, clear errors ----------------------
def _packing():
    lat = lattices.triangular(6, 6)
    rng = np.random.default_rng(3)
    rad = 0.5 + 0.01 * rng.uniform(size=lat.n_particles)
    return lat.positions * 0.99, rad, lat.cell * 0.99


def test_kn_as_function_of_contact():
    pos, rad, cell = _packing()
    net = from_overlaps(pos, rad, cell, kn=lambda i, j, ri, rj, ov: 1.0 / (ri + rj) ** 2, kt=0.0)
    ri, rj = rad[net.pairs[:, 0]], rad[net.pairs[:, 1]]
    assert np.array_equal(net.kn, 1.0 / (ri + rj) ** 2)
    assert np.all(net.kt == 0)
    law = from_overlaps(pos, rad, cell, law=laws.harmonic())
    assert np.array_equal(law.pairs, net.pairs)
    assert np.allclose(law.kn, net.kn, rtol=1e-15)
    assert np.allclose(law.fn, law.kn * law.overlaps, rtol=1e-14)     # fn consistent with kn
    assert np.allclose(net.with_law(laws.harmonic()).fn, law.fn, rtol=1e-15)
    again = net.with_stiffness(kn=lambda i, j, ri, rj, ov: 2.0 + 0 * ov)
    assert np.all(again.kn == 2.0)


def test_arrays_aligned_with_callers_pairs():
    pos, rad, cell = _packing()
    ref = from_overlaps(pos, rad, cell)
    perm = np.random.default_rng(0).permutation(ref.n_contacts)
    pairs = ref.pairs[perm][:, ::-1]                 # the caller's order and orientation
    kn = np.arange(1.0, ref.n_contacts + 1)
    net = from_pairs(pos, rad, cell, pairs, kn=kn, fn=2 * kn)
    assert np.array_equal(net.pairs, pairs) and np.array_equal(net.kn, kn) and np.array_equal(net.fn, 2 * kn)
    assert np.allclose(net.branch, -ref.branch[perm], atol=1e-12)   # minimum image, j - i
    shifted = from_pairs(pos, rad, cell, pairs, shifts=net.image_shifts())
    assert np.allclose(shifted.branch, net.branch, atol=1e-12)


def test_wrong_length_is_a_clear_error():
    pos, rad, cell = _packing()
    nc = from_overlaps(pos, rad, cell).n_contacts
    with pytest.raises(ValueError, match=rf"kn has shape \(5,\) but the network has {nc} contacts"):
        from_overlaps(pos, rad, cell, kn=np.ones(5))
    with pytest.raises(ValueError, match=rf"kt has shape .* {nc} contacts"):
        from_overlaps(pos, rad, cell).with_stiffness(kt=np.ones(nc + 1))
    with pytest.raises(ValueError, match="fn has shape"):
        from_pairs(pos, rad, cell, [[0, 1], [1, 2]], fn=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="either kn or law"):
        from_overlaps(pos, rad, cell, kn=1.0, law=laws.harmonic())
    with pytest.raises(ValueError, match="radii must be a scalar or have shape"):
        from_overlaps(pos, rad[:-1], cell)
