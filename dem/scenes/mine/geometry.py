"""Geometry of the mine scene: the resolved domain (after the readings), the dislocation lines,
which interfaces they cut, and the blocks of coal between them.

Units: m. The seam is horizontal; the adit is an opening over the full seam height. ``x`` grows away
from the adit's axis in the half-model (the left boundary is the symmetry plane).

Dislocation placement (paper: "the toe of the first dislocation at the lower boundary ... 2.5 m from
the wall" for 60 deg, "the upper part of the first dislocation ... 2.5 m from the wall" for 120 deg,
the next ones 5 m further each). The *named end* is the toe (floor end) for angles below 90 deg and
the top (roof end) above. ``placement="near"``: the named end is the end nearest to the rib and the
line runs away from the opening. ``placement="far"``: the named end is the far end and the line runs
toward the rib (it may cut the face).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...hexagons.fault import segments_cross

__all__ = ["Geometry", "resolve", "segments_cross", "block_labels", "block_names"]


@dataclass(frozen=True)
class Geometry:
    """The domain as built, after the readings (all m).

    ``W`` x ``H`` domain; coal seam ``seam_lo <= y <= seam_hi``; opening ``open_x0 <= x <= open_x1``
    over the seam height; ``rib_x`` the face of the rib that holds the dislocations (``side`` +1 for
    the right rib, -1 for the left); rock interfaces with both cells above ``y_elastic`` are
    unbreakable (the loading layer); ``dislocations`` a tuple of (2,2) arrays (floor end, roof end);
    ``named_end`` 0 (floor) or 1 (roof); ``r_in`` the hexagons' inner radius."""
    W: float
    H: float
    seam_lo: float
    seam_hi: float
    open_x0: float
    open_x1: float
    rib_x: float
    side: int
    y_elastic: float
    r_in: float
    named_end: int
    dislocations: tuple

    @property
    def seam_mid(self) -> float:
        return 0.5 * (self.seam_lo + self.seam_hi)


def resolve(p) -> Geometry:
    """The geometry of a :class:`~dem.scenes.mine.params.MineParams` after its readings."""
    y0 = p.floor_layer if p.floor == "rock" else 0.0
    extra = p.tall_extra if p.loading == "tall" else 0.0
    H = p.height + y0 + extra
    if p.model == "half":
        W, ox0, ox1 = p.width, 0.0, 0.5 * p.adit_width
    else:
        W = 2.0 * p.width
        ox0, ox1 = p.width - 0.5 * p.adit_width, p.width + 0.5 * p.adit_width
    side = 1 if p.disl_side == "right" else -1
    rib = ox1 if side > 0 else ox0
    lo, hi = p.seam_bottom + y0, p.seam_top + y0
    named = 0 if p.disl_angle_deg < 90.0 else 1
    segs = []
    if p.n_disl > 0:
        h = hi - lo
        dx = abs(h / math.tan(math.radians(p.disl_angle_deg))) if p.disl_angle_deg != 90 else 0.0
        away = 1.0 if p.placement == "near" else -1.0       # the other end: away from / toward the rib
        for k in range(p.n_disl):
            xn = rib + side * (p.disl_first + k * p.disl_spacing)
            xo = xn + side * away * dx
            ends = (xn, xo) if named == 0 else (xo, xn)
            segs.append(np.array([[ends[0], lo], [ends[1], hi]]))
    return Geometry(W=W, H=H, seam_lo=lo, seam_hi=hi, open_x0=ox0, open_x1=ox1, rib_x=rib, side=side,
                    y_elastic=H - p.elastic_layer - extra, r_in=p.r_in, named_end=named,
                    dislocations=tuple(segs))


def block_labels(g: Geometry, centres, is_coal):
    """Label of each cell (N,) int: 0 = the wedge between the rib and the first dislocation,
    k = the block between dislocations k and k+1, n_disl = the seam beyond the last one, -1 = rock or
    coal on the other rib. The labels depend only on the geometry, so a control run (no dislocation)
    on the same lattice is labelled with the partition of the case it is compared with."""
    C = np.asarray(centres, float)
    lab = np.full(len(C), -1, np.int64)
    mine = np.asarray(is_coal, bool) & (g.side * (C[:, 0] - g.rib_x) > -g.r_in)
    cnt = np.zeros(len(C), np.int64)
    for seg in g.dislocations:
        (xb, yb), (xt, yt) = seg
        xl = xb + (C[:, 1] - yb) / (yt - yb) * (xt - xb)
        cnt += (g.side * (C[:, 0] - xl) > 0).astype(np.int64)
    lab[mine] = cnt[mine]
    return lab


def block_names(n_disl: int):
    """Names of the labels 0..n_disl of :func:`block_labels`."""
    return ["wedge"] + [f"block{k}" for k in range(1, n_disl)] + (["beyond"] if n_disl > 0 else ["seam"])
