"""Pictures of packings: disks, the periodic cell and force chains (matplotlib, Agg backend).

``plot_packing(network, path)`` draws every disk (rattlers greyed), the cell outline and one line per
contact from centre to centre with a width proportional to its normal force (force chains).
"""
from __future__ import annotations

import numpy as np

from microhom.network import ContactNetwork
from microhom.periodic import wrap
from microhom.structural_sums import rattlers

__all__ = ["plot_packing"]


def plot_packing(net: ContactNetwork, path, *, title=None, max_width=3.0, dpi=150, show_images=True):
    """Save a PNG of the packing with force chains to ``path``; returns the path.

    Line width = ``max_width * fn / max(fn)`` (points); sliding contacts are drawn in orange.
    Particles are drawn at their wrapped positions; contacts that cross the periodic boundary are
    drawn from both ends (to the image) when ``show_images``.

    Parameters
    ----------
    net : microhom.network.ContactNetwork
        The packing: positions (N, 2) and radii (N,) in the same length unit, contact pairs and
        normal forces ``fn`` (C,) (without forces every contact line is 0.5 points wide).
    path : str or path-like
        Output PNG file.
    title : str, optional
        Figure title.
    max_width : float
        Width in points of the line of the largest normal force.
    dpi : int
        Resolution of the PNG (dots per inch).
    show_images : bool
        Draw contacts across the periodic boundary from both ends.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import EllipseCollection, LineCollection

    pos = np.asarray(net.positions, dtype=float)
    if net.cell is not None:
        pos, _ = wrap(pos, net.cell, net.origin)
    rat, _ = rattlers(net)
    n_ext = max(np.ptp(pos[:, 0]), np.ptp(pos[:, 1]), 1e-12)
    size = 7.0 if net.n_particles < 20000 else 12.0
    fig, ax = plt.subplots(figsize=(size, size))
    colors = np.where(rat, "0.85", "0.65")
    ax.add_collection(EllipseCollection(2 * net.radii, 2 * net.radii, np.zeros(net.n_particles), units="xy",
                                        offsets=pos, offset_transform=ax.transData, facecolors=colors,
                                        edgecolors="0.4", linewidths=0.2))
    if net.n_contacts:
        fn = np.zeros(net.n_contacts) if net.fn is None else np.asarray(net.fn)
        fmax = np.max(np.abs(fn)) if np.any(fn) else 1.0
        a = pos[net.pairs[:, 0]]
        segs = [np.stack([a, a + net.branch], axis=1)]
        widths = [max_width * np.abs(fn) / fmax if net.fn is not None else np.full(net.n_contacts, 0.5)]
        slide = [net.sliding]
        if show_images and net.cell is not None:
            b = pos[net.pairs[:, 1]]
            crosses = np.any(np.abs((a + net.branch) - b) > 1e-9 * n_ext, axis=1)
            segs.append(np.stack([b[crosses], b[crosses] - net.branch[crosses]], axis=1))
            widths.append(widths[0][crosses])
            slide.append(net.sliding[crosses])
        segs = np.concatenate(segs)
        widths = np.concatenate(widths)
        slide = np.concatenate(slide)
        ax.add_collection(LineCollection(segs, linewidths=widths,
                                         colors=np.where(slide[:, None], [[0.9, 0.5, 0.0, 1.0]],
                                                         [[0.75, 0.05, 0.05, 1.0]])))
    if net.cell is not None:
        o = net.origin
        h = net.cell
        corners = np.array([o, o + h[:, 0], o + h[:, 0] + h[:, 1], o + h[:, 1], o])
        ax.plot(corners[:, 0], corners[:, 1], "k-", lw=0.8)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{net.n_particles} disks, {net.n_contacts} contacts; line width ~ normal force")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
