"""The Verlet-list rebuild (:func:`dem.engine.neighbors.rebuild`) against a plain reference of its
specification: an O(N^2) search over every pair and every image shift in [-2, 2]^2, the spatial sort
as a stable argsort of the bin index, and the contact history carried over through a dict keyed by
(i, j, shift) in the new labels (the first old pair of a key wins).

The reference repeats the rebuild's floating-point expressions (fractional coordinates, branch
vector ``(x_j + h s) - x_i``, cutoff ``(r_i + r_j) + skin``) so that the lists must be equal bit
for bit, pairs at the cutoff included. The states are random: sheared and rotated cells,
polydisperse radii, positions far outside the cell, cells of 1 to 3 bins across (several images of a
pair), history slots with both parities, old lists in and out of order.
"""
import math

import numpy as np
import pytest

from dem.engine.neighbors import rebuild
from dem.engine.state import State
from microhom.periodic import heights
from studies import bench_rebuild

SHIFTS = np.array([(a, b) for a in range(-2, 3) for b in range(-2, 3)], dtype=np.int64)


# ---- reference ---------------------------------------------------------------------------------
def ref_fractional(x, h):
    """Fractional coordinates (N, 2) as the rebuild computes them (the inverse by the cofactors)."""
    det = h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
    return np.stack([(h[1, 1] * x[:, 0] - h[0, 1] * x[:, 1]) / det,
                     (-h[1, 0] * x[:, 0] + h[0, 0] * x[:, 1]) / det], axis=1)


def ref_wrap(x, h):
    """Wrapped positions (N, 2) and the integer wraps k (N, 2) removed: x - h k."""
    k = np.floor(ref_fractional(x, h)).astype(np.int64)
    x = x.copy()
    moved = (k != 0).any(axis=1)
    x[moved, 0] -= h[0, 0] * k[moved, 0] + h[0, 1] * k[moved, 1]
    x[moved, 1] -= h[1, 0] * k[moved, 0] + h[1, 1] * k[moved, 1]
    return x, k


def ref_bins(x, h, rc):
    """Bin index (N,) of wrapped positions: nb_a x nb_b bins of widths >= rc, row-major in a."""
    nba, nbb = (max(1, int(w // rc)) for w in heights(h))
    s = ref_fractional(x, h)
    a = np.clip(np.floor(s[:, 0] * nba).astype(np.int64), 0, nba - 1)
    b = np.clip(np.floor(s[:, 1] * nbb).astype(np.int64), 0, nbb - 1)
    return b * nba + a


def ref_pairs(x, radius, h, skin):
    """Every (i < j, shift) with |(x_j + h s) - x_i| < (r_i + r_j) + skin, ordered by
    (i, j, s_0, s_1): (P,), (P,), (P, 2)."""
    n = x.shape[0]
    i, j = np.triu_indices(n, 1)
    out = []
    for sa, sb in SHIFTS:
        ox = h[0, 0] * float(sa) + h[0, 1] * float(sb)
        oy = h[1, 0] * float(sa) + h[1, 1] * float(sb)
        dx = (x[j, 0] + ox) - x[i, 0]
        dy = (x[j, 1] + oy) - x[i, 1]
        rc = (radius[i] + radius[j]) + skin
        keep = dx * dx + dy * dy < rc * rc
        out.append(np.stack([i[keep], j[keep], np.full(keep.sum(), sa), np.full(keep.sum(), sb)], 1))
    p = np.concatenate(out)
    p = p[np.lexsort((p[:, 3], p[:, 2], p[:, 1], p[:, 0]))]
    return p[:, 0], p[:, 1], np.ascontiguousarray(p[:, 2:])


PER_PARTICLE = ("x", "v", "radius", "mass", "inertia", "omega", "theta", "ids")


def ref_rebuild(st, skin, sort, parity):
    """The expected state after ``rebuild(st, skin, sort=sort, history=parity)`` as a dict."""
    x, k = ref_wrap(st.x, st.h)
    n = x.shape[0]
    rc = 2.0 * float(np.max(st.radius)) + skin
    out = {name: getattr(st, name) for name in PER_PARTICLE}
    out["x"] = x
    perm = np.argsort(ref_bins(x, st.h, rc), kind="stable") if sort else np.arange(n)
    out = {name: (None if a is None else a[perm]) for name, a in out.items()}
    inv = np.empty(n, np.int64)
    inv[perm] = np.arange(n)
    pi, pj, ps = ref_pairs(out["x"], out["radius"], st.h, skin)
    nk = len(parity)
    ft = None
    if nk:
        ft = np.zeros((pi.shape[0], nk))
        old = {}
        if st.nl_i is not None and st.nl_ft is not None and st.nl_ft.size == nk * st.nl_i.shape[0]:
            oft = st.nl_ft.reshape(-1, nk)
            for q, (a, b) in enumerate(zip(st.nl_i, st.nl_j)):
                s = st.nl_shift[q] + k[b] - k[a]
                f = oft[q]
                a, b = inv[a], inv[b]
                if a > b:
                    a, b, s, f = b, a, -s, f * np.asarray(parity, float)
                old.setdefault((a, b, s[0], s[1]), f)
        for p in range(pi.shape[0]):
            ft[p] = old.get((pi[p], pj[p], ps[p, 0], ps[p, 1]), 0.0)
        if nk == 1:
            ft = ft.reshape(-1)
    out.update(nl_i=pi, nl_j=pj, nl_shift=ps, nl_ft=ft, x_ref=out["x"], h_ref=st.h)
    return out


def assert_rebuild_matches(st, skin, sort=False, parity=(1,)):
    """Rebuild a copy of ``st`` and compare every array with the reference, bit for bit."""
    want = ref_rebuild(st, skin, sort, parity)
    got = st.copy()
    m = rebuild(got, skin, sort=sort, history=parity)
    assert m == want["nl_i"].shape[0]
    for name, a in want.items():
        b = getattr(got, name)
        if a is None:
            assert b is None, name
            continue
        assert b.dtype == a.dtype and b.shape == a.shape, name
        assert np.array_equal(b.view(np.uint8), np.ascontiguousarray(a).view(np.uint8)), name
    return got


# ---- random states -----------------------------------------------------------------------------
def random_state(rng, n, widths_in_rc=None, phi=0.7, shear=0.3, rotate=0.0, spread=0.5):
    """n disks, radii uniform in [0.5, 1] (polydisperse), in a sheared and rotated cell at solid
    fraction ``phi``; positions spread ``spread`` cell lengths beyond the cell on each side.
    ``widths_in_rc``: the cell's perpendicular widths in units of the list cutoff (small cells)."""
    r = rng.uniform(0.5, 1.0, n)
    if widths_in_rc is not None:
        rc = 2.0 * r.max() + 0.3
        wa, wb = widths_in_rc
        h = np.array([[wa * rc, shear * wb * rc], [0.0, wb * rc]])
    else:
        side = math.sqrt(np.pi * np.sum(r * r) / phi)
        h = np.array([[side * 1.3, shear * side / 1.3], [0.0, side / 1.3]])
    h = np.array([[math.cos(rotate), -math.sin(rotate)], [math.sin(rotate), math.cos(rotate)]]) @ h
    s = rng.uniform(-spread, 1.0 + spread, (n, 2))
    x = s @ h.T
    st = State.from_disks(x, r, h, spins=True, v=rng.normal(size=(n, 2)), omega=rng.normal(size=n))
    st.ids = rng.permutation(n).astype(np.int64)
    return st


def evolve(st, rng, step, jump_fraction=0.05, strain=0.02):
    """Move the disks by ~``step`` (a few by whole cell vectors: new wraps) and deform the cell by
    ~``strain``."""
    n = st.n
    st.x = st.x + rng.normal(scale=step, size=(n, 2))
    jump = rng.random(n) < jump_fraction
    st.x[jump] += (st.h @ rng.integers(-2, 3, (2, jump.sum()))).T  # other images of the disks
    st.h = (np.eye(2) + strain * rng.normal(size=(2, 2))) @ st.h


def history(st, rng, nk):
    """A random history (nk slots) for every listed pair."""
    f = rng.normal(size=(st.nl_i.shape[0], nk))
    st.nl_ft = f.reshape(-1) if nk == 1 else f


CASES = [  # (n, widths in rc or None, shear, rotation, history parities)
    (300, None, 0.3, 0.0, (1,)),
    (300, None, -0.6, 0.4, (1, -1, -1)),
    (200, None, 1.2, -1.0, (-1, 1)),
    (250, None, 0.0, 0.0, ()),
    (40, (1.2, 1.5), 0.4, 0.2, (1, -1)),   # 1 x 1 bins: three images of a pair
    (60, (2.5, 1.7), -0.3, 0.0, (1,)),     # 2 x 1 bins
    (90, (3.2, 2.2), 0.7, 0.5, (-1,)),     # 3 x 2 bins
]


@pytest.mark.parametrize("sort", [False, True])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_rebuild_matches_reference(case, sort):
    n, widths, shear, rot, parity = CASES[case]
    rng = np.random.default_rng(100 + case)
    st = random_state(rng, n, widths, shear=shear, rotate=rot)
    skin = 0.3
    st = assert_rebuild_matches(st, skin, sort=False, parity=parity)  # first build: no history
    for build in range(4):
        if parity:
            history(st, rng, len(parity))
        evolve(st, rng, step=0.1)
        st = assert_rebuild_matches(st, skin, sort=sort and build % 2 == 0, parity=parity)


def test_rebuild_history_from_an_unordered_or_far_shifted_list():
    """Old lists the ordered merge does not take (shuffled, shifts beyond the packed range,
    repeated keys) go through the general carry-over with the same result; an old list far
    shorter than the new one."""
    rng = np.random.default_rng(7)
    st = random_state(rng, 300, None)
    st = assert_rebuild_matches(st, 0.3, parity=(1, -1))
    history(st, rng, 2)
    evolve(st, rng, step=0.05)
    shuffled = st.copy()
    q = rng.permutation(st.nl_i.shape[0])
    shuffled.nl_i, shuffled.nl_j = st.nl_i[q], st.nl_j[q]
    shuffled.nl_shift, shuffled.nl_ft = st.nl_shift[q], st.nl_ft[q]
    assert_rebuild_matches(shuffled, 0.3, parity=(1, -1))
    far = st.copy()
    far.x[: st.n // 2] += st.h @ np.array([9.0, -12.0])  # wraps of 9 and 12 cells: shifts > 8
    assert_rebuild_matches(far, 0.3, parity=(1, -1))
    repeated = st.copy()  # each pair twice, the second copy's history must be ignored
    repeated.nl_i, repeated.nl_j = np.repeat(st.nl_i, 2), np.repeat(st.nl_j, 2)
    repeated.nl_shift = np.repeat(st.nl_shift, 2, axis=0)
    repeated.nl_ft = np.repeat(st.nl_ft, 2, axis=0)
    repeated.nl_ft[1::2] = rng.normal(size=repeated.nl_ft[1::2].shape)
    assert_rebuild_matches(repeated, 0.3, parity=(1, -1))
    tiny = st.copy()  # 3 old pairs: the room reserved for the new list overflows (a second pass)
    tiny.nl_i, tiny.nl_j, tiny.nl_shift, tiny.nl_ft = st.nl_i[:3], st.nl_j[:3], st.nl_shift[:3], st.nl_ft[:3]
    got = assert_rebuild_matches(tiny, 0.3, parity=(1, -1))
    assert got.nl_i.shape[0] > max(64, int(1.25 * 3) + tiny.n // 8)  # the room rebuild reserves


def test_rebuild_pairs_at_the_cutoff_of_a_square_lattice():
    """Disks on a square lattice of spacing 1 whose cutoff r_i + r_j + skin rounds to 1 or just
    below it (the strict ``<`` decides) and an empty old list."""
    n = 12
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2).astype(float)
    for r, skin in [(0.45, 0.1), (0.4, 0.2), (0.375, 0.25), (0.5, 1e-12)]:
        st = State.from_disks(g + 0.25, r, np.eye(2) * n, spins=True)
        st.nl_i = st.nl_j = np.zeros(0, np.int64)
        st.nl_shift = np.zeros((0, 2), np.int64)
        st.nl_ft = np.zeros(0)
        assert_rebuild_matches(st, skin, parity=(1,))


@pytest.mark.parametrize("seed", [1, 2])
def test_rebuild_of_a_spatially_sorted_state(seed):
    """A dense state sorted by bin, then moved by up to about a bin: most neighbourhoods are
    still in increasing order (the search's fast path), some disks have crossed into the rows
    above and below."""
    rng = np.random.default_rng(seed)
    st = random_state(rng, 1200, None, phi=0.8, shear=0.2, spread=0.0)
    st = assert_rebuild_matches(st, 0.3, sort=True, parity=(1, -1))
    for step in (0.2, 0.4, 0.8):
        history(st, rng, 2)
        evolve(st, rng, step=step, jump_fraction=0.0, strain=0.005)
        st = assert_rebuild_matches(st, 0.3, sort=False, parity=(1, -1))


@pytest.mark.slow
def test_bench_rebuild_runs_and_matches_head(capsys):
    """``studies.bench_rebuild --against HEAD`` on a small scene runs, and the working tree's
    rebuild gives the same lists as the committed one, with and without the spatial sort."""
    bench_rebuild.main(["--base-n", "1000", "--ns", "4000", "--repeats", "1", "--inner", "1",
                        "--against", "HEAD"])
    out = capsys.readouterr().out
    assert out.count("outputs bit-identical: True") == 2, out
