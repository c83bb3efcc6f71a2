"""3D: the geometric terms of the tangential forces under pre-stress (docs/spheres.md, "Tangential
forces under pre-stress") against LAMMPS's own history update, re-implemented here in a few lines
of numpy that share nothing with :mod:`microhom.kinematics`.

The reference (``_path``) moves a small periodic cluster of spheres in a pre-stressed equilibrium
(normal forces ``kn overlap``, tangential forces solved so that every force and torque balances)
along a straight path -- translations ``t u``, turns ``t w``, cell ``(I + t E) h`` -- and updates
every contact's shear history as ``pair gran/hooke/history`` does at each step: the increment
``vtr dt`` (tangential relative velocity of the contact points, arms = radii) added, then the
history projected on the new tangent plane. From the forces, torques, stress and the energy
``sum 1/2 kn overlap^2 + 1/2 kt |s|^2`` at ``t = +-h``:

* central differences of the forces and torques give every column of the rate tangent, which must
  equal ``H + Hn`` and ``F + Fn`` of the assembly (1e-6 of the largest entry);
* second differences of the energy along random paths (Richardson in the step count) give the
  symmetric part of the same tangent, including the strain;
* the dense relaxation of the finite-difference tangent gives the Cauchy tensor, which must equal
  ``stiffness(net, prestress=True, spin_arm=...)`` (1e-6);
* a rigid rotation of the cell with every sphere turning with it leaves the energy unchanged (the
  contact arm: no contact deforms, the history keeps its length): its quadratic form is zero.
"""
import dataclasses
import warnings

import numpy as np
import pytest
import scipy.linalg as la

from dem.analysis.stiffness import stiffness
from microhom import lattices
from microhom.kinematics import assemble
from microhom.network import from_overlaps
from microhom.tensors import mandel_to_strain, strain_to_mandel


def _arms(net, L, arm):
    ri, rj = net.radii[net.pairs[:, 0]], net.radii[net.pairs[:, 1]]
    if arm == "radius":
        return ri, rj
    return L * ri / (ri + rj), L * rj / (ri + rj)


def _equilibrium_ft(net, arm):
    """Tangential forces (C, 3) on j, perpendicular to n, that balance every force and torque
    with the normal forces fn n (least squares: a Z = 12 cluster has far more of them than needed)."""
    N, C = net.n_particles, net.n_contacts
    i, j = net.pairs[:, 0], net.pairs[:, 1]
    n, L = net.normals, net.lengths
    ai, aj = _arms(net, L, arm)
    e1 = np.cross(n, np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(n, e1)
    A = np.zeros((6 * N, 2 * C))
    b = np.zeros(6 * N)
    for c in range(C):
        for k, e in enumerate((e1[c], e2[c])):
            A[3 * j[c]:3 * j[c] + 3, 2 * c + k] += e
            A[3 * i[c]:3 * i[c] + 3, 2 * c + k] -= e
            A[3 * N + 3 * i[c]:3 * N + 3 * i[c] + 3, 2 * c + k] -= ai[c] * np.cross(n[c], e)
            A[3 * N + 3 * j[c]:3 * N + 3 * j[c] + 3, 2 * c + k] -= aj[c] * np.cross(n[c], e)
        b[3 * j[c]:3 * j[c] + 3] -= net.fn[c] * n[c]
        b[3 * i[c]:3 * i[c] + 3] += net.fn[c] * n[c]
    x = la.lstsq(A, b)[0]
    assert np.abs(A @ x - b).max() < 1e-14
    return x[0::2, None] * e1 + x[1::2, None] * e2


def _cluster(arm, seed=0, kt=0.7):
    """32 polydisperse spheres, a compressed and jittered FCC cell (Z = 12) in equilibrium."""
    rng = np.random.default_rng(seed)
    base = lattices.fcc(2, diameter=1.0)
    pos = base.positions + rng.normal(0, 0.003, base.positions.shape)
    radii = 0.5 * (1 + rng.uniform(-0.01, 0.01, len(pos)))
    net = from_overlaps(pos * 0.98, radii, base.cell * 0.98, kn=1.0, kt=kt)
    assert net.n_contacts == 6 * 32
    net = dataclasses.replace(net, fn=net.kn * net.overlaps)
    return dataclasses.replace(net, ft=_equilibrium_ft(net, arm))


def _path(net, arm, u, w, E, h, nsteps):
    """LAMMPS's update along x = (I + tE) x0 + t u, turns t w, cell (I + tE) h0, from 0 to h in
    nsteps steps. Returns (Q (N, 6): forces and torques on the spheres, sigma (3, 3) =
    -sym(sum c f^T)/V, U the energy) at t = h."""
    i, j = net.pairs[:, 0], net.pairs[:, 1]
    k = net.image_shifts()
    x0, h0 = net.positions, net.cell
    kn, kt = net.kn, net.kt
    r = net.radii
    s = -net.ft / kt[:, None]                                # the history: ft = -kt s on j

    def branch(t):
        G = np.eye(3) + t * E
        return (x0[j] + k @ h0.T - x0[i]) @ G.T + t * (u[j] - u[i])

    for step in range(1, nsteps + 1):
        t0, t1 = h * (step - 1) / nsteps, h * step / nsteps
        c1 = branch(t1)
        L1 = np.linalg.norm(c1, axis=1)
        n1 = c1 / L1[:, None]
        ai, aj = _arms(net, L1, arm)
        dc = c1 - branch(t0)                                   # v dt
        vt = dc - np.sum(dc * n1, axis=1)[:, None] * n1
        s = s + vt - np.cross((t1 - t0) * (ai[:, None] * w[i] + aj[:, None] * w[j]), n1)
        s = s - np.sum(s * n1, axis=1)[:, None] * n1         # "rotate shear displacements"
    c = branch(h)
    L = np.linalg.norm(c, axis=1)
    n = c / L[:, None]
    ai, aj = _arms(net, L, arm)
    overlap = r[i] + r[j] - L
    f = (kn * overlap)[:, None] * n - kt[:, None] * s
    N = net.n_particles
    Q = np.zeros((N, 6))
    np.add.at(Q[:, :3], j, f)
    np.add.at(Q[:, :3], i, -f)
    np.add.at(Q[:, 3:], i, -ai[:, None] * np.cross(n, f))
    np.add.at(Q[:, 3:], j, -aj[:, None] * np.cross(n, f))
    V = abs(np.linalg.det((np.eye(3) + h * E) @ h0))
    Pi = c.T @ f
    U = 0.5 * np.sum(kn * overlap ** 2) + 0.5 * np.sum(kt * np.sum(s * s, axis=1))
    return Q, -0.5 * (Pi + Pi.T) / V, U


def _direction(N, z):
    """(u (N, 3), w (N, 3), E (3, 3)) of a vector z over (3N translations, 3N turns, 6 Mandel)."""
    return z[:3 * N].reshape(N, 3), z[3 * N:6 * N].reshape(N, 3), mandel_to_strain(z[6 * N:])


def _fd_tangent(net, arm, h=1e-5, nsteps=3):
    """Central differences over every unit direction: (J (6N, 6N + 6) = -dQ/dz, S (6, 6N + 6) =
    d sigma/dz in Mandel form)."""
    N = net.n_particles
    nz = 6 * N + 6
    J, S = np.empty((6 * N, nz)), np.empty((6, nz))
    for col in range(nz):
        z = np.zeros(nz)
        z[col] = 1.0
        (Qp, sp_, _), (Qm, sm, _) = (_path(net, arm, *_direction(N, z), sg * h, nsteps) for sg in (1, -1))
        dQ = (Qp - Qm) / (2 * h)
        J[:, col] = -np.r_[dQ[:, :3].ravel(), dQ[:, 3:].ravel()]
        S[:, col] = strain_to_mandel((sp_ - sm) / (2 * h))
    return J, S


@pytest.fixture(scope="module", params=["radius", "contact"])
def case(request):
    net = _cluster(request.param)
    return request.param, net, _fd_tangent(net, request.param)


def test_the_assembled_rate_tangent_is_lammps_update(case):
    arm, net, (J, _) = case
    asm = assemble(net, prestress=True, pin=False, spin_arm=arm)
    assert asm.Hn is not None and asm.ndof == 6 * 32
    order = np.argsort(np.flatnonzero(asm.dof_map >= 0))       # full numbering: 3N u, then 3N w
    full = np.flatnonzero(asm.dof_map >= 0)
    A = np.zeros((6 * 32, 6 * 32 + 6))
    A[np.ix_(full, full)] = (asm.H + asm.Hn).toarray()[np.ix_(asm.dof_map[full], asm.dof_map[full])]
    A[full, 6 * 32:] = (asm.F + asm.Fn)[asm.dof_map[full]]
    assert order.size == 6 * 32
    scale = np.abs(J).max()
    assert np.abs(A - J).max() < 1e-9 * scale                  # measured 2e-11 (h = 1e-5)
    # the tangential terms are what made the difference: without them, far off
    A0 = A.copy()
    A0[np.ix_(full, full)] = asm.H.toarray()[np.ix_(asm.dof_map[full], asm.dof_map[full])]
    A0[full, 6 * 32:] = asm.F[asm.dof_map[full]]
    assert np.abs(A0 - J).max() > 1e-3 * scale
    # and they are not symmetric (the history law has no potential)
    Hn = asm.Hn.toarray()
    assert np.abs(Hn - Hn.T).max() > 1e-2 * np.abs(Hn).max()


def test_energy_second_differences_give_the_symmetric_part(case):
    """d^2U/dt^2 along straight paths (translations, turns and strain together) is the quadratic
    form of the rate tangent, strain rows included: sum Delta.K.Delta + c'.(K_g + G_t) c' + the
    arms' torque terms, i.e. z^T [[H + Hn, F + Fn], [V S_q, V S_e]] z."""
    arm, net, (J, S) = case
    N = net.n_particles
    rng = np.random.default_rng(1)
    asm = assemble(net, prestress=True, pin=False, spin_arm=arm)
    full = np.flatnonzero(asm.dof_map >= 0)
    idx = asm.dof_map[full]
    H = np.zeros((6 * N, 6 * N))
    H[np.ix_(full, full)] = (asm.H + asm.Hn).toarray()[np.ix_(idx, idx)]
    F = np.zeros((6 * N, 6))
    F[full] = (asm.F + asm.Fn)[idx]
    Df = asm.Df
    Sq = np.zeros((6, 6 * N))
    Sq[:, full] = np.asarray(asm.Bs.T @ (asm.Ks @ Df) + asm.Bcs.T @ ((asm.Kgs + asm.Gts).T @ Df)).T[:, idx]
    Se = Df.T @ ((asm.Ks + asm.Kgs + asm.Gts) @ Df)
    Hq0 = np.zeros((6 * N, 6 * N))                              # without the tangential terms
    Hq0[np.ix_(full, full)] = asm.H.toarray()[np.ix_(idx, idx)]
    for _ in range(3):
        z = rng.normal(size=6 * N + 6)
        z[6 * N:] *= 3.0
        d2 = []
        for nsteps in (100, 200):
            h = 1e-4
            U = [_path(net, arm, *_direction(N, z), sg * h, nsteps)[2] for sg in (1, -1)]
            U0 = _path(net, arm, *_direction(N, z), 0.0, 1)[2]
            d2.append((U[0] - 2 * U0 + U[1]) / h ** 2)
        d2U = 2 * d2[1] - d2[0]                                  # Richardson in the step count
        zq, ze = z[:6 * N], z[6 * N:]
        form = zq @ H @ zq + zq @ F @ ze + ze @ Sq @ zq + ze @ Se @ ze
        assert d2U == pytest.approx(form, rel=1e-6)                # measured 5e-8


@pytest.mark.parametrize("arm", ["radius", "contact"])
@pytest.mark.parametrize("beta", [0.3, 0.6])
def test_the_turn_of_a_two_contact_sphere_costs_nothing(arm, beta):
    """A periodic zigzag chain of two-force spheres (docs/spheres.md, "Rattlers in 3D"): every
    contact force F e_x along the chords (normal part kn overlap, tangential part fn tan b).
    Turning sphere 1 about its chord (neighbours held) moves neither contact point: along that
    straight path LAMMPS's update changes the energy at third order only, and the assembled
    tangent gives the turn zero curvature, where the normal forces' terms alone give
    -rho^2 sum fn/l; the full block has one zero eigenvalue (the turn its left null vector) and no
    eigenvalue with a negative real part."""
    l = 0.999
    x = np.array([[k * l * np.cos(beta), (k % 2) * l * np.sin(beta), 1.0] for k in range(4)]) + 2.0
    net = from_overlaps(x, np.full(4, 0.5), np.diag([4 * l * np.cos(beta), 6.0, 6.0]), kn=1.0, kt=0.8,
                        tolerance=0.0)
    n = net.normals
    fn = net.kn * net.overlaps
    f = (fn / np.abs(n[:, 0]))[:, None] * np.sign(n[:, :1]) * np.array([1.0, 0, 0])   # along x
    net = dataclasses.replace(net, fn=fn, ft=f - fn[:, None] * n)
    a = l / 2 if arm == "contact" else 0.5
    u, w = np.zeros((4, 3)), np.zeros((4, 3))
    u[1], w[1] = [0.0, 0.0, a * np.sin(beta)], [1.0, 0.0, 0.0]
    d2 = []
    for nsteps in (100, 200):
        U = [_path(net, arm, u, w, np.zeros((3, 3)), sg * 1e-4, nsteps)[2] for sg in (1, 0, -1)]
        d2.append((U[0] - 2 * U[1] + U[2]) / 1e-8)
    d2U = 2 * d2[1] - d2[0]
    rho = a * np.sin(beta)
    normal_only = -rho ** 2 * 2 * fn[0] / l
    asm = assemble(net, prestress=True, pin=False, spin_arm=arm)
    ix = asm.dof_map[np.r_[3 + np.arange(3), 12 + 3 + np.arange(3)]]
    Hf = (asm.H + asm.Hn).toarray()[np.ix_(ix, ix)]
    q = np.r_[u[1], w[1]]
    assert q @ asm.H.toarray()[np.ix_(ix, ix)] @ q == pytest.approx(normal_only, rel=1e-10)
    assert abs(q @ Hf @ q) < 1e-12 * abs(normal_only)
    assert abs(d2U) < 1e-6 * abs(normal_only)
    assert np.abs(q @ Hf).max() < 1e-12 * np.abs(Hf).max()            # left null vector
    ev = np.linalg.eigvals(Hf)
    assert np.sum(np.abs(ev) < 1e-12) == 1 and ev.real.min() > -1e-12


def test_the_relaxed_cauchy_tensor_against_the_dense_relaxation_of_lammps_update(case):
    arm, net, (J, S) = case
    N = net.n_particles
    Jq, Je = J[:, :6 * N], J[:, 6 * N:]
    Zq = -la.lstsq(Jq, Je, cond=1e-10)[0]                     # the 3 translations are free
    C_ref = S[:, 6 * N:] + S[:, :6 * N] @ Zq
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = stiffness(net, prestress=True, spin_arm=arm)
        old = stiffness(net, prestress=False, spin_arm=arm)
    scale = np.abs(C_ref).max()
    assert res.n_rattlers == 0 and res.residual < 1e-10 and res.consistency < 1e-10
    assert np.abs(res.C_mandel - C_ref).max() < 1e-9 * scale     # measured 5e-11
    assert np.abs(old.C_mandel - C_ref).max() > 1e-3 * scale   # the check can fail


def test_a_rigid_rotation_rotates_every_contact_force_but_for_lammps_twist():
    """Cell and spheres turned rigidly by W (axial vector w), the contact arm: no contact point
    moves apart (Delta = 0), and the assembled rate of every contact force is its rotation
    ``w x f`` apart from the turn about the normal, which LAMMPS's history does not follow:
    ``df/dt = w x f - (w . n) n x ft`` (docs/spheres.md). The same by the LAMMPS update above."""
    net = _cluster("contact")
    N = net.n_particles
    asm = assemble(net, prestress=True, pin=False, spin_arm="contact")
    full = np.flatnonzero(asm.dof_map >= 0)
    idx = asm.dof_map[full]
    n, ft = net.normals, net.ft
    f = net.fn[:, None] * n + ft
    for axis in np.eye(3):
        W = np.cross(axis, np.eye(3)).T                        # W v = axis x v
        z = np.zeros(asm.ndof)
        z[idx] = np.r_[(net.positions @ W.T).ravel(), np.tile(axis, N)][full]
        img = (net.image_shifts() @ net.cell.T @ W.T).ravel()     # the cell's part of W c
        delta, dc = asm.Bs @ z + img, asm.Bcs @ z + img
        assert np.abs(delta).max() < 1e-12
        fdot = -(asm.Kgs + asm.Gts) @ dc
        expect = np.cross(axis, f) - (n @ axis)[:, None] * np.cross(n, ft)
        assert np.abs(fdot.reshape(-1, 3) - expect).max() < 1e-12 * np.abs(f).max()
        # the LAMMPS update: the forces of the pair at t = +-h, turned back by -W h
        h = 1e-6
        c0 = net.branch
        i, j = net.pairs[:, 0], net.pairs[:, 1]
        s = -ft / net.kt[:, None]
        s_p = s - np.sum(s * _unit(c0 + h * c0 @ W.T), axis=1)[:, None] * _unit(c0 + h * c0 @ W.T)
        s_m = s - np.sum(s * _unit(c0 - h * c0 @ W.T), axis=1)[:, None] * _unit(c0 - h * c0 @ W.T)
        ft_rate = -net.kt[:, None] * (s_p - s_m) / (2 * h)
        lam = np.cross(axis, ft) - (n @ axis)[:, None] * np.cross(n, ft)
        assert np.abs(ft_rate - lam).max() < 1e-8 * np.abs(ft).max()
        del i, j


def _unit(c):
    return c / np.linalg.norm(c, axis=1)[:, None]
