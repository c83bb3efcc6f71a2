"""Cell-list Verlet neighbour lists in a periodic (possibly sheared) cell, with contact history.

Binning is done in fractional coordinates ``s = h^{-1} x``: the cell is cut into ``nb_a x nb_b``
bins whose perpendicular widths ``H_a / nb_a`` are at least the list cutoff ``rc = 2 r_max + skin``,
so every pair closer than ``rc`` lies in adjacent bins, whatever the shear of the cell. Each pair is
stored once (``i < j``) with its integer image shift ``s`` (branch vector ``x_j + h s - x_i``); the
pair enters the list when ``|branch| < r_i + r_j + skin``.

Rebuild criterion (checked after each step): with ``F = h h_ref^{-1}`` the cell deformation since the
last build and ``d_i = |x_i - F x_ref_i|`` the non-affine displacement, a pair can have come closer
by at most ``d_i + d_j + ||F - I||_2 rc``; the list is rebuilt when
``2 max_i d_i + ||F - I||_2 rc > skin`` (the classic "moved more than half the skin" rule, plus the
cell deformation).

At a rebuild, positions are wrapped into the cell (the image shifts of the old pairs are updated
accordingly, ``s' = s + k_j - k_i``), particles are optionally re-ordered by bin (spatial sorting for
memory locality; ``ids`` keeps the original labels) and the contact history of every pair
``(i, j, s)`` still in the list is carried over. Each history slot has a parity under swapping i
and j (declared by the contact law's sub-models): a scalar tangential force along
``t = rot90(n)`` is invariant (+1), a shear-displacement vector or a relative rotation changes
sign (-1); a re-ordering that swaps a pair applies it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .cell import heights

__all__ = ["rebuild", "list_cutoff", "bin_counts"]


def list_cutoff(radius, skin) -> float:
    """Neighbour-list cutoff ``2 max(radius) + skin`` [m] for radii (N,) [m] and a skin [m]."""
    return 2.0 * float(np.max(radius)) + float(skin)


def bin_counts(h, rc):
    """Number of bins along each fractional direction (>= 1) and the check that the cell is large
    enough: both perpendicular widths must exceed ``rc`` (no particle meets its own image; a cell
    narrower than ``2 rc`` can hold a pair at two images, and both are listed)."""
    H = heights(h)
    if np.any(H <= rc):
        raise ValueError(f"periodic cell too small: its widths {H} must exceed the neighbour-list "
                         f"cutoff 2 r_max + skin = {rc:.6g}")
    return max(1, int(H[0] // rc)), max(1, int(H[1] // rc))


@njit(cache=True, inline="always")
def _fractional(x0, x1, h00, h01, h10, h11, det):
    """Fractional coordinates ``h^{-1} x`` of one position (by the cofactors of h)."""
    return (h11 * x0 - h01 * x1) / det, (-h10 * x0 + h00 * x1) / det


@njit(cache=True)
def _wrap_and_bin(x, h00, h01, h10, h11, nba, nbb, k, binof):
    """Wrap the positions x (N, 2) into the cell in place, ``x -= h k`` with k (N, 2) the whole
    cell vectors removed (``floor`` of the fractional coordinates), and write the bin of each
    wrapped position into binof (N,): ``b * nba + a`` on the nba x nbb grid of fractional
    coordinates (clipped to the grid against rounding at the faces)."""
    det = h00 * h11 - h01 * h10
    for i in range(x.shape[0]):
        s0, s1 = _fractional(x[i, 0], x[i, 1], h00, h01, h10, h11, det)
        k0 = math.floor(s0)
        k1 = math.floor(s1)
        k[i, 0] = k0
        k[i, 1] = k1
        if k0 != 0 or k1 != 0:
            x[i, 0] -= h00 * k0 + h01 * k1
            x[i, 1] -= h10 * k0 + h11 * k1
            s0, s1 = _fractional(x[i, 0], x[i, 1], h00, h01, h10, h11, det)
        a = min(max(int(math.floor(s0 * nba)), 0), nba - 1)
        b = min(max(int(math.floor(s1 * nbb)), 0), nbb - 1)
        binof[i] = b * nba + a


@njit(cache=True)
def _relabel_old_pairs(oi, oj, osh, oft, k, inv, parity):
    """The old list oi, oj (P_old,), osh (P_old, 2), oft (P_old, nk) with the wrap shifts k (N, 2)
    applied (``s + k_j - k_i``) and in the labels of a particle permutation (new index =
    inv[old]), as new arrays keeping i < j: a swapped pair's shift changes sign and its history
    slots are multiplied by their parities (N, +1 or -1)."""
    nold = oi.shape[0]
    ni = np.empty(nold, np.int64)
    nj = np.empty(nold, np.int64)
    nsh = np.empty((nold, 2), np.int64)
    nft = np.empty_like(oft)
    for p in range(nold):
        i = oi[p]
        j = oj[p]
        s0 = osh[p, 0] + k[j, 0] - k[i, 0]
        s1 = osh[p, 1] + k[j, 1] - k[i, 1]
        a = inv[i]
        b = inv[j]
        swap = b < a
        ni[p] = b if swap else a
        nj[p] = a if swap else b
        nsh[p, 0] = -s0 if swap else s0
        nsh[p, 1] = -s1 if swap else s1
        for c in range(parity.shape[0]):
            nft[p, c] = -oft[p, c] if swap and parity[c] < 0 else oft[p, c]
    return ni, nj, nsh, nft


@njit(cache=True)
def _bin_slots(binof, nbins):
    """Counting sort of the particles by their bin binof (N,) in [0, nbins): start (nbins + 1,),
    bin c holds the slots start[c]..start[c+1]-1; members (N,), the particle in each slot
    (increasing within a bin: the stable ``argsort(binof)``); slot (N,), each particle's slot."""
    n = binof.shape[0]
    start = np.zeros(nbins + 1, np.int64)
    for i in range(n):
        start[binof[i] + 1] += 1
    for c in range(nbins):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, np.int64)
    slot = np.empty(n, np.int64)
    for i in range(n):
        q = fill[binof[i]]
        members[q] = i
        slot[i] = q
        fill[binof[i]] = q + 1
    return start, members, slot


@njit(cache=True)
def _gather_by_bin(x, radius, binof, nba, nbb):
    """The particles by bin (row-major, ``c = b * nba + a``): start, members, slot of
    :func:`_bin_slots`; xs (N, 2), rs (N,): positions and radii gathered by slot; run (nbins,)
    bool: the bins c-1, c, c+1 of one row (1 <= a <= nba-2, no wrap) hold increasing particles
    (a spatially sorted state: then the three bins can be scanned as one range); top (nbins,):
    the largest particle in these three bins (-1 if none; N at the edges a = 0, nba-1)."""
    n = x.shape[0]
    nbins = nba * nbb
    start, members, slot = _bin_slots(binof, nbins)
    xs = np.empty((n, 2))
    rs = np.empty(n)
    for q in range(n):
        i = members[q]
        xs[q, 0] = x[i, 0]
        xs[q, 1] = x[i, 1]
        rs[q] = radius[i]
    descents = np.zeros(n + 1, np.int64)  # descents[q]: slots r < q with members[r] < members[r-1]
    for q in range(1, n):
        descents[q + 1] = descents[q] + (members[q] < members[q - 1])
    last = np.empty(nbins, np.int64)  # the largest particle of each bin (in its last slot), -1
    for c in range(nbins):
        last[c] = members[start[c + 1] - 1] if start[c + 1] > start[c] else -1
    run = np.zeros(nbins, np.bool_)
    top = np.full(nbins, n, np.int64)
    for b in range(nbb):
        for a in range(1, nba - 1):
            c = b * nba + a
            lo = start[c - 1]
            hi = start[c + 2]
            run[c] = hi <= lo + 1 or descents[hi] == descents[lo + 1]
            top[c] = max(last[c - 1], max(last[c], last[c + 1]))
    return start, members, slot, xs, rs, run, top


@njit(cache=True, inline="always")
def _periodic_bin(u, nb):
    """Bin index u in [-1, nb] of a row or column of nb bins brought into [0, nb), and the image
    shift (-1, 0 or +1) that this crossing of the cell's face adds."""
    if u < 0:
        return u + nb, -1
    if u >= nb:
        return u - nb, 1
    return u, 0


@njit(cache=True)
def _find_pairs(x, radius, h, nba, nbb, binof, skin, cap):
    """Pairs (i < j, image shift) closer than ``r_i + r_j + skin`` in the cell ``h`` (2, 2) (its
    columns the periodic vectors), grouped by i and sorted by
    (j, shift) within each i (so that the order of the force sums does not depend on the bin
    layout), and their count ``m`` (only the first ``cap`` are stored: call again with
    ``cap = m`` if ``m > cap``). Returns pi, pj (cap + 1,), ps (cap + 1, 2) int64 and m.

    The particles are gathered by bin (:func:`_gather_by_bin`), so the candidates of a bin are
    read contiguously, and the candidates ``j > i`` of particle i are scanned as ranges of slots:
    a bin, or a row of three bins when their particles increase (``run``). A range holding i
    starts after i's slot (its smaller particles are all before it); a row all ``<= i`` is
    skipped; otherwise ``j > i`` is part of the (branch-free) test. Fast path, the common case in
    a spatially sorted state: i's row and the row above are runs, the row below holds only
    particles ``< i`` and the row above only particles above those of i's row. Then the candidates
    are the slots after i in its row and the row above, read in increasing j (all with shift 0),
    and need no sort."""
    n = x.shape[0]
    h00 = h[0, 0]
    h01 = h[0, 1]
    h10 = h[1, 0]
    h11 = h[1, 1]
    start, members, slot, xs, rs, run, top = _gather_by_bin(x, radius, binof, nba, nbb)
    pi = np.empty(cap + 1, np.int64)
    pj = np.empty(cap + 1, np.int64)
    ps = np.empty((cap + 1, 2), np.int64)
    seg = np.empty((9, 4), np.int64)  # ranges of slots to scan: first, end, shift (sa, sb)
    m = 0
    for i in range(n):
        c = binof[i]
        ca = c % nba
        cb = c // nba
        xi0 = x[i, 0]
        xi1 = x[i, 1]
        ri = radius[i]
        si = slot[i]
        m0 = m
        nseg = 0
        ordered = False
        if 1 <= cb and cb <= nbb - 2 and run[c] and run[c + nba] and top[c - nba] < i:
            end0 = start[c + 2]
            lo_up = start[c + nba - 1]
            hi_up = start[c + nba + 2]
            if lo_up == hi_up or members[end0 - 1] < members[lo_up]:
                seg[0, 0] = si + 1
                seg[0, 1] = end0
                seg[1, 0] = lo_up
                seg[1, 1] = hi_up
                seg[0, 2] = seg[0, 3] = seg[1, 2] = seg[1, 3] = 0
                nseg = 2
                ordered = True
        if nseg == 0:
            for db in range(-1, 2):
                ub, sb = _periodic_bin(cb + db, nbb)
                row = run[ub * nba + ca]
                for t in range(1 if row else 3):
                    if row:
                        lo = start[ub * nba + ca - 1]
                        hi = start[ub * nba + ca + 2]
                        sa = 0
                        if hi <= lo or members[hi - 1] <= i:
                            continue
                    else:
                        ua, sa = _periodic_bin(ca + t - 1, nba)
                        lo = start[ub * nba + ua]
                        hi = start[ub * nba + ua + 1]
                    if lo <= si and si < hi:
                        lo = si + 1
                    seg[nseg, 0] = lo
                    seg[nseg, 1] = hi
                    seg[nseg, 2] = sa
                    seg[nseg, 3] = sb
                    nseg += 1
        for t in range(nseg):
            sa = seg[t, 2]
            sb = seg[t, 3]
            ox = h00 * sa + h01 * sb
            oy = h10 * sa + h11 * sb
            for q in range(seg[t, 0], seg[t, 1]):
                j = members[q]
                dx = xs[q, 0] + ox - xi0
                dy = xs[q, 1] + oy - xi1
                rc = ri + rs[q] + skin
                # branch-free append: written at slot min(m, cap) (slot cap is scratch), kept
                # by advancing m (an unpredictable test costs more than the stores)
                w = m if m < cap else cap
                pi[w] = i
                pj[w] = j
                ps[w, 0] = sa
                ps[w, 1] = sb
                m += (dx * dx + dy * dy < rc * rc) & (j > i)
        if not ordered and m <= cap:
            _sort_group(pj, ps, m0, m)
    return pi, pj, ps, m


@njit(cache=True, inline="always")
def _sort_group(pj, ps, p, q):
    """Insertion sort of pairs p..q-1 (one particle's) by (j, shift)."""
    for a in range(p + 1, q):
        kj = pj[a]
        k0 = ps[a, 0]
        k1 = ps[a, 1]
        b = a - 1
        while b >= p and (pj[b] > kj or (pj[b] == kj and (ps[b, 0] > k0 or (ps[b, 0] == k0 and ps[b, 1] > k1)))):
            pj[b + 1] = pj[b]
            ps[b + 1, 0] = ps[b, 0]
            ps[b + 1, 1] = ps[b, 1]
            b -= 1
        pj[b + 1] = kj
        ps[b + 1, 0] = k0
        ps[b + 1, 1] = k1


@njit(cache=True)
def _carry_history(oi, oj, osh, oft, k, pi, pj, ps, ft):
    """ft[p, :] = oft[q, :] of the first old pair q with the same (i, j, shift), the wrap shifts
    k (N, 2) applied to the old shifts (``s + k_j - k_i``); rows without one are left as they are.
    The old list oi, oj (P_old,), osh (P_old, 2), oft (P_old, nk) in any order; the new one pi, pj
    (P,), ps (P, 2); ft (P, nk)."""
    n = k.shape[0]
    start = np.zeros(n + 1, np.int64)
    for p in range(oi.shape[0]):
        start[oi[p] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    order = np.empty(oi.shape[0], np.int64)
    for p in range(oi.shape[0]):
        order[fill[oi[p]]] = p
        fill[oi[p]] += 1
    nk = ft.shape[1]
    for p in range(pi.shape[0]):
        i = pi[p]
        for q in range(start[i], start[i + 1]):
            o = order[q]
            j = oj[o]
            if (j == pj[p] and osh[o, 0] + k[j, 0] - k[i, 0] == ps[p, 0]
                    and osh[o, 1] + k[j, 1] - k[i, 1] == ps[p, 1]):
                for c in range(nk):
                    ft[p, c] = oft[o, c]
                break


_KEY_BITS = 4  # bits per shift component in a packed pair key: shifts in [-8, 7]
_KEY_MAX_N = 1 << 27  # i * n + j fits in 54 bits: the packed key stays below 2**62


@njit(cache=True, inline="always")
def _pair_key(i, j, s0, s1, n):
    """Packed int64 key of the pair (i, j, shift (s0, s1)) for n particles, increasing with
    (i, j, s0, s1) in lexicographic order; -1 if a shift component is outside [-8, 7]."""
    a = s0 + 8
    b = s1 + 8
    if (a | b) & ~15:
        return np.int64(-1)
    return (((i * n + j) << _KEY_BITS | a) << _KEY_BITS) | b


@njit(cache=True, inline="always")
def _old_key(oi, oj, osh, k, q, n):
    """Key of old pair q with the wrap shifts ``k`` (N, 2) applied: ``s + k_j - k_i``."""
    i = oi[q]
    j = oj[q]
    return _pair_key(i, j, osh[q, 0] + k[j, 0] - k[i, 0], osh[q, 1] + k[j, 1] - k[i, 1], n)


@njit(cache=True)
def _carry_history_ordered(oi, oj, osh, oft, k, pi, pj, ps, ft):
    """As :func:`_carry_history` for an old list ordered as :func:`_find_pairs` leaves it (no
    re-ordering since it was built): one merge pass on packed (i, j, shift) keys, the wrap shifts
    ``k`` (N, 2) applied to the old shifts on the fly.

    oi, oj (P_old,), osh (P_old, 2), oft (P_old, nk): the old list; pi, pj (P,), ps (P, 2): the new
    list, strictly increasing in (i, j, shift); ft (P, nk) is written entirely (0 where no old pair
    matches). Returns False, with ft partly written, if the old keys are not strictly increasing,
    an old shift leaves [-8, 7] or N >= 2**27: the caller then uses :func:`_carry_history`."""
    n = k.shape[0]
    nold = oi.shape[0]
    nk = ft.shape[1]
    if nold == 0 or n >= _KEY_MAX_N:
        return False
    q = 0  # the first old pair whose key kq is >= the current new key (nold past the end)
    kq = _old_key(oi, oj, osh, k, 0, n)
    if kq < 0:
        return False
    for p in range(pi.shape[0]):
        kp = _pair_key(pi[p], pj[p], ps[p, 0], ps[p, 1], n)
        while kq < kp:
            q += 1
            if q == nold:
                kq = np.int64(1) << 62
                break
            knext = _old_key(oi, oj, osh, k, q, n)
            if knext <= kq:  # out of order (or out of range: -1)
                return False
            kq = knext
        if kq == kp:
            for c in range(nk):
                ft[p, c] = oft[q, c]
        else:
            for c in range(nk):
                ft[p, c] = 0.0
    for r in range(q + 1, nold):  # the rest of the old list must be ordered too
        knext = _old_key(oi, oj, osh, k, r, n)
        if knext <= kq:
            return False
        kq = knext
    return True


_PER_PARTICLE = ("x", "v", "radius", "mass", "inertia", "omega", "theta", "ids")


def rebuild(state, skin, *, sort=False, history=None):
    """Rebuild the Verlet list of ``state`` in place (wrap, optional spatial sort, history carry-over).

    skin : list skin [m] (> 0). history : the parities (+1/-1) of the history slots of the contact
    law (``law.history_parity``; ``()`` for no history); default: one invariant slot if the
    state has a history, none otherwise. One slot is stored as ``nl_ft`` (P,), more as (P, k).
    Returns the number of pairs.
    """
    if not (skin > 0):
        raise ValueError(f"skin must be > 0, got {skin}")
    h = state.h
    rc = list_cutoff(state.radius, skin)
    nba, nbb = bin_counts(h, rc)
    n = state.n
    if history is None:
        history = (1,) if state.nl_ft is not None else ()
    parity = np.array(history, dtype=np.int64)
    nk = parity.shape[0]
    k = np.empty((n, 2), np.int64)
    binof = np.empty(n, np.int64)
    _wrap_and_bin(state.x, h[0, 0], h[0, 1], h[1, 0], h[1, 1], nba, nbb, k, binof)
    old = (state.nl_i is not None and nk > 0 and state.nl_ft is not None
           and state.nl_ft.size == nk * state.nl_i.shape[0])
    if old:
        oi, oj, osh = state.nl_i, state.nl_j, state.nl_shift
        oft = state.nl_ft.reshape(oi.shape[0], nk)
    if sort:
        perm = _bin_slots(binof, nba * nbb)[1]  # the stable argsort of binof
        for name in _PER_PARTICLE:
            arr = getattr(state, name)
            if arr is not None:
                setattr(state, name, np.take(arr, perm, axis=0))
        binof = binof[perm]
        if old:  # the old list in the new labels (new arrays: the state's list is not modified)
            inv = np.empty(n, np.int64)
            inv[perm] = np.arange(n)
            oi, oj, osh, oft = _relabel_old_pairs(oi, oj, osh, oft, k, inv, parity)
            k[:] = 0
    # room for the new list: 25 % above the old one (a second pass if it is exceeded)
    prev = state.nl_i.shape[0] if state.nl_i is not None else 0
    cap = max(64, int(1.25 * prev) + n // 8) if prev else max(16, 8 * n)
    while True:
        pi, pj, ps, m = _find_pairs(state.x, state.radius, np.ascontiguousarray(h, dtype=np.float64),
                                    nba, nbb, binof, float(skin), cap)
        if m <= cap:
            break
        cap = m
    pi, pj, ps = pi[:m], pj[:m], ps[:m]  # views: the capacity is at most ~25 % above m
    ft = None
    if nk > 0:
        ft = np.empty((m, nk))
        # a list not re-ordered since its build is merged; a relabelled one searched per particle
        if not (old and not sort and _carry_history_ordered(oi, oj, osh, oft, k, pi, pj, ps, ft)):
            ft[:] = 0.0
            if old:
                _carry_history(oi, oj, osh, oft, k, pi, pj, ps, ft)
        if nk == 1:
            ft = ft.reshape(m)
    state.nl_i, state.nl_j, state.nl_shift, state.nl_ft = pi, pj, ps, ft
    state.x_ref = state.x.copy()
    state.h_ref = state.h.copy()
    return m
