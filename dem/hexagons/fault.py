"""A planar fault through the hexagon lattice: a straight joint whose strength acts on the true plane.

Units: SI per m of thickness (m, Pa, N/m). Tension positive.

Why. A straight line through a honeycomb is never a chain of edges: the interfaces it crosses form a
zigzag of two edge families. In the pointy-top lattice (edge normals at 0, 60, 120 deg) a 60 deg line
crosses vertical edges (normal 0 deg) and 30 deg edges (normal 120 deg), a 120 deg line vertical edges
and 150 deg edges (normal 60 deg). Checked edge by edge, the 30 deg and 150 deg edges see different
tractions under the same shear stress, so the lattice, not the plane, decides which fault slips.

The planar law (``fault_law="plane"`` of the mine scene; kernel
``dem.hexagons.dynamics._fault_segments``):

* every crossed interface keeps its cells and nodes, but its frame is the fault's: normal n_f (from
  cell i to cell j), tangent t_f = (-n_fy, n_fx); its springs act in that frame;
* its preload is the virgin traction *vector* of its own edge, sigma0 n_e, written in that frame
  (``sn0 = n_f . sigma0 n_e``, ``tau0 = t_f . sigma0 n_e``): the force L sigma0 n_e is unchanged, so the
  virgin equilibrium is the same as with the edge law;
* consecutive crossed edges along the line are grouped in *segments* of two, one of each family. For
  one edge of each family n_a + n_b = lam n_f with lam = n_a . n_f + n_b . n_f = sqrt3 (both make 30 deg
  with n_f), so for any uniform stress sigma the segment sums are exact:
  sum sn = lam sigma_nf and sum tau = lam tau_f (checked symbolically in the tests);
* the strength (tension cut-off, Mohr-Coulomb) is checked on the segment's fault tractions
  sigma_f = sum sn / lam, tau_f = sum tau / lam; after failure the segment slides as one (a plastic
  slip shared by its edges) under Coulomb friction on the true plane;
* gas on a fault edge is p_g (n_e . n_f), so the segment carries exactly p_g on the plane.

A line crossing an odd number of edges ends with a triple a, b, a, weighted 1/2, 1, 1/2 (the
weighted normals again sum to lam n_f). Only a line crossing a single edge has no exact segment.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fault_frame", "plane_fault", "segment_tractions", "segment_slip", "segments_cross",
           "plane_benchmark_model"]


def segments_cross(p1, p2, q1, q2):
    """Vectorised proper intersection of the segments p1p2 ((m,2) arrays) with one segment q1q2."""
    def orient(a, b, c):
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    d1 = orient(q1, q2, p1)
    d2 = orient(q1, q2, p2)
    d3 = orient(p1, p2, q1)
    d4 = orient(p1, p2, q2)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def fault_frame(p0, p1):
    """(t, n): unit tangent along p0 -> p1 and the unit normal n = (t_y, -t_x) of the line (either sign
    would do: :func:`plane_fault` orients the normal of each edge from its cell i to its cell j)."""
    d = np.asarray(p1, float) - np.asarray(p0, float)
    t = d / np.linalg.norm(d)
    n = np.array([t[1], -t[0]])
    return t, n


def plane_fault(edge_normals, midpoints, crossed, p0, p1, sigma0_edges, first_segment=0):
    """Set up one straight fault from ``p0`` to ``p1`` [m] over the interfaces ``crossed`` (bool (M,)).

    ``edge_normals`` (M,2): geometric normal of each interface's edge, from cell i to cell j;
    ``midpoints`` (M,2): edge midpoints [m]; ``sigma0_edges`` (M,3): virgin stress [sxx, syy, sxy] at
    each edge [Pa]. Returns a dict of per-interface arrays for the crossed edges (index ``idx``):
    ``nx``, ``ny`` (the fault normal oriented from i to j), ``sn0``, ``tau0`` (the edge's virgin traction
    vector in that frame) [Pa], ``flam`` (n_e . n_f > 0) and ``fseg`` (segment ids from
    ``first_segment``, pairs of consecutive edges along the line from ``p0``; with an odd count the
    last three edges form one segment, weighted 1/2, 1, 1/2 by the kernel)."""
    idx = np.nonzero(crossed)[0]
    t_line, n_line = fault_frame(p0, p1)
    ne = np.asarray(edge_normals, float)[idx]
    sgn = np.sign(ne @ n_line)
    if np.any(sgn == 0):
        raise ValueError("an interface parallel to its own normal crossing: degenerate fault line")
    nf = sgn[:, None] * n_line[None, :]
    tf = np.stack([-nf[:, 1], nf[:, 0]], axis=1)
    s = np.asarray(sigma0_edges, float)[idx]
    tx = s[:, 0] * ne[:, 0] + s[:, 2] * ne[:, 1]
    ty = s[:, 2] * ne[:, 0] + s[:, 1] * ne[:, 1]
    along = (np.asarray(midpoints, float)[idx] - np.asarray(p0, float)) @ t_line
    rank = np.empty(len(idx), np.int64)
    rank[np.argsort(along, kind="stable")] = np.arange(len(idx))
    seg = rank // 2
    if len(idx) % 2 == 1 and len(idx) >= 3:
        seg[rank == len(idx) - 1] = (len(idx) - 3) // 2      # the last three: a triple a, b, a
    return {"idx": idx, "nx": nf[:, 0], "ny": nf[:, 1], "sn0": tx * nf[:, 0] + ty * nf[:, 1],
            "tau0": tx * tf[:, 0] + ty * tf[:, 1], "flam": np.abs(ne @ n_line),
            "fseg": first_segment + seg}


def _segments(model):
    fseg = model.fseg
    if fseg is None or not np.any(fseg >= 0):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    e = np.nonzero(fseg >= 0)[0]
    return e, fseg[e]


def segment_tractions(model):
    """Fault tractions per segment of a model with a planar fault: dict of (S,) arrays ``seg`` (ids),
    ``lam`` (projected length / L), ``sigma`` and ``tau`` (weighted sum over the edges / lam) [Pa], ``pg`` (gas
    on the plane) [Pa], ``broken`` (0, 1 tension, 2 shear), ``mid`` (S,2) mean edge midpoint [m].
    Empty arrays without a fault."""
    e, s = _segments(model)
    w = np.zeros(model.n_ifc)
    if len(e):
        fb = model.fault_bundle()
        w[fb.sidx] = fb.sw
    w = w[e]
    segs = np.unique(s)
    inv = np.searchsorted(segs, s)
    ns = len(segs)
    lam = np.bincount(inv, weights=w * model.flam[e], minlength=ns)
    sig = np.bincount(inv, weights=w * model.sn[e], minlength=ns) / np.where(lam > 0, lam, 1.0)
    tau = np.bincount(inv, weights=w * model.tau[e], minlength=ns) / np.where(lam > 0, lam, 1.0)
    pg = np.bincount(inv, weights=w * model.pg[e], minlength=ns) / np.where(lam > 0, lam, 1.0)
    br = np.zeros(ns, np.int64)
    br[inv] = model.broken[e]
    mid = model.centres[model.ci[e]] + model.geo["x"][model.ca[e]]
    cnt = np.bincount(inv, minlength=ns)
    mids = np.stack([np.bincount(inv, weights=mid[:, k], minlength=ns) for k in range(2)], 1) / cnt[:, None]
    return {"seg": segs, "lam": lam, "sigma": sig, "tau": tau, "pg": pg, "broken": br, "mid": mids,
            "n_edges": cnt}


def segment_slip(model, u_ref=None):
    """Slip and opening of every fault segment [m], relative to ``u_ref`` (default ``model.u0``, the
    start of the run): the mean over the segment's edges of the jump of the node displacements along
    t_f and n_f. Returns (seg ids, slip (S,), opening (S,), lam (S,))."""
    e, s = _segments(model)
    if len(e) == 0:
        z = np.zeros(0)
        return np.zeros(0, np.int64), z, z, z
    u = model.u - (model.u0 if u_ref is None else u_ref)
    i, a, j, b = model.ci[e], model.ca[e], model.cj[e], model.cb[e]
    dux = u[j, 2 * b] - u[i, 2 * a]
    duy = u[j, 2 * b + 1] - u[i, 2 * a + 1]
    nx, ny = model.nx[e], model.ny[e]
    jn = dux * nx + duy * ny
    jt = -dux * ny + duy * nx
    segs = np.unique(s)
    inv = np.searchsorted(segs, s)
    cnt = np.bincount(inv, minlength=len(segs))
    lam = np.bincount(inv, weights=model.flam[e], minlength=len(segs))
    return (segs, np.bincount(inv, weights=jt, minlength=len(segs)) / cnt,
            np.bincount(inv, weights=jn, minlength=len(segs)) / cnt, lam)


def plane_benchmark_model(angle_deg: float, stress, phi_deg: float, c: float = 0.0, law: str = "plane",
                          W: float = 6.0, H: float = 6.0, r_in: float = 0.25, E: float = 50e9,
                          nu: float = 0.25, rho: float = 2548.0, alpha: float = 0.0):
    """The one-plane benchmark: a W x H block [m] of identical elastic hexagons (E [Pa], nu, rho
    [kg/m^3]) under the uniform stress ``stress`` = (sxx, syy, sxy) [Pa] (prestress of every cell and
    interface, u = 0 is the exact equilibrium), every boundary edge node fixed, one straight fault
    through the vertical axis (d sqrt3/4 above the centre) at ``angle_deg`` (counter-clockwise from +x,
    in (0, 180)) from the bottom to the
    top, cohesion ``c`` [Pa], friction ``phi_deg`` [deg], no tension. Every other interface is
    unbreakable. ``law``: ``"plane"`` (Mohr-Coulomb on the true plane, this module) or ``"zigzag"``
    (each crossed edge on its own). The lattice is anchored at the centre with the pointy-top
    orientation, so it is its own mirror image about the vertical axis through the centre: the 60 and
    120 deg faults are mirror images of each other.

    Returns (model, info) with ``info`` holding the line ends ``p0``, ``p1`` [m], the true-plane
    normal ``n`` and tangent ``t``, the plane's tractions ``sigma_n``, ``tau`` [Pa] and Coulomb failure
    function ``cff = |tau| + sigma_n tan(phi) - c`` [Pa]."""
    from .dynamics import RAMP_CODES, Model, stored_energy_abs
    from .element import element_stiffness
    from .interface import spring_stiffness_rule
    from .lattice import classify_free_edges, make_lattice

    if not (0.0 < angle_deg < 180.0):
        raise ValueError(f"angle_deg={angle_deg!r}: must be in (0, 180) deg")
    if law not in ("plane", "zigzag"):
        raise ValueError(f"law={law!r}: allowed 'plane', 'zigzag'")
    if not (0.0 <= phi_deg < 90.0):
        raise ValueError(f"phi_deg={phi_deg!r}: friction angle must be in [0, 90) deg")
    sig = np.asarray(stress, float).reshape(3)
    lat = make_lattice(W, H, r_in, 0.0, anchor=(0.5 * W, 0.5 * H))
    geo = lat.geo
    N = lat.n_cells
    C = lat.centres
    L = geo["L"]
    kn = spring_stiffness_rule([(E, nu)], r_in)
    ci, ca, cj, cb = (a.copy() for a in lat.ifc.T)
    n = geo["n"][ca]
    t = geo["t"][ca]
    mid = C[ci] + geo["x"][ca]
    a = np.radians(angle_deg)
    # through the vertical axis of the block, half-way between two rows of centres (never through a
    # centre, so the crossed edges are the same for the mirrored angle)
    ctr = np.array([0.5 * W, 0.5 * H + 0.25 * np.sqrt(3.0) * 2.0 * r_in])
    p0 = ctr - ctr[1] / np.sin(a) * np.array([np.cos(a), np.sin(a)])           # on the bottom, y = 0
    p1 = ctr + (H - ctr[1]) / np.sin(a) * np.array([np.cos(a), np.sin(a)])     # on the top, y = H
    crossed = segments_cross(C[ci], C[cj], p0, p1)
    M = len(ci)
    s0 = np.broadcast_to(sig, (M, 3))
    tx = sig[0] * n[:, 0] + sig[2] * n[:, 1]
    ty = sig[2] * n[:, 0] + sig[1] * n[:, 1]
    sn0 = tx * n[:, 0] + ty * n[:, 1]
    tau0 = tx * t[:, 0] + ty * t[:, 1]
    nf = n.copy()
    fseg = flam = None
    if law == "plane":
        pf = plane_fault(n, mid, crossed, p0, p1, s0)
        k = pf["idx"]
        fseg = -np.ones(M, np.int64)
        flam = np.zeros(M)
        nf[k, 0], nf[k, 1] = pf["nx"], pf["ny"]
        sn0[k], tau0[k], flam[k], fseg[k] = pf["sn0"], pf["tau0"], pf["flam"], pf["fseg"]
    big = 1e300
    ft = np.where(crossed, 0.0, big)
    coh = np.where(crossed, c, big)
    tanphi = np.full(M, np.tan(np.radians(phi_deg)))
    nn = geo["n"]
    f0 = np.zeros((N, 12))
    f0[:, 0::2] = (sig[0] * nn[None, :, 0] + sig[2] * nn[None, :, 1]) * L
    f0[:, 1::2] = (sig[2] * nn[None, :, 0] + sig[1] * nn[None, :, 1]) * L
    mnode = np.full(N, rho * geo["A"] / 6.0)
    minv = np.full((N, 12), 1.0 / mnode[0])
    fc, fe, _ = classify_free_edges(lat, W, H)
    minv[fc, 2 * fe] = 0.0
    minv[fc, 2 * fe + 1] = 0.0
    fext = np.zeros((N, 12))
    fext[fc, 2 * fe] = f0[fc, 2 * fe]
    fext[fc, 2 * fe + 1] = f0[fc, 2 * fe + 1]
    z = np.zeros(M)
    e64 = np.zeros(0, np.int64)
    m = Model(centres=C, mat=np.zeros(N, np.int64), is_coal=np.zeros(N, bool),
              Kmat=element_stiffness(E, nu, r_in, 0.0)[None], f0=f0, fext=fext, mnode=mnode, minv=minv,
              geo=geo, ci=ci, ca=ca, cj=cj, cb=cb, nx=nf[:, 0].copy(), ny=nf[:, 1].copy(), L=L,
              kn=np.full(M, kn), kt=np.full(M, kn), ft=ft, coh=coh, tanphi=tanphi, tanphi_r=tanphi.copy(),
              vent=np.full(M, np.inf), sn0=sn0, is_disl=crossed, sn=sn0.copy(), tau=tau0.copy(), jtp=z.copy(),
              jnp=z.copy(), broken=np.zeros(M, np.int64), pg=z.copy(), wc=e64, wk=e64, FE0=np.zeros((0, 2)),
              ramp_kind=RAMP_CODES["none"], alpha=alpha, fseg=fseg, flam=flam)
    m.u = np.zeros((N, 12))
    m.u0 = m.u.copy()
    m.vh = np.zeros_like(m.u)
    m.vh_prev = np.zeros_like(m.u)
    m.U0 = stored_energy_abs(m)
    tl, nl = fault_frame(p0, p1)
    trac = np.array([sig[0] * nl[0] + sig[2] * nl[1], sig[2] * nl[0] + sig[1] * nl[1]])
    sn_, tau_ = float(trac @ nl), float(trac @ tl)
    info = {"p0": p0, "p1": p1, "n": nl, "t": tl, "sigma_n": sn_, "tau": tau_,
            "cff": abs(tau_) + sn_ * np.tan(np.radians(phi_deg)) - c}
    return m, info
