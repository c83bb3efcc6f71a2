"""Contact laws for 2D disks: one specialised numba kernel per law, no per-contact branching on the law.

Conventions (2D, per unit thickness; any consistent units, e.g. SI: forces [N/m], stiffnesses
[N/m per m of overlap, written N/m as in the DEM literature], lengths [m]):

* branch ``l = x_j + h s - x_i``, normal ``n = l/|l|`` from i to j, tangent ``t = (-n_y, n_x)``;
* overlap ``delta = r_i + r_j - |l|`` (> 0 in contact);
* force on j ``F = fn n + ft t`` (fn > 0 repulsive), on i ``-F``; torques on i and j ``-r_i ft`` and
  ``-r_j ft`` (lever arms = radii);
* relative velocity of j's contact point w.r.t. i's: ``dv = v_j - v_i + L l - (w_i r_i + w_j r_j) t``
  (fluctuation velocities plus the affine field of the cell);
* tangential history: a scalar ``ft`` along ``t`` (2D: the rotation of the contact frame is exact
  by construction, the projection trivial), incremented by ``-kt (dv . t) dt`` and capped at the
  Coulomb limit ``|ft| <= mu fn``; reset when the contact opens.

Viscous normal damping from a restitution coefficient ``e`` in (0, 1]: damping ratio
``zeta = -ln e / sqrt(pi^2 + ln^2 e)``, dashpot ``c = 2 zeta sqrt(m_eff kn)`` with
``m_eff = m_i m_j / (m_i + m_j)``; for the linear law the coefficient of restitution of a binary
collision is then exactly ``e`` and the contact lasts ``pi / (omega0 sqrt(1 - zeta^2))``,
``omega0 = sqrt(kn / m_eff)``.

Laws (dataclasses; ``kernel`` is the numba force routine, ``params()`` its parameter vector):

* :class:`Frictionless` — linear normal spring, no history, no spins.
* :class:`LinearFriction` — linear normal spring kn, tangential spring kt, Coulomb mu, spins.
* :class:`HertzMindlin` — ``fn = kh delta^{3/2}`` (the 3D sphere form applied to disks, as in
  Yade/LAMMPS 2D runs), tangent ``kt = kt_ratio * dfn/ddelta``, incremental Coulomb history.

Every kernel fills ``f`` (N, 2) (and ``torque`` (N,) if spins) with the contact resultants and
``out`` (8,) with: ``S_xx, S_xy, S_yx, S_yy`` (sum of F_a l_b, so that the Love-Weber stress is
``sigma = -S/A``, tension positive), number of contacts, sum of |F| over contacts, elastic energy,
``sum kn_c |l_c|^2`` (the affine isotropic stiffness numerator used by the pressure servo).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["Frictionless", "LinearFriction", "HertzMindlin", "damping_ratio", "law_from_meta"]


def damping_ratio(e) -> float:
    """Damping ratio zeta of a linear spring-dashpot giving the restitution coefficient e (0 < e <= 1)."""
    if e is None:
        return 0.0
    if not (0 < e <= 1):
        raise ValueError(f"restitution must be in (0, 1], got {e}")
    le = math.log(e)
    return -le / math.sqrt(math.pi ** 2 + le * le)


# --------------------------------------------------------------------------------------------------
# kernels. Signature: (x, v, omega, radius, mass, L(4), h(4), pi, pj, ps, ft, prm, dt, f, torque, out, pc)
# pc: per-pair constants from the law's ``pair_constants`` (depends only on the list and the masses;
# LinearFriction: the normal dashpot coefficient c = 2 zeta sqrt(m_eff kn), bit-identical to the
# per-contact formula), an empty array for the other laws.
# --------------------------------------------------------------------------------------------------
@njit(cache=True)
def _forces_frictionless(x, v, omega, radius, mass, L00, L01, L10, L11, h00, h01, h10, h11,
                         pi, pj, ps, ft, prm, dt, f, torque, out, pc):
    kn = prm[0]
    zeta = prm[1]
    f[:, :] = 0.0
    for k in range(out.shape[0]):
        out[k] = 0.0
    s00 = 0.0
    s01 = 0.0
    s10 = 0.0
    s11 = 0.0
    nc = 0.0
    fsum = 0.0
    U = 0.0
    kl2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        j = pj[p]
        sa = ps[p, 0]
        sb = ps[p, 1]
        lx = x[j, 0] + h00 * sa + h01 * sb - x[i, 0]
        ly = x[j, 1] + h10 * sa + h11 * sb - x[i, 1]
        rs = radius[i] + radius[j]
        d2 = lx * lx + ly * ly
        if d2 >= rs * rs:
            continue
        d = math.sqrt(d2)
        nx = lx / d
        ny = ly / d
        delta = rs - d
        fn = kn * delta
        U += 0.5 * kn * delta * delta
        if zeta > 0.0:
            dvx = v[j, 0] - v[i, 0] + L00 * lx + L01 * ly
            dvy = v[j, 1] - v[i, 1] + L10 * lx + L11 * ly
            vn = dvx * nx + dvy * ny
            meff = mass[i] * mass[j] / (mass[i] + mass[j])
            fn -= 2.0 * zeta * math.sqrt(meff * kn) * vn
        fx = fn * nx
        fy = fn * ny
        f[j, 0] += fx
        f[j, 1] += fy
        f[i, 0] -= fx
        f[i, 1] -= fy
        s00 += fx * lx
        s01 += fx * ly
        s10 += fy * lx
        s11 += fy * ly
        nc += 1.0
        fsum += abs(fn)
        kl2 += kn * d2
    out[0] = s00
    out[1] = s01
    out[2] = s10
    out[3] = s11
    out[4] = nc
    out[5] = fsum
    out[6] = U
    out[7] = kl2


@njit(cache=True)
def _dashpot_per_pair(mass, pi, pj, kn, zeta):
    """c_p = 2 zeta sqrt(m_eff kn) for every listed pair (same expression as the per-contact one)."""
    c = np.zeros(pi.shape[0])
    if zeta > 0.0:
        for p in range(pi.shape[0]):
            i = pi[p]
            j = pj[p]
            meff = mass[i] * mass[j] / (mass[i] + mass[j])
            c[p] = 2.0 * zeta * math.sqrt(meff * kn)
    return c


@njit(cache=True)
def _forces_linear(x, v, omega, radius, mass, L00, L01, L10, L11, h00, h01, h10, h11,
                   pi, pj, ps, ft, prm, dt, f, torque, out, pc):
    kn = prm[0]
    kt = prm[1]
    mu = prm[2]
    zeta = prm[3]
    tdamp = prm[4]
    f[:, :] = 0.0
    torque[:] = 0.0
    # flat views: xf[2 * j] -> xf[2 j] saves the stride arithmetic (same values, same order)
    xf = x.reshape(-1)
    vf = v.reshape(-1)
    ff = f.reshape(-1)
    psf = ps.reshape(-1)
    s00 = 0.0
    s01 = 0.0
    s10 = 0.0
    s11 = 0.0
    nc = 0.0
    fsum = 0.0
    U = 0.0
    kl2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        j = pj[p]
        sa = psf[2 * p]
        sb = psf[2 * p + 1]
        lx = xf[2 * j] + h00 * sa + h01 * sb - xf[2 * i]
        ly = xf[2 * j + 1] + h10 * sa + h11 * sb - xf[2 * i + 1]
        ri = radius[i]
        rj = radius[j]
        rs = ri + rj
        d2 = lx * lx + ly * ly
        if d2 >= rs * rs:
            ft[p] = 0.0
            continue
        d = math.sqrt(d2)
        nx = lx / d
        ny = ly / d
        tx = -ny
        ty = nx
        delta = rs - d
        dvx = vf[2 * j] - vf[2 * i] + L00 * lx + L01 * ly
        dvy = vf[2 * j + 1] - vf[2 * i + 1] + L10 * lx + L11 * ly
        vn = dvx * nx + dvy * ny
        vt = dvx * tx + dvy * ty - (omega[i] * ri + omega[j] * rj)
        fn = kn * delta
        U += 0.5 * kn * delta * delta
        c = 0.0
        if zeta > 0.0:
            c = pc[p]
            fn -= c * vn
        fc = fn if fn > 0.0 else 0.0
        lim = mu * fc
        fs = ft[p] - kt * vt * dt
        if tdamp > 0.0:
            ftot = fs - c * vt
            if abs(ftot) > lim:
                ftot = lim if ftot > 0.0 else -lim
                fs = ftot + c * vt
        else:
            if abs(fs) > lim:
                fs = lim if fs > 0.0 else -lim
            ftot = fs
        ft[p] = fs
        if kt > 0.0:
            U += 0.5 * fs * fs / kt
        fx = fn * nx + ftot * tx
        fy = fn * ny + ftot * ty
        ff[2 * j] += fx
        ff[2 * j + 1] += fy
        ff[2 * i] -= fx
        ff[2 * i + 1] -= fy
        torque[i] -= ri * ftot
        torque[j] -= rj * ftot
        s00 += fx * lx
        s01 += fx * ly
        s10 += fy * lx
        s11 += fy * ly
        nc += 1.0
        fsum += math.sqrt(fx * fx + fy * fy)
        kl2 += kn * d2
    out[0] = s00
    out[1] = s01
    out[2] = s10
    out[3] = s11
    out[4] = nc
    out[5] = fsum
    out[6] = U
    out[7] = kl2


@njit(cache=True)
def _forces_hertz(x, v, omega, radius, mass, L00, L01, L10, L11, h00, h01, h10, h11,
                  pi, pj, ps, ft, prm, dt, f, torque, out, pc):
    kh = prm[0]
    ktr = prm[1]
    mu = prm[2]
    zeta = prm[3]
    f[:, :] = 0.0
    torque[:] = 0.0
    s00 = 0.0
    s01 = 0.0
    s10 = 0.0
    s11 = 0.0
    nc = 0.0
    fsum = 0.0
    U = 0.0
    kl2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        j = pj[p]
        sa = ps[p, 0]
        sb = ps[p, 1]
        lx = x[j, 0] + h00 * sa + h01 * sb - x[i, 0]
        ly = x[j, 1] + h10 * sa + h11 * sb - x[i, 1]
        ri = radius[i]
        rj = radius[j]
        rs = ri + rj
        d2 = lx * lx + ly * ly
        if d2 >= rs * rs:
            ft[p] = 0.0
            continue
        d = math.sqrt(d2)
        nx = lx / d
        ny = ly / d
        tx = -ny
        ty = nx
        delta = rs - d
        sq = math.sqrt(delta)
        kn = 1.5 * kh * sq
        kt = ktr * kn
        dvx = v[j, 0] - v[i, 0] + L00 * lx + L01 * ly
        dvy = v[j, 1] - v[i, 1] + L10 * lx + L11 * ly
        vn = dvx * nx + dvy * ny
        vt = dvx * tx + dvy * ty - (omega[i] * ri + omega[j] * rj)
        fn = kh * delta * sq
        U += 0.4 * kh * delta * delta * sq
        if zeta > 0.0:
            meff = mass[i] * mass[j] / (mass[i] + mass[j])
            fn -= 2.0 * zeta * math.sqrt(meff * kn) * vn
        fc = fn if fn > 0.0 else 0.0
        lim = mu * fc
        fs = ft[p] - kt * vt * dt
        if abs(fs) > lim:
            fs = lim if fs > 0.0 else -lim
        ft[p] = fs
        if kt > 0.0:
            U += 0.5 * fs * fs / kt
        fx = fn * nx + fs * tx
        fy = fn * ny + fs * ty
        f[j, 0] += fx
        f[j, 1] += fy
        f[i, 0] -= fx
        f[i, 1] -= fy
        torque[i] -= ri * fs
        torque[j] -= rj * fs
        s00 += fx * lx
        s01 += fx * ly
        s10 += fy * lx
        s11 += fy * ly
        nc += 1.0
        fsum += math.sqrt(fx * fx + fy * fy)
        kl2 += kn * d2
    out[0] = s00
    out[1] = s01
    out[2] = s10
    out[3] = s11
    out[4] = nc
    out[5] = fsum
    out[6] = U
    out[7] = kl2


# --------------------------------------------------------------------------------------------------
# law objects
# --------------------------------------------------------------------------------------------------
_EMPTY = np.zeros(0)


def _pos(name, v, allow_zero=False):
    ok = np.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if not ok:
        rng = "[0, inf)" if allow_zero else "(0, inf)"
        raise ValueError(f"{name} must be in {rng}, got {v}")


@dataclass(frozen=True)
class Frictionless:
    """Linear normal spring ``fn = kn delta`` [N/m], no tangential force, no spins, no history.

    restitution : optional coefficient of restitution e in (0, 1] (viscous normal damping).
    """
    kn: float
    restitution: float | None = None

    needs_spin = False
    needs_history = False
    kernel = staticmethod(_forces_frictionless)

    def __post_init__(self):
        _pos("kn", self.kn)
        damping_ratio(self.restitution)

    @property
    def mu(self):
        return 0.0

    @property
    def kt(self):
        return 0.0

    def params(self):
        return np.array([self.kn, damping_ratio(self.restitution)], dtype=np.float64)

    def pair_constants(self, mass, pi, pj):
        return _EMPTY

    def dt_stiffness(self):
        """Stiffness per possible contact entering the critical time step: kn."""
        return self.kn

    def tangent(self, delta):
        """(kn, kt) tangent stiffnesses at overlaps delta."""
        return np.full_like(delta, self.kn), np.zeros_like(delta)

    def fn_elastic(self, delta):
        return self.kn * delta

    def with_friction(self, mu):
        if mu != 0:
            raise ValueError("Frictionless law: mu must be 0")
        return self

    def to_meta(self):
        return {"law": "Frictionless", "kn": self.kn, "restitution": self.restitution}


@dataclass(frozen=True)
class LinearFriction:
    """Linear spring kn [N/m], tangential spring kt [N/m] with Coulomb limit mu, with spins.

    restitution : optional e in (0, 1] for viscous normal damping (see module docstring).
    tangential_damping : if True the same dashpot also acts on the tangential relative velocity
        (LAMMPS gran/hooke/history style; the Coulomb cap applies to the total tangential force).
    """
    kn: float
    kt: float
    mu: float
    restitution: float | None = None
    tangential_damping: bool = False

    needs_spin = True
    needs_history = True
    kernel = staticmethod(_forces_linear)

    def __post_init__(self):
        _pos("kn", self.kn)
        _pos("kt", self.kt, allow_zero=True)
        _pos("mu", self.mu, allow_zero=True)
        damping_ratio(self.restitution)

    def params(self):
        return np.array([self.kn, self.kt, self.mu, damping_ratio(self.restitution),
                         1.0 if self.tangential_damping else 0.0], dtype=np.float64)

    def pair_constants(self, mass, pi, pj):
        """Per-pair normal dashpot coefficients for the kernel (recomputed at each list build)."""
        return _dashpot_per_pair(mass, pi, pj, float(self.kn), damping_ratio(self.restitution))

    def dt_stiffness(self):
        """Stiffness per possible contact entering the critical time step: max(kn, 2 kt).

        The factor 2 on kt covers the rotational modes of disks (I = m r^2/2): a disk whose z
        contacts all resist the same rotation has omega^2 = 4 z kt / m.
        """
        return max(self.kn, 2.0 * self.kt)

    def tangent(self, delta):
        return np.full_like(delta, self.kn), np.full_like(delta, self.kt)

    def fn_elastic(self, delta):
        return self.kn * delta

    def with_friction(self, mu):
        from dataclasses import replace
        return replace(self, mu=float(mu))

    def to_meta(self):
        return {"law": "LinearFriction", "kn": self.kn, "kt": self.kt, "mu": self.mu,
                "restitution": self.restitution, "tangential_damping": self.tangential_damping}


@dataclass(frozen=True)
class HertzMindlin:
    """Hertz normal force ``fn = kh delta^{3/2}`` (kh [N/m^{3/2}]), Mindlin tangent stiffness
    ``kt = kt_ratio * 1.5 kh sqrt(delta)`` (incremental, no-slip), Coulomb mu, with spins.

    delta_ref : overlap [m] at which the tangent stiffness enters the critical time step.
    """
    kh: float
    mu: float
    delta_ref: float
    kt_ratio: float = 2.0 / 3.0
    restitution: float | None = None

    needs_spin = True
    needs_history = True
    kernel = staticmethod(_forces_hertz)

    def __post_init__(self):
        _pos("kh", self.kh)
        _pos("mu", self.mu, allow_zero=True)
        _pos("delta_ref", self.delta_ref)
        _pos("kt_ratio", self.kt_ratio, allow_zero=True)
        damping_ratio(self.restitution)

    def params(self):
        return np.array([self.kh, self.kt_ratio, self.mu, damping_ratio(self.restitution)],
                        dtype=np.float64)

    def pair_constants(self, mass, pi, pj):
        return _EMPTY

    def dt_stiffness(self):
        kn = 1.5 * self.kh * math.sqrt(self.delta_ref)
        return max(kn, 2.0 * self.kt_ratio * kn)

    def tangent(self, delta):
        kn = 1.5 * self.kh * np.sqrt(np.maximum(delta, 0.0))
        return kn, self.kt_ratio * kn

    def fn_elastic(self, delta):
        return self.kh * np.maximum(delta, 0.0) ** 1.5

    def with_friction(self, mu):
        from dataclasses import replace
        return replace(self, mu=float(mu))

    def to_meta(self):
        return {"law": "HertzMindlin", "kh": self.kh, "mu": self.mu, "delta_ref": self.delta_ref,
                "kt_ratio": self.kt_ratio, "restitution": self.restitution}


def law_from_meta(meta: dict):
    """Rebuild a law from its ``to_meta()`` dict (used by checkpoints)."""
    meta = dict(meta)
    kind = meta.pop("law")
    return {"Frictionless": Frictionless, "LinearFriction": LinearFriction,
            "HertzMindlin": HertzMindlin}[kind](**meta)
