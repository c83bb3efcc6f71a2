"""The advancing face: excavation in slices with quasi-static stages, the energy partition of each
stage, the abutment stress at each stage (the paper's Fig. 1), and Salamon's stability check of the
wedge between the face and the dislocation.

Units: SI per m of thickness (N/m, m, J/m, Pa). Tension positive.

A stage (:func:`advance_face`) removes the next ``slice_width`` of the seam at the face. The cells of
the slice go; each kept cell that bordered one gets the force the removed neighbour's interface
carried at the end of the previous stage (Eshelby's cut-and-weld, as in
:func:`~dem.scenes.mine.excavation.excavate` but from the current, not the virgin, state: so the
cut leaves the equilibrium unchanged), and the forces are ramped to zero over ``ramp_time``. Mass-
proportional damping ``relax_alpha`` then relaxes the model until the kinetic energy is at most
``ek_tol`` times the stage's released Eshelby work (the stated quasi-static criterion), or
``t_max`` runs out (``converged`` False). The overburden is the scene's loading system: with
``loading="spring"`` a dead traction plus a Winkler spring of stated stiffness (lambda + 2 mu) /
``overburden_height`` per unit area on the top.

Energy partition of a stage (all J/m, from the stage's start; :func:`dem.hexagons.dynamics.energies`)::

    W_boundary + W_E + W_gas = dU + Ek + D_interfaces + D_radiated + residual

``W_boundary`` the work of the loading system on the model (dead loads minus the energy stored in the
overburden spring), ``-W_E`` the released Eshelby work (the work the mined slice did on its
neighbours as it was removed), ``dU`` the change of strain energy of the rock and coal,
``D_interfaces`` friction, breakage and contact dashpots, ``D_radiated`` the kinetic energy
removed by the absorbing boundaries and the relaxation damping (the energy a bump would radiate).

Salamon's check (Salamon 1970, "Stability, instability and design of pillar workings"): the wedge
(the coal between the face and the dislocation) is unstable when its load-convergence curve softens
faster than the surroundings unload, ``k_post < 0`` and ``|k_post| > k_LMS``.

* ``k_post`` (:func:`wedge_secant`): the secant stiffness of the wedge of stage k over the stage,
  dF/d(delta) of the same cells between the end of stage k-1 and the end of stage k. ``F`` is the
  vertical force the wedge carries, half the sum of ``|f_y|`` of the forces it exerts on its
  neighbours, and ``delta`` the closure work-conjugate to that load pattern.
* ``k_LMS`` (:func:`local_mine_stiffness`), the local mine stiffness: the wedge is taken out and
  its own load pattern ``f`` (the forces it exerts on its neighbours) is applied to the surroundings
  as a small static probe on the tangent stiffness ``K``: ``K du = f``,
  ``k_LMS = F^2 / (f . du)``. With every interface's spring in ``K`` (cracks as if glued) it is an
  upper bound; without the open cracks a lower bound.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import scipy.sparse.linalg as spla

from microhom.results import Result

from ...hexagons.dynamics import (RAMP_CODES, Model, advance, assemble_stiffness, energies, forces_frozen,
                                  gershgorin_dt, stored_energy_abs)
from .build import build_scene
from .excavation import wall_forces
from .geometry import block_labels, resolve
from .indicators import seam_profile
from .params import MineParams

__all__ = ["FaceStage", "SalamonCheck", "FaceAdvance", "remove_cells", "advance_face", "wedge_load",
           "wedge_secant", "local_mine_stiffness", "probe_stiffness", "salamon_verdict", "overburden_stiffness"]

_PER_IFC = ("nx", "ny", "kn", "kt", "ft", "coh", "tanphi", "tanphi_r", "vent", "sn0", "is_disl", "sn", "tau",
            "jtp", "jnp", "pg", "broken", "fseg", "flam")
_PER_CELL = ("centres", "mat", "is_coal", "f0", "fext", "mnode", "minv", "u", "kspr", "uref", "cvis")


def overburden_stiffness(p: MineParams) -> float:
    """Stiffness of the overburden spring per unit area of the top, (lambda + 2 mu) / overburden_height
    [Pa/m] (``loading="spring"``; 0 otherwise: a dead load has no stiffness)."""
    if p.loading != "spring":
        return 0.0
    lam = p.rock_E * p.rock_nu / ((1 + p.rock_nu) * (1 - 2 * p.rock_nu))
    return (lam + p.rock_E / (1 + p.rock_nu)) / p.overburden_height


def remove_cells(m: Model, gone, ramp_time: float = 0.01, alpha: float = 0.0):
    """A new model without the cells ``gone`` (N,) bool, every state carried over (displacements,
    interface states with their damage, boundary devices, contact), and Eshelby loads on the kept
    cells that bordered a removed one: the force the removed neighbour's interface carries now,
    ramped linearly to zero over ``ramp_time`` [s]. Returns (model, kept indices of ``m``)."""
    gone = np.asarray(gone, bool)
    keep = np.nonzero(~gone)[0]
    newidx = -np.ones(m.n_cells, np.int64)
    newidx[keep] = np.arange(len(keep))
    ki = ~gone[m.ci] & ~gone[m.cj]
    wc, wk, FE = wall_forces(m, gone, newidx)
    kw = {k: getattr(m, k)[ki].copy() for k in _PER_IFC if getattr(m, k) is not None}
    kw.update({k: getattr(m, k)[keep].copy() for k in _PER_CELL if getattr(m, k) is not None})
    u = kw.pop("u")
    new = Model(Kmat=m.Kmat, geo=m.geo, L=m.L, ci=newidx[m.ci[ki]], ca=m.ca[ki].copy(), cj=newidx[m.cj[ki]],
                cb=m.cb[ki].copy(), wc=wc, wk=wk, FE0=FE, ramp_kind=RAMP_CODES["linear"], ramp_time=ramp_time,
                alpha=alpha, v_abort=m.v_abort, cdash=m.cdash, **kw)
    new.u = u
    if m.contact:
        new.enable_contact(m.kc, m.cc)
    _restart(new)
    return new, keep


def _restart(m: Model):
    """Start a stage: velocities zero, clock and accounts reset, reference state = the current one."""
    m.vh = np.zeros_like(m.u)
    m.vh_prev = np.zeros_like(m.u)
    m.t = 0.0
    m.nstep = 0
    m.acc = np.zeros_like(m.acc)
    m.u0 = m.u.copy()
    m.U0 = stored_energy_abs(m)
    m.f = forces_frozen(m, m.u)


def _spring(m: Model) -> float:
    return 0.0 if m.kspr is None else float(0.5 * np.sum(m.kspr * (m.u - m.uref) ** 2))


def wedge_load(m: Model, wedge, u=None, u_ref=None):
    """The load a body of coal cells ``wedge`` (N,) bool carries between the roof and the floor:
    (F [N/m], delta [m], f) with ``f`` = (cells, edges, forces (n,2) [N/m]) of the forces it exerts on
    the nodes of the rock cells it touches, ``F = 1/2 sum |f_y|`` and ``delta = -(f/F) . (u - u_ref)``
    over those nodes (the roof-floor closure work-conjugate to the load pattern; ``u`` defaults to
    ``m.u``, ``u_ref`` to ``m.u0``). Its coal neighbours (the face's slices, the seam across the
    dislocation) are not part of the pattern."""
    u = m.u if u is None else u
    u_ref = m.u0 if u_ref is None else u_ref
    wc, wk, FE = wall_forces(m, np.asarray(wedge, bool), np.arange(m.n_cells))
    rock = ~m.is_coal[wc]
    wc, wk, FE = wc[rock], wk[rock], FE[rock]
    F = 0.5 * float(np.abs(FE[:, 1]).sum())
    du = np.stack([u[wc, 2 * wk] - u_ref[wc, 2 * wk], u[wc, 2 * wk + 1] - u_ref[wc, 2 * wk + 1]], axis=1)
    delta = -float(np.sum(FE * du)) / F if F > 0 else 0.0
    return F, delta, (wc, wk, FE)


def local_mine_stiffness(m: Model, wedge, closed_only: bool = False) -> float:
    """Local mine stiffness seen by the body ``wedge`` (N,) bool [N/m per m]: the body is removed,
    its load pattern ``f`` (:func:`wedge_load`) is applied to the rest as a static probe on the
    tangent stiffness (elements, interface springs, ground springs), ``K du = f`` on the free dofs,
    and ``k_LMS = F^2 / (f . du)``. Every interface keeps its spring (an upper bound: cracks act as
    if glued), or with ``closed_only`` the open cracks (broken, ``sn + pg >= 0``) have none (a
    lower bound: closed cracks keep their normal and shear springs, sliding ones would not)."""
    wedge = np.asarray(wedge, bool)
    F, _, (wc, wk, FE) = wedge_load(m, wedge)
    if F <= 0:
        return float("nan")
    rest, keep = remove_cells(m, wedge)
    newidx = -np.ones(m.n_cells, np.int64)
    newidx[keep] = np.arange(len(keep))
    if closed_only:                     # a throwaway copy: mark the closed cracks intact for the assembly
        rest.broken = np.where(rest.sn + rest.pg < 0, 0, rest.broken)
    K = assemble_stiffness(rest, intact_only=closed_only)
    free = rest.minv.ravel() > 0
    f = np.zeros(rest.u.size)
    idx = 12 * newidx[wc] + 2 * wk
    np.add.at(f, idx, FE[:, 0])
    np.add.at(f, idx + 1, FE[:, 1])
    return probe_stiffness(K[free][:, free], f[free], F)


def probe_stiffness(K, f, F: float) -> float:
    """Stiffness seen by a load pattern ``f`` (n,) of size ``F`` on a system of stiffness ``K`` (n, n),
    sparse: ``F^2 / (f . K^-1 f)`` (the generalised force ``F`` over its work-conjugate displacement).
    A diagonal shift of 1e-12 of the mean diagonal keeps floating parts solvable (they then carry no
    load: a pattern that loads one gives a stiffness near 0)."""
    import scipy.sparse as sp
    Kf = sp.csc_matrix(K)
    Kf = Kf + 1e-12 * float(Kf.diagonal().mean()) * sp.identity(Kf.shape[0], format="csc")
    du = spla.spsolve(Kf, np.asarray(f, float))
    w = float(np.dot(f, du))
    return F * F / w if w > 0 else float("inf")


def wedge_secant(prev: Model, cur: Model, keep, wedge_cur, u_virgin_prev, u_virgin_cur):
    """Secant stiffness [N/m per m] of the wedge of the stage ``cur`` (cells ``wedge_cur`` (N,) bool
    of ``cur``; ``keep`` maps ``cur``'s cells to ``prev``'s) between the end of the previous stage
    (``prev``) and now: dF / d(delta) of the same cells with the same load pattern (that of now),
    closures from the virgin displacements. Returns (k, F_prev, F_cur, delta_prev, delta_cur)."""
    w_prev = np.zeros(prev.n_cells, bool)
    w_prev[keep[wedge_cur]] = True
    F1, d1, pat = wedge_load(cur, wedge_cur, u_ref=u_virgin_cur)
    F0 = wedge_load(prev, w_prev, u_ref=u_virgin_prev)[0]
    # delta of the previous state on the current nodes and pattern (the same neighbours' nodes)
    wc, wk, FE = pat
    u0 = prev.u[keep[wc]]
    uv = u_virgin_prev[keep[wc]]
    du = np.stack([u0[np.arange(len(wc)), 2 * wk] - uv[np.arange(len(wc)), 2 * wk],
                   u0[np.arange(len(wc)), 2 * wk + 1] - uv[np.arange(len(wc)), 2 * wk + 1]], axis=1)
    d0 = -float(np.sum(FE * du)) / (0.5 * float(np.abs(FE[:, 1]).sum()))
    k = (F1 - F0) / (d1 - d0) if d1 != d0 else float("nan")
    return k, F0, F1, d0, d1


def salamon_verdict(k_post: float, k_lms_lo: float, k_lms_hi: float) -> str:
    """Salamon's criterion with a bracketed local mine stiffness: "stable" when the wedge stiffens
    (``k_post >= 0``) or softens slower than the softest surroundings (``|k_post| < k_lms_lo``),
    "unstable" when it softens faster than the stiffest (``|k_post| > k_lms_hi``), "undecided"
    between, "no data" when ``k_post`` is NaN."""
    if not np.isfinite(k_post):
        return "no data"
    if k_post >= 0 or -k_post < k_lms_lo:
        return "stable"
    if -k_post > k_lms_hi:
        return "unstable"
    return "undecided"


@dataclass(frozen=True)
class FaceStage(Result):
    """One stage of the advancing face (SI per m of thickness; energies from the stage's start).

    Attributes
    ----------
    stage : int
        1, 2, ... (0 is the first opening, the adit itself).
    face_m : float
        Distance the face has advanced from the adit's rib [m].
    n_removed : int
        Cells removed at this stage.
    steps : int
        Time steps of the stage.
    t_s : float
        Duration of the stage (ramp + relaxation) [s].
    converged : bool
        The kinetic-energy criterion was met before ``t_max``.
    Ek_end_J_per_m, Ek_peak_J_per_m : float
        Kinetic energy at the end and its peak during the stage [J/m].
    W_boundary_J_per_m : float
        Work of the loading system on the model: dead loads minus the energy stored in the
        overburden spring [J/m].
    released_J_per_m : float
        Released Eshelby work ``-W_E`` [J/m].
    W_gas_J_per_m : float
        Work of the gas [J/m].
    dU_J_per_m : float
        Change of the strain energy of the rock and coal (cells, interfaces, contacts) [J/m].
    D_interfaces_J_per_m : float
        Dissipated in the interfaces: friction, breakage, contact dashpots [J/m].
    D_radiated_J_per_m : float
        Kinetic energy removed by the absorbing boundaries and the relaxation damping [J/m].
    residual_J_per_m : float
        Energy-balance residual ``W_boundary - released + W_gas - (dU + Ek + D)`` [J/m].
    n_broken_new : int
        Interfaces broken during the stage.
    wedge_F_N_per_m, wedge_delta_m : float
        Load of the wedge (coal between the face and the dislocation) and its closure from the virgin
        state at the end of the stage (:func:`wedge_load`) [N/m], [m].
    k_secant_N_per_m2 : float
        Secant stiffness of this stage's wedge over the stage (:func:`wedge_secant`) [N/m per m].
    k_lms_lo_N_per_m2, k_lms_hi_N_per_m2 : float
        Local mine stiffness seen by the wedge without the open cracks (lower bound) and with every
        interface (upper bound) [N/m per m] (:func:`local_mine_stiffness`).
    x_m : ndarray, shape (n,)
        Distance of the seam mid-height cells from the adit's rib [m].
    syy_Pa : ndarray, shape (n,)
        Their vertical stress at the end of the stage [Pa] (Fig. 1 of the paper).
    wall_s : float
        Wall time of the stage [s].
    """
    stage: int
    face_m: float
    n_removed: int
    steps: int
    t_s: float
    converged: bool
    Ek_end_J_per_m: float
    Ek_peak_J_per_m: float
    W_boundary_J_per_m: float
    released_J_per_m: float
    W_gas_J_per_m: float
    dU_J_per_m: float
    D_interfaces_J_per_m: float
    D_radiated_J_per_m: float
    residual_J_per_m: float
    n_broken_new: int
    wedge_F_N_per_m: float
    wedge_delta_m: float
    k_secant_N_per_m2: float
    k_lms_lo_N_per_m2: float
    k_lms_hi_N_per_m2: float
    x_m: np.ndarray
    syy_Pa: np.ndarray
    wall_s: float = 0.0


@dataclass(frozen=True)
class SalamonCheck(Result):
    """Salamon's stability check of the wedge (N/m per m of thickness).

    Attributes
    ----------
    k_post_N_per_m2 : float
        Smallest (most negative: post-peak) secant stiffness of the wedge over the stages; >= 0 when
        the wedge never softens; NaN with fewer than two stages [N/m per m].
    stage : int
        Stage where it was measured.
    k_lms_lo_N_per_m2, k_lms_hi_N_per_m2 : float
        Local mine stiffness of that stage, lower and upper bound [N/m per m].
    verdict : str
        :func:`salamon_verdict`: "stable", "unstable", "undecided" or "no data".
    """
    k_post_N_per_m2: float
    stage: int
    k_lms_lo_N_per_m2: float
    k_lms_hi_N_per_m2: float
    verdict: str


@dataclass(frozen=True)
class FaceAdvance(Result):
    """The advancing face of one scene.

    Attributes
    ----------
    params : dict
        The scene's parameters (``MineParams.to_dict()``).
    slice_width_m : float
        Width of the slice removed per stage [m].
    ek_tol : float
        Kinetic-energy criterion: Ek <= ek_tol * released work of the stage [-].
    relax_alpha_per_s : float
        Mass-proportional relaxation damping [1/s].
    k_overburden_Pa_per_m : float
        Stiffness of the loading system per unit area of the top [Pa/m] (0: dead load).
    stages : tuple of FaceStage
        The stages in order.
    salamon : SalamonCheck
        Salamon's check over the stages.
    wall_s, cpu_s : float
        Wall and CPU time of the whole advance [s].
    final : Model
        The model at the end of the last stage (not exported).
    """
    params: dict
    slice_width_m: float
    ek_tol: float
    relax_alpha_per_s: float
    k_overburden_Pa_per_m: float
    stages: tuple
    salamon: SalamonCheck
    wall_s: float = 0.0
    cpu_s: float = 0.0
    final: Model = field(default=None, metadata={"export": False})

    def table(self):
        """One row per stage (the scalars of :class:`FaceStage`), a pandas DataFrame."""
        import pandas as pd
        return pd.DataFrame([{k: v for k, v in s.as_dict().items() if k not in ("x_m", "syy_Pa")}
                             for s in self.stages])


def _slice(m: Model, g, face0: float, face1: float):
    """Coal cells of ``m`` whose centres lie between ``face0`` and ``face1`` [m] from the adit's rib."""
    d = g.side * (m.centres[:, 0] - g.rib_x)
    return m.is_coal & (d > face0 + 1e-9) & (d <= face1 + 1e-9)


def _relax(m: Model, ek_tol: float, t_max: float, dt_safety: float, sample: float, window: float):
    """Integrate the stage until the largest kinetic energy over the trailing ``window`` [s] is at most
    ``ek_tol`` times the released Eshelby work (after the ramp), or until ``t_max`` [s].
    Returns (converged, Ek peak [J/m])."""
    dtg = gershgorin_dt(m)
    dt = dt_safety * dtg
    n_out = max(1, int(round(sample / dt)))
    n_win = max(1, int(round(window / (n_out * dt))))
    hist, peak = [], 0.0
    while True:
        advance(m, n_out, dt, dtg)
        e = energies(m)
        hist.append(e["Ek"])
        peak = max(peak, e["Ek"])
        ref = max(-e["W_E"], 1e-9)
        if m.t >= m.ramp_time + window and max(hist[-n_win:]) <= ek_tol * ref:
            return True, peak
        if m.t >= t_max:
            return False, peak


def _record(stage, face, n_removed, m: Model, g, spring0, converged, peak, wedge, kq, wall, nbr0):
    """The :class:`FaceStage` of a relaxed model (``kq``: secant and the two k_LMS)."""
    e = energies(m)
    dsp = _spring(m) - spring0
    F, delta, _ = wedge_load(m, wedge, u_ref=kq["u_virgin"]) if wedge.any() else (0.0, 0.0, None)
    x, syy = seam_profile(SimpleNamespace(geometry=g, model=m))
    return FaceStage(stage=stage, face_m=face, n_removed=int(n_removed), steps=int(m.nstep), t_s=float(m.t),
                     converged=bool(converged), Ek_end_J_per_m=float(e["Ek"]), Ek_peak_J_per_m=float(peak),
                     W_boundary_J_per_m=float(e["W_dead"] - dsp), released_J_per_m=float(-e["W_E"]),
                     W_gas_J_per_m=float(e["W_gas"]), dU_J_per_m=float(e["U"] - dsp),
                     D_interfaces_J_per_m=float(e["D_fric"] + e["D_break"] + e["D_dash"]),
                     D_radiated_J_per_m=float(e["D_damp"]), residual_J_per_m=float(e["residual"]),
                     n_broken_new=int((m.broken > 0).sum()) - nbr0, wedge_F_N_per_m=F, wedge_delta_m=delta,
                     k_secant_N_per_m2=kq["k"], k_lms_lo_N_per_m2=kq["lo"], k_lms_hi_N_per_m2=kq["hi"],
                     x_m=x, syy_Pa=syy, wall_s=wall)


def advance_face(p: MineParams, n_steps: int = 4, slice_width: float | None = None, ek_tol: float = 1e-5,
                 relax_alpha: float = 300.0, t_max: float = 0.2, dt_safety: float | None = None,
                 sample: float = 2.5e-4, window: float = 5e-3, partition: MineParams | None = None) -> FaceAdvance:
    """The adit (stage 0) and then ``n_steps`` slices of ``slice_width`` [m] (default one column of
    cells, 2 r_in) at the face, each ramped over ``p.ramp_time`` and relaxed with mass damping
    ``relax_alpha`` [1/s] until the kinetic energy over the trailing ``window`` [s] is at most
    ``ek_tol`` of the stage's released work (or ``t_max`` [s]); samples every ``sample`` [s].
    ``partition``: the scene whose dislocation bounds the wedge (default ``p``; give the case for a
    control run without a dislocation). Raises ``ValueError`` naming ``n_steps`` when a slice would
    reach the dislocation."""
    t0, c0 = time.perf_counter(), time.process_time()
    if not (isinstance(n_steps, int) and n_steps >= 0):
        raise ValueError(f"n_steps={n_steps!r}: must be an integer >= 0")
    for name, v in (("ek_tol", ek_tol), ("relax_alpha", relax_alpha), ("t_max", t_max), ("sample", sample),
                    ("window", window)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name}={v!r}: must be a finite number > 0")
    sc = build_scene(p)
    g = sc.geometry
    gw = dataclasses.replace(g, dislocations=resolve(partition or p).dislocations)
    width = 2.0 * p.r_in if slice_width is None else float(slice_width)
    if not (width > 0):
        raise ValueError(f"slice_width={slice_width!r}: must be > 0 m")
    dts = p.dt_safety if dt_safety is None else dt_safety
    m = sc.model
    m.alpha = relax_alpha
    uv = m.u0.copy()
    stages, prev, keep = [], None, None
    uv_prev = None                                      # the previous stage's virgin displacements
    for k in range(n_steps + 1):
        ts = time.perf_counter()
        if k:
            cut = _slice(prev, g, (k - 1) * width, k * width)
            if np.any(prev.is_disl & (cut[prev.ci] | cut[prev.cj])):
                raise ValueError(f"n_steps={n_steps}: stage {k} (face at {k * width:.3f} m) cuts the dislocation; "
                                 "use fewer steps or a narrower slice_width")
            m, keep = remove_cells(prev, cut, p.ramp_time, relax_alpha)
            uv = uv[keep]
        nbr0 = int((m.broken > 0).sum())
        spring0 = _spring(m)
        ok, peak = _relax(m, ek_tol, t_max, dts, sample, window)
        wedge = (block_labels(gw, m.centres, m.is_coal) == 0)
        kq = {"u_virgin": uv, "k": float("nan"), "lo": float("nan"), "hi": float("nan")}
        if wedge.any():
            kq["lo"] = local_mine_stiffness(m, wedge, closed_only=True)
            kq["hi"] = local_mine_stiffness(m, wedge)
            if k:
                kq["k"] = wedge_secant(prev, m, keep, wedge, uv_prev, uv)[0]
        stages.append(_record(k, k * width, 0 if not k else int(cut.sum()), m, g, spring0, ok, peak, wedge, kq,
                              time.perf_counter() - ts, nbr0))
        prev, uv_prev = m, uv
    sal = _salamon(stages)
    return FaceAdvance(params=p.to_dict(), slice_width_m=width, ek_tol=ek_tol, relax_alpha_per_s=relax_alpha,
                       k_overburden_Pa_per_m=overburden_stiffness(p), stages=tuple(stages), salamon=sal,
                       wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0, final=m)


def _salamon(stages) -> SalamonCheck:
    ks = [(s.k_secant_N_per_m2, s) for s in stages if np.isfinite(s.k_secant_N_per_m2)]
    if not ks:
        return SalamonCheck(float("nan"), -1, float("nan"), float("nan"), "no data")
    k, s = min(ks, key=lambda q: q[0])
    return SalamonCheck(k_post_N_per_m2=float(k), stage=s.stage, k_lms_lo_N_per_m2=s.k_lms_lo_N_per_m2,
                        k_lms_hi_N_per_m2=s.k_lms_hi_N_per_m2,
                        verdict=salamon_verdict(k, s.k_lms_lo_N_per_m2, s.k_lms_hi_N_per_m2))
