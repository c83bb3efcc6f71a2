"""Pictures (matplotlib, Agg) and a legacy-VTK file of a mine-scene state.

Units: m, Pa, m/s, J/m.
"""
from __future__ import annotations

import numpy as np

from ...hexagons.dynamics import cell_stress
from ...runtime import atomic_write
from .indicators import cell_flags, seam_profile

__all__ = ["plot_state", "plot_series", "plot_profile", "write_vtk", "snapshot", "draw_snapshot"]


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection
    return plt, PolyCollection, LineCollection


def _polys(model, scale_disp=0.0):
    verts = model.geo["verts"]
    c = model.centres
    P = c[:, None, :] + verts[None, :, :]
    if scale_disp:
        d = (model.u - model.u0).reshape(-1, 6, 2).mean(axis=1)
        P = P + scale_disp * d[:, None, :]
    return P


def plot_state(scene, path, title="", vectors=True, vec_scale=None):
    """Cells coloured by state (rock / coal intact / coal damaged / detached / free), broken
    interfaces (red tension, blue shear, green dislocation) and displacement vectors of the centres."""
    plt, PolyCollection, LineCollection = _mpl()
    m = scene.model
    nif, nbr, detached, free = cell_flags(m)
    col = np.where(m.is_coal, "#404040", "#c8c8c8").astype(object)
    col[(nbr > 0) & m.is_coal] = "#8a6d3b"
    col[(nbr > 0) & ~m.is_coal] = "#e0b070"
    col[detached] = "#d98c00"
    col[free] = "#ff3030"
    fig, ax = plt.subplots(figsize=(13, 5.2))
    ax.add_collection(PolyCollection(_polys(m), facecolors=list(col), edgecolors="#909090", linewidths=0.2))
    x = m.geo["x"]
    L = m.geo["L"]
    t = m.geo["t"]
    segs, cols = [], []
    for e in np.nonzero((m.broken > 0) | m.is_disl)[0]:
        c0 = m.centres[m.ci[e]] + x[m.ca[e]]
        tt = t[m.ca[e]]
        segs.append([c0 - 0.5 * L * tt, c0 + 0.5 * L * tt])
        cols.append("tab:red" if m.broken[e] == 1 else ("tab:blue" if m.broken[e] == 2 else "tab:green"))
    if segs:
        ax.add_collection(LineCollection(segs, colors=cols, linewidths=1.6))
    for seg in scene.geometry.dislocations:
        ax.plot(seg[:, 0], seg[:, 1], "g--", lw=0.8)
    if vectors:
        d = (m.u - m.u0).reshape(-1, 6, 2).mean(axis=1)
        mag = np.linalg.norm(d, axis=1)
        if vec_scale is None:
            vec_scale = 1.0 / max(np.percentile(mag, 99.5), 1e-12) * 0.8
        sel = mag > 0.02 * mag.max()
        ax.quiver(m.centres[sel, 0], m.centres[sel, 1], d[sel, 0], d[sel, 1], angles="xy",
                  scale_units="xy", scale=1.0 / vec_scale, width=0.0012, color="navy")
    ax.set_xlim(-0.3, scene.geometry.W + 0.3)
    ax.set_ylim(-0.3, scene.geometry.H + 0.3)
    ax.set_aspect("equal")
    ax.set_title(title or f"t = {m.t * 1e3:.1f} ms   red: tension, blue: shear, green: intact dislocation; "
                          f"orange/red cells: detached/free")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_series(series, path, title=""):
    """Save a three-panel picture of the time series of a run (``RunResult.series``) to ``path``:
    kinetic energy (all, coal, free cells) [kJ/m], broken interfaces (tension, shear), and the
    energy accounts W_ext, W_E, U, D_fric, D_break, D_dash and the balance residual [kJ/m], against
    time [ms]."""
    plt, _, _ = _mpl()
    t = np.asarray(series["t"]) * 1e3
    fig, axs = plt.subplots(1, 3, figsize=(15, 4))
    axs[0].plot(t, np.asarray(series["Ek"]) / 1e3, label="E_k total")
    axs[0].plot(t, np.asarray(series["Ek_coal"]) / 1e3, label="E_k coal")
    axs[0].plot(t, np.asarray(series["Ek_free"]) / 1e3, label="E_k free (ejected)")
    axs[0].set_ylabel("kJ/m")
    axs[0].legend()
    axs[1].plot(t, series["n_tension"], label="tension")
    axs[1].plot(t, series["n_shear"], label="shear")
    axs[1].set_ylabel("broken interfaces")
    axs[1].legend()
    for k in ("W_ext", "W_E", "U", "D_fric", "D_break", "D_dash", "residual"):
        axs[2].plot(t, np.asarray(series[k]) / 1e3, label=k)
    axs[2].set_ylabel("kJ/m")
    axs[2].legend(fontsize=7)
    for a in axs:
        a.set_xlabel("t [ms]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_profile(scene, path, title="", extra=None):
    """Save sigma_yy along the seam mid-height row [MPa] against the distance from the rib [m] to
    ``path``, with the virgin stress. ``extra``: {label: (distance (n,) [m], sigma_yy (n,) [Pa])}
    of other runs drawn on the same axes."""
    plt, _, _ = _mpl()
    d, s = seam_profile(scene)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(d, s / 1e6, ".-", label="this run")
    if extra:
        for lab, (dd, ss) in extra.items():
            ax.plot(dd, ss / 1e6, ".-", label=lab)
    ax.axhline(scene.sigma0[1] / 1e6, color="k", lw=0.5, ls="--", label="virgin")
    ax.set_xlabel("distance from rib [m]")
    ax.set_ylabel("sigma_yy at seam mid-height [MPa]")
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_vtk(scene, path):
    """Legacy ASCII VTK polydata: one hexagon polygon per cell (displaced by its mean node
    displacement) with cell data, then one line per broken interface (ParaView opens it)."""
    m = scene.model
    P = _polys(m, 1.0)
    N = m.n_cells
    s = cell_stress(m)
    nif, nbr, detached, free = cell_flags(m)
    vc = (0.5 * (m.vh + m.vh_prev)).reshape(-1, 6, 2).mean(axis=1)
    d = (m.u - m.u0).reshape(-1, 6, 2).mean(axis=1)
    brk = np.nonzero(m.broken > 0)[0]
    x = m.geo["x"]
    L = m.geo["L"]
    t = m.geo["t"]
    lpts = []
    for e in brk:
        c0 = m.centres[m.ci[e]] + x[m.ca[e]] + d[m.ci[e]]
        tt = t[m.ca[e]]
        lpts += [c0 - 0.5 * L * tt, c0 + 0.5 * L * tt]
    atomic_write(path, lambda fh: _vtk_body(fh, m, P, N, s, nbr, free, vc, d, brk, lpts), binary=False)


def _vtk_body(fh, m, P, N, s, nbr, free, vc, d, brk, lpts):
    npts = 6 * N + len(lpts)
    fh.write("# vtk DataFile Version 3.0\nmine scene state t=%g s\nASCII\nDATASET POLYDATA\n" % m.t)
    fh.write(f"POINTS {npts} double\n")
    for q in P.reshape(-1, 2):
        fh.write(f"{q[0]:.6f} {q[1]:.6f} 0\n")
    for q in lpts:
        fh.write(f"{q[0]:.6f} {q[1]:.6f} 0\n")
    if len(brk):
        fh.write(f"LINES {len(brk)} {3 * len(brk)}\n")
        for k in range(len(brk)):
            fh.write(f"2 {6 * N + 2 * k} {6 * N + 2 * k + 1}\n")
    fh.write(f"POLYGONS {N} {7 * N}\n")
    for c in range(N):
        fh.write("6 " + " ".join(str(6 * c + k) for k in range(6)) + "\n")
    ncell = len(brk) + N
    fh.write(f"CELL_DATA {ncell}\n")

    def scal(name, vals_lines, vals_polys, fmt="%.6g"):
        fh.write(f"SCALARS {name} double 1\nLOOKUP_TABLE default\n")
        fh.write("\n".join(fmt % v for v in np.concatenate([vals_lines, vals_polys])) + "\n")

    bl = m.broken[brk].astype(float)
    z = np.zeros(len(brk))
    scal("broken_type", bl, np.full(N, -1.0))
    scal("coal", z, m.is_coal.astype(float))
    scal("sxx_MPa", z, s[:, 0] / 1e6)
    scal("syy_MPa", z, s[:, 1] / 1e6)
    scal("sxy_MPa", z, s[:, 2] / 1e6)
    scal("n_broken", z, nbr.astype(float))
    scal("free", z, free.astype(float))
    scal("speed", z, np.linalg.norm(vc, axis=1))
    fh.write("VECTORS displacement double\n")
    fh.write("\n".join(f"{a:.6g} {b:.6g} 0" for a, b in np.vstack([np.zeros((len(brk), 2)), d])) + "\n")


def snapshot(scene) -> dict:
    """Compact picture of a final state (arrays only, for ``np.savez``): cell centres (N,2) [m],
    displacement of the centres (N,2) [m], coal flag, number of broken interfaces per cell, free
    flag, broken interfaces as segments (M,2,2) [m] with their type, the dislocation lines, domain."""
    m = scene.model
    nif, nbr, detached, free = cell_flags(m)
    x, L, t = m.geo["x"], m.geo["L"], m.geo["t"]
    e = np.nonzero(m.broken > 0)[0]
    c0 = m.centres[m.ci[e]] + x[m.ca[e]]
    tt = t[m.ca[e]]
    segs = np.stack([c0 - 0.5 * L * tt, c0 + 0.5 * L * tt], axis=1) if len(e) else np.zeros((0, 2, 2))
    g = scene.geometry
    return {"centres": m.centres, "disp": (m.u - m.u0).reshape(-1, 6, 2).mean(axis=1), "is_coal": m.is_coal,
            "nbr": nbr, "free": free, "crack_segs": segs, "crack_type": m.broken[e],
            "disl": np.array(g.dislocations).reshape(-1, 2, 2), "domain": np.array([g.W, g.H]),
            "verts": m.geo["verts"]}


def draw_snapshot(ax, snap, title="", vectors=False, xlim=None, vec_scale=None):
    """Draw a :func:`snapshot` on a matplotlib axis: cells (grey rock, dark coal, brown cracked coal,
    red free) at their displaced positions, cracks (red tension, blue shear), the dislocation lines
    (green dashed); with ``vectors`` the displacement vectors of the centres instead of the cells'
    movement."""
    plt, PolyCollection, LineCollection = _mpl()
    C = snap["centres"]
    d = snap["disp"]
    coal = snap["is_coal"].astype(bool)
    col = np.where(coal, "#404040", "#c8c8c8").astype(object)
    col[(snap["nbr"] > 0) & coal] = "#8a6d3b"
    col[snap["free"].astype(bool)] = "#ff3030"
    P = C[:, None, :] + snap["verts"][None, :, :] + (0.0 if vectors else d[:, None, :])
    ax.add_collection(PolyCollection(P, facecolors=list(col), edgecolors="#909090", linewidths=0.15))
    if len(snap["crack_segs"]):
        cols = np.where(snap["crack_type"] == 1, "tab:red", "tab:blue")
        ax.add_collection(LineCollection(snap["crack_segs"], colors=list(cols), linewidths=1.0))
    for seg in snap["disl"]:
        ax.plot(seg[:, 0], seg[:, 1], "g--", lw=0.9)
    if vectors:
        mag = np.linalg.norm(d, axis=1)
        if vec_scale is None:
            vec_scale = 0.8 / max(np.percentile(mag, 99.5), 1e-12)
        sel = mag > 0.02 * mag.max()
        ax.quiver(C[sel, 0], C[sel, 1], d[sel, 0], d[sel, 1], angles="xy", scale_units="xy",
                  scale=1.0 / vec_scale, width=0.002, color="navy")
    W, H = snap["domain"]
    ax.set_xlim(*(xlim or (-0.3, W + 0.3)))
    ax.set_ylim(-0.3, H + 0.3)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
