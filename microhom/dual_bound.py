"""Complementary-energy (dual) lower bound of the stiffness of a contact network, without any
eigenvalue or factorisation (docs/theory.md, section 12).

Without pre-stress the relaxed energy of a Mandel strain ``e`` is (``microhom.kinematics``)

    V/2 e^T C e = min_q 1/2 sum_c (D_c e + B_c q)^T K_c (D_c e + B_c q),

``K_c`` positive semi-definite. For any contact force field ``f`` (``f_c`` in the range of
``K_c``: along the normal on a sliding contact) that is **exactly in equilibrium**,
``sum_c B_c^T f_c = 0`` (every force and moment balance of every particle), the Fenchel inequality
``1/2 d^T K d >= f^T d - 1/2 f^T K^+ f`` summed over the contacts, with ``sum f^T B q = 0``, gives

    V/2 e^T C e >= f^T D e - 1/2 f^T K^+ f.

With ``f = G e`` linear in ``e`` (G: (d C, m)) this is a bound in the Loewner order,
``V C >= G^T D + D^T G - G^T K^+ G``, hence on K and G (positive combinations of quadratic forms
of C). The field is built from the CG iterate ``X`` of the hierarchy: ``G = K (D + B X) + Corr``
with ``B^T Corr = -B^T K (D + B X)`` (the CG residual), so that the gap to the iterate's upper
bound is exactly ``Corr^T K^+ Corr`` (quadratic in the residual).

``Corr`` is found without a global solve by statics, leaf to root: a construction order of the
particles (a seed cluster first, then each particle once it is attached to earlier ones by
contacts whose equilibrium matrix has full row rank: 2 sticking contacts in 2D, 3 with
non-collinear contact points in 3D) is peeled in reverse; each particle's load is carried by its
contacts to earlier particles (the local solve of least ``K^+``-norm), whose reactions load those
particles. The seed's leftover (a dense least-squares solve of its own contacts) is the net
moment that only a cycle around the periodic cell can carry: a few reserved periodic contacts
carry it. Particles that cannot be attached in such an order (counted in ``DualBound``) are
solved by least squares and their leftover shows in the measured equilibrium residual.

``build_equilibrator(asm, clusters=m)`` makes the two-level statics instead (docs/theory.md section
12, "Two-level statics"): boxes of the cell of about ``m`` particles, each carried to its own seed
on its own contacts, after a coarse equilibrium step on the clusters' rigid motions that leaves no
net force or moment on any cluster; the paths to a seed stay inside a cluster, so the statics'
amplification no longer grows with the network.

Pre-stressed networks are outside this bound (the geometric term is not of the form
``B^T K B`` with ``K`` positive semi-definite): :func:`dual_lower_bound` refuses them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from .kinematics import Assembly, rotational_dofs
from .network import _norms
from .results import Result

__all__ = ["DualBound", "Equilibrator", "build_equilibrator", "dual_lower_bound"]

_RANK_TOL = 1e-9       # eigenvalue of the local A K A^T below this fraction of the largest: rank-deficient
_ACCEPT = 1e-4         # a unit joins only if every eigenvalue of its A K A^T is above this fraction (cond <= 1e4)
_U = np.finfo(float).eps
_VALID_RESIDUAL = 1e-9  # relative equilibrium residual above which the field is not taken as balanced
#: contacts per chunk of the dual bound's sums over contacts (gap, ``S``, ``b``, ``L`` and the margins'
#: terms): each chunk's per-contact compliance and products are formed alone, so that no (d C, m)
#: temporary besides ``G``, ``Phi`` and the statics' output exists (issue 26). A network of fewer
#: contacts is one chunk: the very operations of the sums over all contacts, bit for bit
CHUNK = 1 << 18
#: load columns per statics call of the two-level statics in 3D (issue 26: ``r2`` and the peeled
#: forces are this many columns wide; the coarse step's ``f1`` is made in chunks of contacts and
#: not kept beside them, :func:`_coarse_forces`); the one-seed statics and 2D keep their six. Six:
#: fewer columns cost time (a dual bound with a 12-column trial at 1.08e5 spheres, one thread:
#: 5.5-7.0 s with 6, 8.3-8.6 s with 3, 10.1-10.6 s with 2) for 0.1-0.2 GB at 1e6 each column
TWO_COLS = 6


# ---- local statics (numba) ----------------------------------------------------------------------
class _Graph(NamedTuple):
    """The network as the statics kernels read it (C contacts, N particles, d dimensions, nl = d +
    rotations unknowns per particle): per particle its contact slots ``ptr`` (N + 1,) into
    ``adj_e`` (contact), ``adj_s`` (0 if the particle is the contact's first end, 1 if the second)
    and ``adj_q`` (the other end) (2 C,); ``usable`` (C,) bool; ``pdof`` (N, nl) the global unknown
    of each particle's component (-1: eliminated); ``pairs`` (C, 2); ``B`` (C, d, 2 nl) the contact
    kinematics; per contact the force basis ``Q`` (C, d, d), its size ``nk`` (C,) and the stiffness
    in it ``Kq`` (C, d, d); ``nl``."""
    ptr: np.ndarray
    adj_e: np.ndarray
    adj_s: np.ndarray
    adj_q: np.ndarray
    usable: np.ndarray
    pdof: np.ndarray
    pairs: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    nk: np.ndarray
    Kq: np.ndarray
    nl: int


class _Order(NamedTuple):
    """The construction order being built (N particles): ``idx`` (N,) each particle's unit
    position (``BIG``: not built), ``cnt`` (N,) force unknowns to built particles, ``slot`` (N,)
    scratch (-1), the breadth-first ``queue`` (N,), the units' ``members`` (N,) and ``uptr``
    (N + 1,), and the counters ``st`` = (head, tail, nm, nu, pos)."""
    idx: np.ndarray
    cnt: np.ndarray
    slot: np.ndarray
    queue: np.ndarray
    members: np.ndarray
    uptr: np.ndarray
    st: np.ndarray


class _Tree(NamedTuple):
    """The units' local operators (construction order): parent contacts ``pe[pptr[a]:pptr[a+1]]``,
    unknowns ``rdof[rptr[a]:rptr[a+1]]`` and the flat operator ``Y[yptr[a]:yptr[a+1]]`` of unit a."""
    pptr: np.ndarray
    pe: np.ndarray
    rptr: np.ndarray
    rdof: np.ndarray
    yptr: np.ndarray
    Y: np.ndarray


@numba.njit(cache=True)
def _joins(t, slot, idx, before, g):
    """Is the contact at adjacency slot ``t`` one of the unit's (members marked in ``slot``): usable,
    to a particle built before (``idx < before``) or to another member (counted from its first end)?"""
    e, q = g.adj_e[t], g.adj_q[t]
    return g.usable[e] and ((slot[q] >= 0 and g.adj_s[t] == 0) or (slot[q] < 0 and idx[q] < before))


@numba.njit(cache=True)
def _unit_local(mem, slot, idx, before, g):
    """Equilibrium matrix ``A`` (rows, cols) of the unit ``mem`` (one or two particles, marked in
    ``slot``) on its usable contacts to particles with ``idx < before`` and between its members,
    in the force unknowns of each contact (:class:`_Graph` ``g``); the block-diagonal stiffness
    ``Kl`` of those unknowns, the contacts and the unknowns (rows) of the unit."""
    ptr, adj_e, adj_s, adj_q, usable, pdof, pairs, B, Q, nk, Kq, nl = g
    d = B.shape[1]
    nrow = 0
    rowof = np.full((mem.shape[0], nl), -1, np.int64)
    rdof = np.empty(mem.shape[0] * nl, np.int64)
    for u in range(mem.shape[0]):
        for k in range(nl):
            if pdof[mem[u], k] >= 0:
                rowof[u, k] = nrow
                rdof[nrow] = pdof[mem[u], k]
                nrow += 1
    deg = 0
    for u in range(mem.shape[0]):
        deg += ptr[mem[u] + 1] - ptr[mem[u]]
    es = np.empty(deg, np.int64)        # at most every contact of the unit; trimmed below
    ncol = 0
    ne = 0
    for u in range(mem.shape[0]):
        p = mem[u]
        for t in range(ptr[p], ptr[p + 1]):
            e = adj_e[t]
            if _joins(t, slot, idx, before, g):
                es[ne] = e
                ne += 1
                ncol += nk[e]
    es = es[:ne]
    A = np.zeros((nrow, ncol))
    Kl = np.zeros((ncol, ncol))
    col = 0
    for a in range(ne):
        e = es[a]
        m = nk[e]
        for side in range(2):
            x = pairs[e, side]
            if slot[x] < 0:
                continue
            for k in range(nl):
                r = rowof[slot[x], k]
                if r < 0:
                    continue
                for b in range(m):
                    v = 0.0
                    for y in range(d):
                        v += B[e, y, side * nl + k] * Q[e, y, b]
                    A[r, col + b] += v
        for b in range(m):
            for b2 in range(m):
                Kl[col + b, col + b2] = Kq[e, b, b2]
        col += m
    return A, Kl, es, rdof[:nrow]


@numba.njit(cache=True)
def _operator(A, Kl):
    """``Y = Kl A^T (A Kl A^T)^+`` (least ``K^+``-norm forces carrying a load) and the rank."""
    neq = A.shape[0]
    if A.shape[1] == 0 or neq == 0:
        return np.zeros((A.shape[1], neq)), 0
    KA = Kl @ A.T
    M = A @ KA
    M = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(M)
    top = w.max()
    rank = 0
    Winv = np.zeros(neq)
    for i in range(neq):
        if top > 0 and w[i] > _RANK_TOL * top:
            Winv[i] = 1.0 / w[i]
            rank += 1
    Minv = (V * Winv) @ V.T
    return KA @ Minv, rank


@numba.njit(cache=True)
def _unit_gram(mem, slot, idx, before, g):
    """The symmetric part of ``A Kl A^T`` (nrow, nrow) of :func:`_unit_local`'s unit (members in ``slot``),
    summed contact by contact without forming ``A`` (its rounding differs from the product's: only
    for the clear decisions of :func:`_clear_accept`), and the number of force unknowns ``ncol``."""
    ptr, adj_e, adj_s, adj_q, usable, pdof, pairs, B, Q, nk, Kq, nl = g
    d = B.shape[1]
    nrow = 0
    rowof = np.full((mem.shape[0], nl), -1, np.int64)
    for u in range(mem.shape[0]):
        for k in range(nl):
            if pdof[mem[u], k] >= 0:
                rowof[u, k] = nrow
                nrow += 1
    M = np.zeros((nrow, nrow))
    a = np.zeros((2 * nl, d))        # one contact's nonzero rows of A (at most two members')
    ak = np.zeros((2 * nl, d))       # and of A Kq
    rows = np.empty(2 * nl, np.int64)
    ncol = 0
    for u in range(mem.shape[0]):
        for t in range(ptr[mem[u]], ptr[mem[u] + 1]):
            e = adj_e[t]
            if not _joins(t, slot, idx, before, g):
                continue
            m = nk[e]
            ncol += m
            nr = 0
            for side in range(2):
                x = pairs[e, side]
                for k in range(nl if slot[x] >= 0 else 0):
                    if rowof[slot[x], k] < 0:
                        continue
                    rows[nr] = rowof[slot[x], k]
                    for b in range(m):
                        a[nr, b] = 0.0
                        for y in range(d):
                            a[nr, b] += B[e, y, side * nl + k] * Q[e, y, b]
                    nr += 1
            for i in range(nr):
                for b in range(m):
                    ak[i, b] = 0.0
                    for b2 in range(m):
                        ak[i, b] += a[i, b2] * Kq[e, b2, b]
            for i in range(nr):
                for j in range(nr):
                    for b in range(m):
                        M[rows[i], rows[j]] += ak[i, b] * a[j, b]
    return 0.5 * (M + M.T), ncol


@numba.njit(cache=True)
def _short(mem, slot, idx, before, g):
    """Is the unit's ``A`` (:func:`_unit_local`) surely short of full row rank by counting? A member
    with fewer force components on the unit's contacts than unknowns moves alone without meeting
    any; in 3D a particle with all its six unknowns and two contacts turns alone about the line
    through the two contact points."""
    ptr, adj_e, adj_s, adj_q, usable, pdof, pairs, B, Q, nk, Kq, nl = g
    n = mem.shape[0]
    comps = np.zeros(n, np.int64)
    cnt = np.zeros(n, np.int64)
    for u in range(n):
        for t in range(ptr[mem[u]], ptr[mem[u] + 1]):
            e, q = adj_e[t], adj_q[t]
            if not _joins(t, slot, idx, before, g):
                continue
            comps[u] += nk[e]
            cnt[u] += 1
            if slot[q] >= 0:
                comps[slot[q]] += nk[e]
                cnt[slot[q]] += 1
    for u in range(n):
        rows = 0
        for k in range(nl):
            rows += pdof[mem[u], k] >= 0
        if comps[u] < rows or (B.shape[1] == 3 and nl == 6 and rows == 6 and cnt[u] < 3):
            return True
    return False


@numba.njit(cache=True)
def _chol_ok(M, shift):
    """Does the Cholesky factorisation of ``M - shift I`` (n, n) meet only positive pivots?"""
    n = M.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = M[j, j] - shift
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            v = 0.5 * (M[i, j] + M[j, i])
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    return True


@numba.njit(cache=True)
def _clear_accept(M):
    """The test ``w_min > _ACCEPT w_max`` on the symmetric positive semi-definite ``M`` when it is
    clear by a factor 2 (1: passes, 0: fails), else -1 (decide by the eigenvalues). With ``U`` the
    largest absolute row sum (>= w_max) and ``L`` the largest diagonal entry (<= w_max, >= U / n):
    ``M - 2 _ACCEPT U I`` positive definite means ``w_min > 2 _ACCEPT w_max``; ``M - _ACCEPT L / 2 I``
    not, ``w_min < _ACCEPT w_max / 2``. Rounding (about ``n eps U``, far below ``_ACCEPT L``) can
    blur neither, nor the eigenvalue solver's (same order) the exact test's answer there."""
    n = M.shape[0]
    U, L = 0.0, 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += abs(M[i, j])
        U, L = max(U, s), max(L, M[i, i])
    if not L > 0.0:
        return -1
    if _chol_ok(M, 2.0 * _ACCEPT * U):
        return 1
    if not _chol_ok(M, 0.5 * _ACCEPT * L):
        return 0
    return -1


@numba.njit(cache=True)
def _try_unit(mem, slot, idx, before, g):
    """Does the unit carry any load on its contacts to the built particles (full row rank; every
    eigenvalue of ``A Kl A^T`` above ``_ACCEPT`` times the largest)? Units short by counting
    (:func:`_short`) fail at once; clear cases are decided on the Gram matrix by
    :func:`_clear_accept`, the rest by the eigenvalues of the product."""
    for u in range(mem.shape[0]):
        slot[mem[u]] = u
    if _short(mem, slot, idx, before, g):
        for u in range(mem.shape[0]):
            slot[mem[u]] = -1
        return False
    M, ncol = _unit_gram(mem, slot, idx, before, g)
    clear = -1 if M.shape[0] == 0 or ncol < M.shape[0] else _clear_accept(M)
    if clear < 0 and M.shape[0] > 0 and ncol >= M.shape[0]:
        A, Kl, _, _ = _unit_local(mem, slot, idx, before, g)
        P = A @ Kl @ A.T
        w = np.linalg.eigvalsh(0.5 * (P + P.T))
        clear = 1 if w[0] > _ACCEPT * w[-1] else 0
    for u in range(mem.shape[0]):
        slot[mem[u]] = -1
    return clear == 1


@numba.njit(cache=True)
def _attach(mem, o):
    """Join the unit ``mem`` at the next position of the :class:`_Order` ``o`` (its counters
    ``st`` updated)."""
    st = o.st
    for x in mem:
        o.idx[x] = st[4]
        o.queue[st[1]] = x
        st[1] += 1
        o.members[st[2]] = x
        st[2] += 1
    st[3] += 1
    o.uptr[st[3]] = st[2]
    st[4] += 1


@numba.njit(cache=True)
def _grow(q, kmax, o, regular, g):
    """A unit of up to ``kmax`` unbuilt particles around ``q`` (each step the unbuilt neighbour with
    the most contacts to the built set) that carries any load; empty if none does."""
    BIG = 1 << 60
    idx, cnt = o.idx, o.cnt
    ptr, adj_e, adj_q, usable = g.ptr, g.adj_e, g.adj_q, g.usable
    mem = np.empty(kmax, np.int64)
    mem[0] = q
    m = 1
    while m < kmax:
        best, bc = -1, -1
        for u in range(m):
            p = mem[u]
            for t in range(ptr[p], ptr[p + 1]):
                r = adj_q[t]
                if not usable[adj_e[t]] or idx[r] < BIG or not regular[r] or cnt[r] <= bc:
                    continue
                dup = False
                for v in range(m):
                    dup = dup or mem[v] == r
                if not dup:
                    best, bc = r, cnt[r]
        if best < 0:
            break
        mem[m] = best
        m += 1
        if _try_unit(mem[:m], o.slot, idx, BIG, g):
            return mem[:m].copy()
    return mem[:0].copy()


@numba.njit(cache=True)
def _drain(o, regular, neq, g):
    """Breadth-first growth of the :class:`_Order` ``o`` by single particles."""
    BIG = 1 << 60
    st, idx, cnt = o.st, o.idx, o.cnt
    ptr, adj_e, adj_q, usable, nk = g.ptr, g.adj_e, g.adj_q, g.usable, g.nk
    one = np.empty(1, np.int64)
    while st[0] < st[1]:
        p = o.queue[st[0]]
        st[0] += 1
        for t in range(ptr[p], ptr[p + 1]):
            q = adj_q[t]
            e = adj_e[t]
            if not usable[e] or idx[q] < BIG or not regular[q]:
                continue
            cnt[q] += nk[e]
            if cnt[q] < neq[q]:
                continue
            one[0] = q
            if _try_unit(one, o.slot, idx, BIG, g):
                _attach(one, o)


@numba.njit(cache=True)
def _bootstrap(seed, regular, neq, g, kmax, lazy=False):
    """Construction order from the seed: a regular particle joins once its usable contacts to the
    particles already in carry any load (full row rank), or, failing that, together with unbuilt
    neighbours as one unit of up to ``kmax`` particles (in 3D two contacts leave a sphere a twist
    about the line of its contact points, which a contact to a neighbour resists). ``lazy``: a
    particle whose unit failed is tried again only once its contacts to the built particles
    changed (the two-level statics' many cluster boundaries). Returns ``idx``
    (N,): 0 for the seed, 1.. the unit's position, ``BIG`` for particles that never joined; and
    the units' members in order (``members``, ``uptr``)."""
    N = neq.shape[0]
    BIG = 1 << 60
    o = _Order(np.full(N, BIG, np.int64), np.zeros(N, np.int64), np.full(N, -1, np.int64),
               np.empty(N, np.int64), np.empty(N, np.int64), np.zeros(N + 1, np.int64),
               np.zeros(5, np.int64))
    tail = 0
    for p in seed:
        o.idx[p] = 0
        o.queue[tail] = p
        tail += 1
    o.st[1] = tail
    o.st[4] = 1                 # st = (head, tail, nm, nu, pos)
    tried = np.full(N, -1, np.int64)
    while True:
        _drain(o, regular, neq, g)
        progressed = False      # stalled: units of several particles on the frontier, pass by pass
        for q in range(N):
            if o.idx[q] < BIG or not regular[q] or o.cnt[q] == 0 or (lazy and tried[q] == o.cnt[q]):
                continue
            mem = _grow(q, kmax, o, regular, g)
            if mem.shape[0]:
                _attach(mem, o)
                progressed = True
                _drain(o, regular, neq, g)
            else:
                tried[q] = o.cnt[q]
        if not progressed:
            break
    nm, nu = o.st[2], o.st[3]
    return o.idx, o.members[:nm], o.uptr[:nu + 1]


@numba.njit(cache=True)
def _operators(members, uptr, idx, g):
    """Per unit (construction order): its parent contacts (to earlier units, and between its
    members), its unknowns, the flat operator ``Y`` (a :class:`_Tree`) and its rank deficit."""
    n = uptr.shape[0] - 1
    N = idx.shape[0]
    slot = np.full(N, -1, np.int64)
    pptr = np.zeros(n + 1, np.int64)
    rptr = np.zeros(n + 1, np.int64)
    yptr = np.zeros(n + 1, np.int64)
    es_l, rd_l, y_l = numba.typed.List(), numba.typed.List(), numba.typed.List()
    deficit = np.zeros(n, np.int64)
    for a in range(n):          # one local solve per unit, kept until the sizes are known
        mem = members[uptr[a]:uptr[a + 1]]
        for u in range(mem.shape[0]):
            slot[mem[u]] = u
        A, Kl, es, rd = _unit_local(mem, slot, idx, idx[mem[0]], g)
        for u in range(mem.shape[0]):
            slot[mem[u]] = -1
        Yp, rank = _operator(A, Kl)
        deficit[a] = rd.shape[0] - rank
        es_l.append(es)
        rd_l.append(rd)
        y_l.append(Yp.ravel().copy())
        pptr[a + 1] = pptr[a] + es.shape[0]
        rptr[a + 1] = rptr[a] + rd.shape[0]
        yptr[a + 1] = yptr[a] + y_l[a].shape[0]
    pe = np.empty(pptr[n], np.int64)
    rdof = np.empty(rptr[n], np.int64)
    Y = np.empty(yptr[n])
    for a in range(n):
        pe[pptr[a]:pptr[a + 1]] = es_l[a]
        rdof[rptr[a]:rptr[a + 1]] = rd_l[a]
        Y[yptr[a]:yptr[a + 1]] = y_l[a]
    return _Tree(pptr, pe, rptr, rdof, yptr, Y), deficit


@numba.njit(cache=True)
def _peel(load, c, tree, g, rows, a0, a1):
    """Leaf to root: each unit ``a0 <= a < a1`` of the :class:`_Tree` ``tree`` (reversed
    construction order) hands its load to its parent contacts (``c`` += forces, (C, d, s)); the
    reactions ``B_e^T f`` load the other ends (:class:`_Graph` ``g`` for the force bases). ``rows``:
    the assembly's ``Bs`` (d C, ndof) as CSR arrays (indptr, indices, data), row ``d e + x`` the
    component ``x`` of contact ``e`` (:func:`_bs_rows`; the same numbers as ``g.B``, which the
    statics then need not keep: 288 bytes per contact in 3D). ``load`` (ndof, s) keeps what is
    left (round-off where the local solve has full rank)."""
    pptr, pe, rptr, rdof, yptr, Y = tree
    Q, nk, nl = g.Q, g.nk, g.nl
    indptr, indices, data = rows
    d = Q.shape[1]
    s = load.shape[1]
    v = np.empty((2 * nl, s))
    for a in range(a1 - 1, a0 - 1, -1):
        m = rptr[a + 1] - rptr[a]
        ncol = (yptr[a + 1] - yptr[a]) // max(m, 1)
        if ncol == 0 or m == 0:
            continue
        lp = np.empty((m, s))
        for r in range(m):
            for j in range(s):
                lp[r, j] = load[rdof[rptr[a] + r], j]
        y = Y[yptr[a]:yptr[a + 1]].reshape(ncol, m) @ lp
        col = 0
        f = np.zeros((d, s))
        for t in range(pptr[a], pptr[a + 1]):
            e = pe[t]
            f[:] = 0.0
            for b in range(nk[e]):
                for x in range(d):
                    for j in range(s):
                        f[x, j] += Q[e, x, b] * y[col + b, j]
            col += nk[e]
            for x in range(d):
                for j in range(s):
                    c[e, x, j] += f[x, j]
            # the rows of one contact hold the same unknowns in the same order: v = B_e^T f summed
            # over x in order, as from the dense B_e
            r0 = indptr[d * e]
            n = indptr[d * e + 1] - r0
            v[:n] = 0.0
            for x in range(d):
                rx = indptr[d * e + x]
                for p in range(n):
                    val = data[rx + p]
                    for j in range(s):
                        v[p, j] += val * f[x, j]
            for p in range(n):
                u = indices[r0 + p]
                for j in range(s):
                    load[u, j] -= v[p, j]


# ---- the equilibrator ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Equilibrator:
    """A right inverse of the equilibrium operator ``B^T`` of a network, by statics (module
    docstring): ``correct(r)`` returns contact forces ``c`` (C, d, s) [N] with ``B^T c = r`` (the
    loads ``r`` (ndof, s) [N, N m] in the assembly's unknowns) up to round-off, each ``c_c`` in the
    range of ``K_c``.

    Attributes
    ----------
    n_seed : int
        Particles of the seed cluster (solved together by dense least squares).
    n_attached : int
        Particles attached in the construction order with a full-rank local solve.
    n_stalled : int
        Particles with a full-rank contact set that the order could not attach: solved together,
        as one sparse block on their contacts (``block_solved``).
    n_deficient : int
        Particles whose contacts cannot carry every load (e.g. a two-contact sphere): peeled
        first, by least squares (consistent: the load of a network's residual has no component on
        their local mechanism).
    n_reserved : int
        Contacts reserved to carry the seed's net moment (across the periodic boundary and at random).
    block_solved : bool
        The stalled particles were solved together (a sparse factorisation of their own system,
        up to ``block_max`` unknowns); False: they were not, and the field is not in equilibrium.
    setup_time : float
        Wall time of the construction [s].
    n_clusters : int
        Clusters of the two-level statics (``build_equilibrator(clusters=...)``), 0 for the
        one-seed statics; there ``n_seed`` counts the seeds' particles, ``n_attached`` the
        particles attached in their cluster, ``n_stalled`` those that are a cluster of their own.
    _data : dict
        The construction's arrays (order, local operators, seed, block, reserved cycles): internal.
    """

    n_seed: int
    n_attached: int
    n_stalled: int
    n_deficient: int
    n_reserved: int
    block_solved: bool
    setup_time: float
    _data: dict = field(repr=False)
    n_clusters: int = 0

    @property
    def group(self) -> int:
        """The number of load columns per statics call (``TWO_COLS`` for the two-level statics in
        3D, else 6)."""
        return TWO_COLS if self._data.get("two") is not None and self._data["d"] == 3 else 6

    def correct(self, r: np.ndarray, chunk: int | None = None, own: bool = False) -> np.ndarray:
        """Forces ``c`` (C, d, s) with ``B^T c = r`` for loads ``r`` (ndof, s) in the range of
        ``B^T`` (orthogonal to the rigid translations), ``chunk`` (default :attr:`group`) columns
        at a time (a column's numbers depend on it only at round-off: the coarse factor's solve and
        the peeling's small products round differently for other column counts). ``own``: ``r`` is
        a float64 temporary the caller gives up (the two-level statics works in it: one (ndof, s)
        array fewer; the same numbers)."""
        r = np.asarray(r, dtype=float)
        chunk = self.group if chunk is None else chunk
        one = r.ndim == 1
        r = r[:, None] if one else r
        if r.shape[1] <= chunk and r.shape[1]:   # one chunk: no copy (issue 26: 0.5 GB at 1e6)
            out = self._correct(r, own)
        else:           # filled chunk by chunk (no list of chunks beside a concatenated copy)
            out = np.empty((self._data["C"], self._data["d"], r.shape[1]))
            for a in range(0, r.shape[1], chunk):
                out[:, :, a:a + chunk] = self._correct(r[:, a:a + chunk], own)
        return out[:, :, 0] if one else out

    def _correct(self, r, own=False):
        D = self._data
        if D.get("two") is not None:
            return self._two_level(r, own)
        c, left = self._tree(r)
        if D["Lres"] is not None:       # the seed's leftover (net moment): the reserved cycles
            # c = T(r) + sum_u alpha_u (u - T(B^T u)), B^T (u - T(B^T u)) = Lres[:, u] on the seed
            alpha = D["Lres_pinv"] @ left[D["seed_dofs"]]
            c2, _ = self._tree(D["BtU"] @ alpha)
            c -= c2
            for t, e in enumerate(D["res_e"]):
                c[e] += D["Ures"][t] @ alpha[D["res_cols"][t]]
        return c

    def _two_level(self, r, own=False):
        """The coarse step ``c1 = K B R y``, ``R^T H R y = R^T r``, then each cluster's statics
        on ``r - B^T c1`` (no net force or moment on any cluster; docs/theory.md section 12).
        ``own``: ``r`` is the caller's temporary, ``r - B^T c1`` is formed in it."""
        T = self._data["two"]
        s = r.shape[1]
        y = T["solve"](np.asarray(T["R"].T @ r))
        f1 = np.empty((T["Bs"].shape[0], s))
        _coarse_forces(T, np.asarray(T["R"] @ y), f1)
        if own:
            r -= np.asarray(T["Bs"].T @ f1)        # the same numbers as r - B^T f1
            r2 = r
        else:
            r2 = r - np.asarray(T["Bs"].T @ f1)
        # f1 and R y are not kept beside the peeled forces: recomputed below (issue 26)
        del f1, r
        c, _ = Equilibrator(0, 0, 0, 0, 0, True, 0.0, T["local"])._tree(r2, own=True)
        del r2
        _coarse_forces(T, np.asarray(T["R"] @ y), c.reshape(-1, s), add=True)    # c += f1, in place
        return c

    def _tree(self, r, own=False):
        """Forces ``c`` (C, d, s) carrying ``r`` (ndof, s) by the construction order, and the load
        left on the seed. ``own``: ``r`` is a temporary the caller gives up (worked on in place,
        without a copy)."""
        D = self._data
        load = np.ascontiguousarray(r, dtype=float) if own else np.array(r, dtype=float, order="C", copy=True)
        c = np.zeros((D["C"], D["d"], r.shape[1]))
        if D["block"] is not None:        # the particles the order could not attach: one sparse solve
            A, AS, KAT, lu, be, bcols = D["block"]
            rhs = np.ascontiguousarray(load[D["block_dofs"]])
            z = lu.solve(rhs)
            for _ in range(3):           # iterative refinement: the factor is of M + 1e-13 max|M| I
                z += lu.solve(rhs - AS @ (KAT @ z))
            y = KAT @ z
            f = np.zeros((len(be), D["d"], r.shape[1]))
            for b in range(D["d"]):
                ok = bcols[:, b] >= 0
                f[ok] += D["Q"][be[ok], :, b][:, :, None] * y[bcols[ok, b]][:, None, :]
            np.add.at(c, be, f)
            load -= A @ y
        _peel(load, c, D["tree"], D["graph"], D["rows"], 0, D["n_tree"])
        if D["seed_Y"] is not None and len(D["seed_e"]):   # the seed: dense least squares on its contacts
            ls = load[D["seed_dofs"]]
            y = D["seed_Y"] @ ls
            f = np.einsum("uxb,ubs->uxs", D["seed_Q"], y.reshape(len(D["seed_e"]), D["d"], -1))
            np.add.at(c, D["seed_e"], f)
            load[D["seed_dofs"]] -= D["seed_A"] @ y
        return c, load


def _force_basis(asm: Assembly):
    """(C, d, d) basis ``Q`` of each contact's admissible forces (identity; the normal alone on a
    sliding contact), ``nk`` (C,) its size and ``Kq`` (C, d, d) the stiffness in that basis."""
    net, K = asm.net, asm.matrices.K
    C, d = K.shape[0], K.shape[1]
    stick = net.effective_kt > 0
    n = net.normals
    Q = np.zeros((C, d, d))
    Q[stick] = np.eye(d)
    Q[~stick, :, 0] = n[~stick]
    nk = np.where(stick, d, 1).astype(np.int64)
    Kq = np.zeros((C, d, d))
    Kq[stick] = K[stick]
    Kq[~stick, 0, 0] = (np.asarray(net.kn, float) * np.ones(C))[~stick]
    return Q, nk, Kq


def _bs_rows(asm: Assembly):
    """The assembly's ``Bs`` as the CSR arrays :func:`_peel` reads (no copy of a CSR ``Bs``)."""
    return _csr(asm.Bs)


def _particle_dofs(asm: Assembly):
    N, d = asm.net.n_particles, asm.net.dim
    rot = rotational_dofs(d)
    pdof = np.full((N, d + rot), -1, np.int64)
    for a in range(d):
        pdof[:, a] = asm.dof_map[a:d * N:d]
    for b in range(rot):
        pdof[:, d + b] = asm.dof_map[d * N + b::rot]
    return pdof


def _adjacency(pairs, N):
    C = pairs.shape[0]
    ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
    e = np.concatenate([np.arange(C), np.arange(C)])
    side = np.concatenate([np.zeros(C, np.int64), np.ones(C, np.int64)])
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    o = np.argsort(ends, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(ends, minlength=N))]).astype(np.int64)
    return ptr, e[o].astype(np.int64), side[o], other[o].astype(np.int64)


def _ball(start, target, ptr, adj_q, regular):
    """Breadth-first ball of ``target`` regular particles around ``start``."""
    seen = {int(start)}
    ball, front = [int(start)], [int(start)]
    while front and len(ball) < target:
        nxt = []
        for p in front:
            for q in adj_q[ptr[p]:ptr[p + 1]]:
                q = int(q)
                if q not in seen and regular[q]:
                    seen.add(q)
                    nxt.append(q)
        ball.extend(nxt)
        front = nxt
    return ball[:target]


def _seed_matrix(seed, g):
    """Equilibrium matrix of the seed on its internal contacts (rows: the seed's unknowns)."""
    usable, pdof, pairs, B, Q, Kq, nl = g.usable, g.pdof, g.pairs, g.B, g.Q, g.Kq, g.nl
    d = B.shape[1]
    seed = np.asarray(seed, dtype=np.int64)
    inc = np.concatenate([g.adj_e[g.ptr[p]:g.ptr[p + 1]] for p in seed]) if len(seed) else np.zeros(0, np.int64)
    inc = np.unique(inc)          # the seed's contacts (through the adjacency: O(its degree))
    inc = inc[usable[inc]]
    se = inc[np.isin(pairs[inc, 0], seed) & np.isin(pairs[inc, 1], seed)]
    sd = pdof[seed].ravel()
    sd = sd[sd >= 0]
    srt = np.argsort(sd)
    A = np.zeros((len(sd), d * len(se)))
    cols = d * np.arange(len(se))[:, None] + np.arange(d)[None, :]
    for side in range(2):
        for k in range(nl):
            gk = pdof[pairs[se, side], k]
            ok = gk >= 0
            rows = srt[np.searchsorted(sd, gk[ok], sorter=srt)]
            v = np.einsum("cx,cxb->cb", B[se[ok], :, side * nl + k], Q[se[ok]])   # Q's columns past nk are 0
            np.add.at(A, (rows[:, None], cols[ok]), v)
    Kl = np.zeros((d * len(se), d * len(se)))
    for a, e in enumerate(se):
        Kl[d * a:d * a + d, d * a:d * a + d] = Kq[e]
    return A, Kl, se, sd


@numba.njit(cache=True)
def _inside(b, g):
    """Per member of the ball ``b`` (n,) its usable contacts inside the ball (a contact with its own
    image once) and their force components, each (n,); from the members' adjacency only (O(the
    ball's degree log n), not O(all contacts))."""
    n = b.shape[0]
    srt = np.argsort(b, kind="mergesort")
    sb = b[srt]
    inner = np.zeros(n, np.int64)
    comps = np.zeros(n, np.int64)
    for u in range(n):
        for t in range(g.ptr[b[u]], g.ptr[b[u] + 1]):
            e, q = g.adj_e[t], g.adj_q[t]
            if not g.usable[e] or (q == b[u] and g.adj_s[t] == 1):
                continue
            k = np.searchsorted(sb, q)
            if k < n and sb[k] == q:
                inner[u] += 1
                comps[u] += g.nk[e]
    return inner, comps


def _trimmed(ball, g, rigid):
    """The list ``ball`` of particles trimmed (the one with the fewest usable contacts inside
    first) until its internal contacts carry every self-equilibrated load (rank = unknowns -
    ``rigid``); None if no ball of two or more particles does. The rank is computed only where
    every member has at least as many force components inside as unknowns: otherwise a motion of
    that member alone meets no internal force, and it is not a rigid motion of the ball when every
    member has all its ``nl`` unknowns (rigid motions move each member's translations or
    rotations), so the rank falls short anyway (where some unknown is eliminated: always computed).
    Likewise in 3D a sphere with two contacts inside: its rotation about the line through the two
    contact points moves neither."""
    d = g.B.shape[1]
    full = bool((g.pdof[np.asarray(ball, dtype=np.int64)] >= 0).all()) and g.nl > d
    while len(ball) >= 2:
        b = np.array(ball, dtype=np.int64)
        inner, comps = _inside(b, g)
        if not full or ((comps >= g.nl).all() and (d == 2 or (inner >= 3).all())):
            A, Kl, se, sd = _seed_matrix(b, g)
            if len(se):
                w = np.linalg.eigvalsh(A @ Kl @ A.T)
                if int((w > _RANK_TOL * w.max()).sum()) == len(sd) - rigid:
                    return b
        ball.pop(int(np.argmin(inner)))
    return None


def _seed(deg, target, g, regular, tries=20):
    """A rigid seed cluster: a ball around a well-connected particle, trimmed (the particle with
    the fewest contacts inside first) until its internal contacts carry every self-equilibrated
    load (rank = unknowns - rigid motions)."""
    ptr, adj_q = g.ptr, g.adj_q
    d = g.B.shape[1]
    rigid = d + rotational_dofs(d)
    cand = np.argsort(-np.where(regular, deg, -1), kind="stable")[:tries]
    for start in cand:
        ball = _trimmed(_ball(start, target, ptr, adj_q, regular), g, rigid)
        if ball is not None:
            return ball
    # none: a single particle (no internal contact; its whole load is left, carried by the cycles)
    return np.array(cand[:1], dtype=np.int64)


def _reserve(asm, usable, stick, per_axis=4, n_random=8, seed=0):
    """Sticking contacts kept out of the construction, carriers of the seed's net moment: up to
    ``per_axis`` crossing each periodic direction (a cycle around the cell) and ``n_random``
    others at random (where the construction already routes around the cell)."""
    sh = asm.net.image_shifts()
    ok = stick & usable & (asm.net.pairs[:, 0] != asm.net.pairs[:, 1])
    res = []
    for ax in range(asm.net.dim):
        cand = np.flatnonzero((sh[:, ax] != 0) & ok)
        res.extend(cand[:: max(1, len(cand) // per_axis)][:per_axis].tolist())
    cand = np.flatnonzero(ok)
    if len(cand):
        res.extend(np.random.default_rng(seed).choice(cand, min(n_random, len(cand)), replace=False).tolist())
    return np.array(sorted(set(res)), dtype=np.int64)


def build_equilibrator(asm: Assembly, seed_size=None, block_max: int = 300_000,
                       clusters: int | None = None) -> Equilibrator:
    """The statics of ``asm`` (module docstring): construction order, local operators, seed and
    reserved contacts. O(C) time and memory. ``clusters``: None (default: one seed for the whole
    network) or the number of particles per cluster of the two-level statics (an integer >= 8;
    docs/theory.md section 12, "Two-level statics"): clusters of about that size, each carried
    to its own seed, after a coarse equilibrium step on the clusters' rigid motions; a cell too
    small for ``2^d`` clusters of that size gets the one-seed statics. Raises ``ValueError`` for
    another ``clusters``."""
    if clusters is not None and (isinstance(clusters, bool) or not isinstance(clusters, (int, np.integer))
                                 or clusters < 8):
        raise ValueError(f"clusters must be None or an integer >= 8 (particles per cluster), got {clusters!r}")
    t0 = time.perf_counter()
    net = asm.net
    N, d, C = net.n_particles, net.dim, net.n_contacts
    nl = d + rotational_dofs(d)
    pairs = np.ascontiguousarray(net.pairs, dtype=np.int64)
    B = np.ascontiguousarray(asm.matrices.B)
    Q, nk, Kq = _force_basis(asm)
    pdof = _particle_dofs(asm)
    neq = (pdof >= 0).sum(axis=1)
    ptr, adj_e, adj_s, adj_q = _adjacency(pairs, N)
    stick = net.effective_kt > 0
    usable = pairs[:, 0] != pairs[:, 1]                 # a particle touching its own image: unused
    g = _Graph(ptr, adj_e, adj_s, adj_q, usable, pdof, pairs, B, Q, nk, Kq, nl)
    regular = _regular(neq, g)
    if clusters is not None:
        two = _two_level(asm, g, neq, int(clusters), regular)
        if two is not None:
            st = two["stats"]
            return Equilibrator(n_seed=st["n_seed"], n_attached=st["n_attached"], n_stalled=st["n_alone"],
                                n_deficient=int((~regular & (neq > 0)).sum()), n_reserved=0, block_solved=True,
                                setup_time=time.perf_counter() - t0, _data=dict(C=C, d=d, two=two),
                                n_clusters=st["n_clusters"])
    reserved = _reserve(asm, usable, stick & regular[pairs[:, 0]] & regular[pairs[:, 1]])
    usable[reserved] = False
    regular2 = _regular(neq, g)
    back = reserved[~(regular2[pairs[reserved, 0]] & regular2[pairs[reserved, 1]])]
    if len(back):                 # a reservation must not leave a particle unable to carry its load
        usable[back] = True
        reserved = np.setdiff1d(reserved, back)
        regular2 = _regular(neq, g)
    regular = regular2
    deg = np.bincount(pairs[usable].ravel(), minlength=N)
    seed = _seed(deg, seed_size or (12 if d == 2 else 30), g, regular)
    idx, members, uptr = _bootstrap(seed, regular, neq, g, 16)
    BIG = 1 << 60
    live = neq > 0
    stalled = np.flatnonzero(live & (idx == BIG) & regular)
    deficient = np.flatnonzero(live & ~regular)
    n_tree = len(uptr) - 1
    idx[stalled] = n_tree + 1        # one block after every attached unit: the stalled and deficient
    idx[deficient] = n_tree + 1      # particles (its load is the network's own: consistent)
    tree, deficit = _operators(members, uptr, idx, g)
    data = dict(C=C, d=d, nl=nl, pairs=pairs, B=B, Q=Q, nk=nk, pdof=pdof, graph=g, rows=_bs_rows(asm), tree=tree,
                seed_Y=None, Lres=None, n_tree=n_tree, block=None)
    resolved = _block(data, asm, np.concatenate([stalled, deficient]), idx, usable, Kq, block_max)
    _seed_solve(data, seed)
    _reserved_fields(data, asm, reserved)
    return Equilibrator(n_seed=len(seed), n_attached=int(uptr[n_tree]), n_stalled=len(stalled),
                        n_deficient=len(deficient), n_reserved=len(reserved), block_solved=resolved,
                        setup_time=time.perf_counter() - t0, _data=data)


def _block(data, asm, stalled, idx, usable, Kq, block_max):
    """Sparse least-``K^+``-norm solve of the particles the order could not attach, on their
    contacts to the attached particles and between them (peeled after the deficient particles,
    before the tree). Returns whether it was made (False above ``block_max`` unknowns)."""
    if not len(stalled):
        return True
    pdof, pairs, d, nl, nk, B, Q = (data[k] for k in ("pdof", "pairs", "d", "nl", "nk", "B", "Q"))
    sd = pdof[stalled].ravel()
    sd = sd[sd >= 0]
    if len(sd) > block_max:
        return False
    ins = np.zeros(pdof.shape[0], bool)
    ins[stalled] = True
    lim = idx[stalled[0]]
    i, j = pairs[:, 0], pairs[:, 1]
    be = np.flatnonzero(usable & (ins[i] | ins[j]) & (idx[i] <= lim) & (idx[j] <= lim))
    bcols = np.full((len(be), d), -1, np.int64)
    ncol = 0
    for b in range(d):
        ok = nk[be] > b
        bcols[ok, b] = ncol + np.arange(ok.sum())
        ncol += int(ok.sum())
    rows, cols, vals = [], [], []
    for side in range(2):
        for k in range(nl):
            g = pdof[pairs[be, side], k]
            for b in range(d):
                ok = (g >= 0) & (bcols[:, b] >= 0)
                rows.append(g[ok])
                cols.append(bcols[ok, b])
                vals.append(np.einsum("cx,cx->c", B[be[ok], :, side * nl + k], Q[be[ok], :, b]))
    A = sps.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(pdof.max() + 1, ncol))
    kr, kc, kv = [], [], []
    for a in range(d):
        for b in range(d):
            ok = (bcols[:, a] >= 0) & (bcols[:, b] >= 0)
            kr.append(bcols[ok, a])
            kc.append(bcols[ok, b])
            kv.append(Kq[be[ok], a, b])
    Kl = sps.csr_matrix((np.concatenate(kv), (np.concatenate(kr), np.concatenate(kc))), shape=(ncol, ncol))
    AS = A[sd]
    KAT = (Kl @ AS.T).tocsr()
    M = (AS @ KAT).tocsc()
    scale = float(abs(M.diagonal()).max(initial=1.0))
    lu = spla.splu((M + 1e-13 * scale * sps.eye(M.shape[0])).tocsc())
    data.update(block=(A, AS, KAT, lu, be, bcols), block_dofs=sd)
    return True


def _regular(neq, g, which=None, out=None):
    """Particles whose whole usable contact set carries any load (:class:`_Graph` ``g``): (N,)
    bool; with ``which`` (n,) and ``out`` (N,) only those particles recomputed in ``out`` (the
    answer depends on a particle's usable contacts alone: unchanged contacts, unchanged answer)."""
    N = neq.shape[0]
    if which is None:
        return _regular_at(np.arange(N), neq, g, np.zeros(N, np.bool_))
    return _regular_at(np.asarray(which, dtype=np.int64), neq, g, out.copy())


@numba.njit(cache=True)
def _regular_at(which, neq, g, out):
    """:func:`_regular` at the particles ``which`` (n,), written into ``out`` (N,)."""
    N = neq.shape[0]
    idx = np.zeros(N, np.int64)
    slot = np.full(N, -1, np.int64)
    one = np.empty(1, np.int64)
    for p in which:
        out[p] = False
        if neq[p] > 0:
            one[0] = p
            out[p] = _try_unit(one, slot, idx, 1, g)
    return out


def _seed_solve(data, seed):
    """Dense least-``K^+``-norm operator of the seed on its internal contacts."""
    A, Kl, se, sd = _seed_matrix(seed, data["graph"])
    data["seed_dofs"] = sd
    if not len(sd):
        return
    if not len(se):                 # a single particle: it keeps its whole load (the cycles carry it)
        data.update(seed_e=se, seed_A=np.zeros((len(sd), 0)), seed_Q=data["Q"][se], seed_Y=np.zeros((0, len(sd))))
        return
    KA = Kl @ A.T
    M = A @ KA
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    keep = w > _RANK_TOL * w.max()
    data.update(seed_e=se, seed_A=A, seed_Q=data["Q"][se],
                seed_Y=KA @ (V[:, keep] / w[keep]) @ V[:, keep].T)


def _reserved_fields(data, asm, reserved):
    """Leftover on the seed of each reserved unit force ``u`` (the cycle ``u - T(B^T u)``)."""
    if not len(reserved) or data.get("seed_Y") is None:
        return
    d, nk, Q = data["d"], data["nk"], data["Q"]
    cols, U = [], []
    k = 0
    for e in reserved:
        U.append(Q[e, :, :nk[e]])
        cols.append(np.arange(k, k + nk[e]))
        k += nk[e]
    ncol = k
    # B^T u for every reserved unit force (ndof, ncol)
    rows = asm.Bs[np.add.outer(d * reserved, np.arange(d)).ravel()]      # (d R, ndof)
    Ublk = np.zeros((d * len(reserved), ncol))
    for t, e in enumerate(reserved):
        Ublk[d * t:d * t + d, cols[t]] = U[t]
    BtU = np.asarray((rows.T @ Ublk))
    lefts = []
    for a in range(0, ncol, 6):
        _, left = Equilibrator(0, 0, 0, 0, 0, True, 0.0, data)._tree(BtU[:, a:a + 6])
        lefts.append(left[data["seed_dofs"]])
    L = np.concatenate(lefts, axis=1)          # B^T (u - T B^T u) on the seed
    data.update(Lres=L, Lres_pinv=np.linalg.pinv(L, rcond=1e-10), BtU=BtU, res_e=reserved,
                Ures=U, res_cols=cols)


# ---- the bound ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class DualBound(Result):
    """A rigorous lower bound of the stiffness tensor from an equilibrated contact force field
    (docs/theory.md, section 12).

    Attributes
    ----------
    C_lower : (m, m) ndarray
        Mandel tensor with ``C_exact - C_lower`` positive semi-definite [N/m in 2D, Pa in 3D]
        (m = 3 in 2D, 6 in 3D), the round-off margin already subtracted.
    K_lower, G_lower : float
        Isotropic projections of ``C_lower`` (``microhom.hierarchy.isotropic_weights``) [N/m, Pa].
    margin : float
        Round-off margin subtracted (times the identity) [unit of C].
    residual : float
        Largest equilibrium residual ``|B^T G|`` of the corrected field relative to the largest
        per-contact load before it cancelled (round-off: about 1e-15 .. 1e-12).
    gap : (m, m) ndarray
        ``Corr^T K^+ Corr / V``: the distance to the energy of the iterate the field was built from
        [unit of C] (with ``coarse``: the corrected iterate; with ``trial``: of the statics' field
        before the span's improvement, which only raises ``C_lower``).
    time : float
        Wall time of this evaluation [s].
    valid : bool
        The corrected field is in equilibrium to round-off (``residual <= 1e-9``) and the stalled
        particles were solved: only then is ``C_lower`` a bound.
    """

    C_lower: np.ndarray
    K_lower: float
    G_lower: float
    margin: float
    residual: float
    gap: np.ndarray
    time: float
    valid: bool


def _compliance(asm: Assembly, c0: int = 0, c1: int | None = None):
    """Per-contact ``K^+`` (c1 - c0, d, d) of the contacts ``c0 <= c < c1`` (default all C):
    ``nn/kn + (I - nn)/kt_eff`` (``nn/kn`` when sliding) [m/N]; each contact's numbers do not depend
    on the range."""
    net = asm.net
    C = net.n_contacts
    sl = slice(c0, C if c1 is None else c1)
    b = net.branch[sl]
    n = b / _norms(b)[:, None]             # net.normals of the range (the same operations)
    nn = n[:, :, None] * n[:, None, :]
    kn = np.broadcast_to(np.asarray(net.kn, float), (C,))[sl]
    kt = net.effective_kt[sl]
    inv_kt = np.where(kt > 0, 1.0 / np.where(kt > 0, kt, 1.0), 0.0)
    eye = np.eye(net.dim)
    return nn / kn[:, None, None] + inv_kt[:, None, None] * (eye - nn)


def _gersh(A):
    A = np.maximum(A, A.T)
    return float(A.sum(axis=1).max(initial=0.0))


def _iso(C):
    from .tensors import isotropic_moduli
    return isotropic_moduli(C)


def _coarse_forces(T, u, out, add=False):
    """``out = K B u`` (``add``: ``out += K B u``), (d C, s), for the two-level statics' arrays
    ``T`` (its ``Bs``, ``Ks``) and ``u`` (ndof, s), CHUNK contacts' rows at a time: each row of a
    CSR product is its own sum in the stored order, so the numbers are those of ``Ks @ (Bs @ u)``
    (``Ks`` is block diagonal: a chunk's rows have their columns in the chunk) without its
    (d C, s) temporary (issue 26)."""
    d = T["local"]["d"]
    for c0, c1 in _chunks(T["local"]["C"]):
        rows = slice(d * c0, d * c1)
        Bu = _rows_times(_csr(T["Bs"]), rows.start, rows.stop, 0, u)
        f = _rows_times(_csr(T["Ks"]), rows.start, rows.stop, rows.start, Bu)
        if add:
            out[rows] += f
        else:
            out[rows] = f


def _csr(A):
    """A sparse matrix's CSR ``(indptr, indices, data)`` (what :func:`_rows_times` and
    :func:`_peel` read; no copy of a CSR matrix)."""
    A = A if A.format == "csr" else A.tocsr()
    return (A.indptr, A.indices, A.data)


@numba.njit(cache=True)
def _rows_times(A, r0, r1, shift, X):
    """``A[r0:r1] @ X`` for a CSR ``A = (indptr, indices, data)`` (a tuple: the kernel argument
    rule) and ``X`` (n, k) C-contiguous, the columns of ``A`` read as ``j - shift`` (a block-diagonal
    ``A`` times its rows' own block of ``X``; 0 otherwise): scipy's ``csr_matvecs`` sum for sum
    (``y_i += a_ij x_j`` over the stored entries in order, from 0; no fused multiply-add), without
    the copies scipy's row slicing makes (116 MB a chunk of ``Bs`` at 1.08e5 spheres)."""
    indptr, indices, data = A
    k = X.shape[1]
    out = np.zeros((r1 - r0, k))
    for i in range(r0, r1):
        for t in range(indptr[i], indptr[i + 1]):
            a = data[t]
            j = indices[t] - shift
            for c in range(k):
                out[i - r0, c] += a * X[j, c]
    return out


def _chunks(C):
    """Contact ranges ``(c0, c1)`` of at most ``CHUNK`` contacts covering ``range(C)`` (one, empty,
    for no contact)."""
    return [(c0, min(C, c0 + CHUNK)) for c0 in range(0, max(C, 1), CHUNK)]


def _kp_times(Kp, A):
    """``K^+ A`` (n, p) for the rows ``A`` (n = d c, p) of ``c`` contacts, ``Kp`` (c, d, d) theirs."""
    d = Kp.shape[1]
    return np.einsum("cxy,cyp->cxp", Kp, A.reshape(-1, d, A.shape[1])).reshape(-1, A.shape[1])


def _over_contacts(asm, term):
    """The sums over the contacts of the matrices ``term(rows, Kp)`` returns (a tuple), chunk by
    chunk (``CHUNK``; ``rows`` the chunk's slice of the d C rows, ``Kp`` its :func:`_compliance`).
    One chunk: the very operations of the sum over all contacts. Several: each dot product is summed
    in pieces of at most ``d CHUNK`` terms and the k pieces then added, whose error bound
    (``gamma_{n_max + k - 1} <= gamma_n``, and ``sqrt(n_max + k - 1) <= sqrt(n)`` for the margin's
    estimate) is no larger than the plain sum's: the round-off margin covers them as before."""
    d = asm.net.dim
    total = None
    for c0, c1 in _chunks(asm.net.n_contacts):
        t = term(slice(d * c0, d * c1), _compliance(asm, c0, c1))
        total = t if total is None else tuple(a + b for a, b in zip(total, t))
    return total


def _balance(eq, Bs, A):
    """``A += T(-B^T A)`` in place (``A`` (d C, s) forces, ``T`` the statics ``eq``), :attr:`Equilibrator.group`
    columns at a time: no whole-width correction beside ``A`` (issue 26); the grouping changes a
    column's numbers only at round-off (:meth:`Equilibrator.correct`)."""
    k = eq.group
    for a in range(0, A.shape[1], k):
        b = min(a + k, A.shape[1])
        A[:, a:b] += eq.correct(-np.asarray(Bs.T @ A[:, a:b]), own=True).reshape(-1, b - a)


def _check_trial(asm, W):
    """The trial blocks (ndof, p_i) as float arrays; ValueError naming ``trial`` otherwise."""
    Ws = [np.asarray(w, dtype=float) for w in (W if isinstance(W, (list, tuple)) else [W])]
    for w in Ws:
        if w.ndim != 2 or w.shape[0] != asm.ndof or not np.all(np.isfinite(w)):
            raise ValueError(f"trial must be a finite array of shape (ndof, p) = ({asm.ndof}, p) or a list of "
                             f"them, got shape {w.shape}"
                             + ("" if w.ndim != 2 or w.shape[0] != asm.ndof else " with non-finite entries"))
    return Ws


def _span_fields(asm, Ws, eq, passes):
    """``Phi = Pi K B W`` (d C, p): the trial blocks' columns side by side (no stacked trial), made
    and balanced ``passes`` times in place, :attr:`Equilibrator.group` columns at a time (each column
    of a sparse product summed alone: the same numbers as whole; issue 26)."""
    Phi = np.empty((asm.Bs.shape[0], sum(w.shape[1] for w in Ws)))
    a, k = 0, eq.group
    for w in Ws:
        for j in range(0, w.shape[1], k):
            j1 = min(j + k, w.shape[1])
            Phi[:, a + j:a + j1] = asm.Ks @ (asm.Bs @ w[:, j:j1])
        a += w.shape[1]
    for _ in range(passes):
        _balance(eq, asm.Bs, Phi)
    return Phi


def _best_in_span(asm, G0, W, eq, passes):
    """The Loewner-best equilibrated field ``G0 + Phi beta``, ``Phi = Pi K B W`` (each column of
    ``K B W`` balanced by the statics, ``passes`` times): with ``S = Phi^T K^+ Phi`` and
    ``b = Phi^T (D - K^+ G0)`` the bound is ``L0 + b^T beta + beta^T b - beta^T S beta``
    ``= L0 + b^T S^+ b - (beta - S^+ b)^T S (beta - S^+ b)`` (docs/theory.md section 12), so
    ``beta = S^+ b``. Any ``beta`` is a bound: the pseudo-inverse's accuracy decides only how
    tight. ``G0`` (d C, m) is updated in place and returned."""
    Ws = _check_trial(asm, W)
    if not sum(w.shape[1] for w in Ws):
        return G0
    Phi = _span_fields(asm, Ws, eq, passes)

    def term(s, Kp):
        P = Phi[s]
        KpPhi = _kp_times(Kp, P)
        return P.T @ KpPhi, P.T @ asm.Df[s], KpPhi.T @ G0[s]
    S, b, b2 = _over_contacts(asm, term)
    b = b - b2
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > 1e-12 * w.max(initial=0.0)
    if not keep.any():
        return G0
    beta = (V[:, keep] / w[keep]) @ (V[:, keep].T @ b)
    d = asm.net.dim
    for c0, c1 in _chunks(asm.net.n_contacts):      # G0 + Phi beta, in place, chunk by chunk
        G0[d * c0:d * c1] += Phi[d * c0:d * c1] @ beta
    return G0


def _coarse_step(asm, X, coarse):
    """``X + coarse(r)``, ``r = -F - H X`` the residual of ``H X = -F`` (checked shape, finite)."""
    if not callable(coarse):
        raise ValueError(f"coarse must be None or a callable r -> y, got {coarse!r}")
    r = -asm.F - np.asarray(asm.H @ X)
    y = np.asarray(coarse(r), dtype=float)
    if y.shape != X.shape or not np.all(np.isfinite(y)):
        raise ValueError(f"coarse(r) must return a finite array of shape {X.shape}, got shape {y.shape}"
                         + ("" if y.shape != X.shape else " with non-finite entries"))
    return X + y


def _statics_field(asm, X, eq, passes):
    """``G = K (D + B X) + Corr`` (d C, m) balanced by the statics ``eq`` (``passes`` times, in place)
    and the gap ``Corr^T K^+ Corr`` (m, m) (times the volume). ``Corr = G - G0`` is taken in place
    in the kept ``G0``, not by a second product (issue 26)."""
    T = np.asarray(asm.Bs @ X)
    T += asm.Df                                                        # D + B X without a third array
    G = np.asarray(asm.Ks @ T)
    del T
    G0 = G.copy()
    for _ in range(passes):
        _balance(eq, asm.Bs, G)
    corr = np.subtract(G, G0, out=G0)                                   # the statics' correction
    gap, = _over_contacts(asm, lambda s, Kp: (corr[s].T @ _kp_times(Kp, corr[s]),))
    return G, gap


def _statics_out(eq, r):
    """``T(r)`` (d C, m) of the loads ``r`` (ndof, m), a temporary it works in (``own``;
    :meth:`Equilibrator.correct` takes :attr:`Equilibrator.group` columns at a time into one
    array)."""
    return eq.correct(r, own=True).reshape(-1, r.shape[1])


def _bound_and_margin(asm, G, c3):
    """``L = G^T D + D^T G - G^T K^+ G`` (m, m) of the field ``G`` (d C, m) and the round-off margin
    (times the volume; docs/theory.md section 12, "Round-off") from ``c3`` (d C, m), the statics'
    estimate of the field ``c3*`` that balances ``G`` exactly: the change of the bound from ``G`` to
    ``G + c3*`` (``c3`` taken twice) and the evaluation error of ``L`` (dot products over the d C
    contact components), every sum over contacts chunk by chunk (:func:`_over_contacts`). ``G`` and
    ``c3`` are overwritten by their absolute values (the caller's temporaries: no copy beside them)."""
    Df = asm.Df
    ac3 = np.abs(c3, out=c3)          # only |c3| enters the margin

    def term(s, Kp):       # each chunk array freed before the next term's (the same numbers)
        Gc, D = G[s], Df[s]
        KpG = _kp_times(Kp, Gc)
        out = [Gc.T @ D, Gc.T @ KpG]
        aK = np.abs(Kp)
        out += [ac3[s].T @ np.abs(D - KpG), ac3[s].T @ _kp_times(aK, ac3[s])]
        aG = np.abs(Gc, out=Gc)       # the chunk's signed G no longer needed
        out.append(2 * aG.T @ np.abs(D) + aG.T @ np.abs(KpG))
        del KpG
        return tuple(out) + (aG.T @ _kp_times(aK, aG),)
    L, L2, t1, t2, t3, t4 = _over_contacts(asm, term)
    L = L + L.T - L2
    L = 0.5 * (L + L.T)
    t1, t2, t3, t4 = (_gersh(t) for t in (t1, t2, t3, t4))
    g_n = np.sqrt(G.shape[0]) * _U
    return L, 2 * 2 * t1 + 4 * t2 + g_n * t3 + (asm.net.dim + 1) * _U * t4


def dual_lower_bound(asm: Assembly, X: np.ndarray, volume: float, equilibrator: Equilibrator | None = None,
                     passes: int = 2, coarse=None, trial=None) -> DualBound:
    """Lower bound of the Mandel tensor from the trial relaxation ``X`` (ndof, m) (any ``X``: the
    closer to ``H X = -F``, the tighter; e.g. the hierarchy's CG iterate) of an assembly without
    pre-stress (``assemble(..., prestress=False)``; ``pin`` either way). ``volume``: cell area
    [m^2] in 2D, volume [m^3] in 3D. ``passes`` corrections of the equilibrium (the second removes
    the round-off of the first). ``coarse``: None (default) or a callable ``r -> y`` ((ndof, m)
    in and out) approximating ``H^-1 r``; the field is then built from ``X + coarse(-F - H X)``
    before the statics (docs/theory.md section 12, "A correction before the statics"): e.g. a
    V-cycle of ``microhom.multilevel.amg_preconditioner`` or its ``coarse_correction``. Any
    ``y`` keeps the bound rigorous (only its gap depends on it); ``DualBound.gap`` is then that
    of the corrected iterate. ``trial``: None (default) or trial relaxations ``W`` (ndof, p) (or a
    list of such blocks, their columns taken together without a stacked copy); the
    field is then the best, in the Loewner order, of ``G0 + Pi K B W beta`` over ``beta`` (p, m)
    (``Pi`` the statics' projector on equilibrated fields; docs/theory.md section 12, "The best
    field in a small subspace"), e.g. the hierarchy's next preconditioned residual and its last
    search block. Raises ``ValueError`` for a pre-stressed assembly, when ``coarse`` returns an
    array of another shape or a non-finite one, and for a ``trial`` of the wrong shape or with
    non-finite entries."""
    if asm.Kgs is not None:
        raise ValueError("dual_lower_bound: the assembly is pre-stressed (prestress=True): the "
                         "complementary-energy bound needs H = B^T K B with K positive semi-definite per "
                         "contact, and the geometric stiffness -(fn/|c|)(I - nn) is not; use the spectral "
                         "certificate (relaxation_hierarchy with spectral_bound='auto' or a float)")
    if not (np.isfinite(volume) and volume > 0):
        raise ValueError(f"volume must be a positive finite number (cell area in 2D, volume in 3D), got {volume!r}")
    if not isinstance(passes, (int, np.integer)) or not 1 <= passes <= 5:
        raise ValueError(f"passes must be an integer in [1, 5], got {passes!r}")
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[0] != asm.ndof or X.shape[1] != asm.Df.shape[1]:
        raise ValueError(f"X must have shape (ndof, m) = ({asm.ndof}, {asm.Df.shape[1]}), got {X.shape}")
    t0 = time.perf_counter()
    if coarse is not None:
        X = _coarse_step(asm, X, coarse)
    eq = equilibrator if equilibrator is not None else build_equilibrator(asm)
    G, gap = _statics_field(asm, X, eq, passes)
    gap /= volume
    if trial is not None:
        G = _best_in_span(asm, G, trial, eq, passes)
    rho = np.asarray(asm.Bs.T @ G)
    scale = asm.F_scale if asm.F_scale > 0 else 1.0
    res = float(np.abs(rho).max(initial=0.0) / scale)
    np.negative(rho, out=rho)           # -B^T G in place: the statics works in it (issue 26)
    L, margin = _bound_and_margin(asm, G, _statics_out(eq, rho))      # G is |G| after it
    del rho, G
    margin /= volume
    C_lower = L / volume - margin * np.eye(asm.Df.shape[1])
    K_l, G_l = _iso(C_lower)
    return DualBound(C_lower=C_lower, K_lower=float(K_l), G_lower=float(G_l), margin=float(margin),
                     residual=res, gap=0.5 * (gap + gap.T), time=time.perf_counter() - t0,
                     valid=bool(eq.block_solved and res <= _VALID_RESIDUAL))


# ---- the two-level statics (clusters of bounded size and a coarse equilibrium step) ------------
def _box_labels(net, size):
    """Geometric boxes of the periodic cell holding about ``size`` particles each (at least two
    boxes along every axis; fewer than ``2^d`` boxes in all: None)."""
    N, d = net.n_particles, net.dim
    h = np.asarray(net.cell, float)
    w = np.linalg.norm(h, axis=0)
    per = (N / max(size, 1)) ** (1.0 / d) * w / np.prod(w) ** (1.0 / d)
    nb = np.maximum(np.round(per), 2).astype(np.int64)
    if np.prod(nb) > N or min(per) < 1.0:
        return None
    s = np.linalg.solve(h, np.asarray(net.positions, float).T).T
    s = s - np.floor(s)
    b = np.minimum((s * nb).astype(np.int64), nb - 1)
    lab = np.zeros(N, np.int64)
    for a in range(d):
        lab = lab * nb[a] + b[:, a]
    return lab


@numba.njit(cache=True)
def _csr_argmax(indptr, indices, data, ncols):
    """``scipy.sparse`` ``argmax(axis=1)`` of a CSR matrix (n, ncols) with sorted, summed indices,
    in one pass (scipy's loops in Python per row): the column of each row's first largest stored
    value; an empty row 0; a row whose largest stored value is not positive and that has implicit
    zeros: the first missing column (stored maximum negative) or, maximum zero, the smaller of that
    column and the maximum's position in the row (scipy's rule, kept as it is)."""
    n = indptr.shape[0] - 1
    out = np.zeros(n, np.int64)
    for i in range(n):
        p, q = indptr[i], indptr[i + 1]
        if q == p:
            continue
        m = p
        for t in range(p + 1, q):
            if data[t] > data[m]:
                m = t
        if data[m] > 0 or q - p == ncols:
            out[i] = indices[m]
            continue
        miss = q - p if q - p < ncols else -1        # the first column missing from the row
        for t in range(p, q):
            if indices[t] != t - p:
                miss = t - p
                break
        out[i] = min(m - p, miss) if data[m] == 0 else miss
    return out


def _argmax_rows(M):
    """``M.argmax(axis=1)`` (n,) of the sparse ``M`` (n, m), as scipy gives it (:func:`_csr_argmax`)."""
    M = M.tocsr()
    M.sum_duplicates()
    return _csr_argmax(M.indptr.astype(np.int64), M.indices.astype(np.int64), M.data, M.shape[1])


def _reassign(lab, pairs, usable, nk, need, passes=3):
    """Each particle with fewer than ``need`` (N,) force components on contacts inside its box moves to
    the neighbouring box it has the most components to (``passes`` times)."""
    N = lab.shape[0]
    i, j = pairs[usable, 0], pairs[usable, 1]
    w = nk[usable].astype(float)
    for _ in range(passes):
        own = np.bincount(i, w * (lab[i] == lab[j]), N) + np.bincount(j, w * (lab[i] == lab[j]), N)
        bad = own < need
        if not bad.any():
            break
        M = sps.coo_matrix((np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([lab[j], lab[i]]))),
                           shape=(N, lab.max() + 1)).tocsr()
        best = _argmax_rows(M)
        moved = bad & (np.asarray(M.max(axis=1).toarray()).ravel() > own)
        if not moved.any():
            break
        lab = np.where(moved, best, lab)
    return lab


@numba.njit(cache=True)
def _continue(x, ch, pr, step, order):
    """``x[ch[k]] = x[pr[k]] + step[k]`` (x (N, d), step (n, d)) for ``k`` in ``order`` (n,), in
    place: a parent placed before its children continues the positions along a tree."""
    for k in order:
        for a in range(x.shape[1]):
            x[ch[k], a] = x[pr[k], a] + step[k, a]


def _unwrap(net, inner, N):
    """Positions continued along the contacts ``inner`` from one root per connected component
    (breadth first): ``x_j = x_i + c_ij`` on the tree edges; returns them and the contacts of
    ``inner`` the continuation is consistent with (a component wrapping the cell is cut there)."""
    from scipy.sparse.csgraph import breadth_first_order, connected_components
    pairs = net.pairs
    c = net.branch
    e = np.flatnonzero(inner)
    G = sps.coo_matrix((e + 1.0, (pairs[e, 0], pairs[e, 1])), shape=(N, N)).tocsr()
    ncomp, comp = connected_components(G, directed=False)
    roots = np.unique(comp, return_index=True)[1]
    # a virtual node N joined to every component's root: one breadth-first pass over all of them
    Gv = sps.bmat([[G + G.T, sps.coo_matrix((np.ones(len(roots)), (roots, np.zeros(len(roots), int))), shape=(N, 1))],
                   [None, sps.csr_matrix((1, 1))]]).tocsr()
    Gv = (Gv + Gv.T).tocsr()
    order, pred = breadth_first_order(Gv, N, directed=False)
    x = np.array(net.positions, dtype=float)
    src = np.concatenate([pairs[e, 0], pairs[e, 1]])          # directed edges, the first contact per pair
    dst = np.concatenate([pairs[e, 1], pairs[e, 0]])
    sid = np.concatenate([e + 1, -(e + 1)])
    key, first = np.unique(src.astype(np.int64) * N + dst, return_index=True)
    ch = order[1:]
    pr = pred[ch]
    tree = pr != N
    ch, pr = ch[tree], pr[tree]
    sg = sid[first[np.searchsorted(key, pr.astype(np.int64) * N + ch)]]
    step = np.sign(sg)[:, None] * c[np.abs(sg) - 1]
    pos_in = np.empty(N + 1, np.int64)
    pos_in[order] = np.arange(len(order))
    _continue(x, ch, pr, step, np.argsort(pos_in[ch], kind="stable"))     # parents before children
    ok = inner.copy()
    ok[e] = np.abs(x[pairs[e, 1]] - x[pairs[e, 0]] - c[e]).max(axis=1) <= 1e-9 * (1 + np.abs(c[e]).max(axis=1))
    return x, ok


def _cluster_seed(members, deg, target, g, regular):
    """A rigid ball of the cluster ``members`` (their contacts of ``g`` only) around its
    best-connected regular particles, trimmed as :func:`_seed`; one particle if none is rigid."""
    mem = members[regular[members]]
    if not len(mem):
        return members[:1]
    inside = set(int(p) for p in mem)
    ptr, adj_e, adj_q, usable = g.ptr, g.adj_e, g.adj_q, g.usable
    d = g.B.shape[1]
    rigid = d + rotational_dofs(d)
    for start in mem[np.argsort(-deg[mem], kind="stable")[:4]]:
        seen, ball, front = {int(start)}, [int(start)], [int(start)]
        while front and len(ball) < target:
            nxt = []
            for p in front:
                for t in range(ptr[p], ptr[p + 1]):
                    q = int(adj_q[t])
                    if usable[adj_e[t]] and q in inside and q not in seen:
                        seen.add(q)
                        nxt.append(q)
            ball.extend(nxt)
            front = nxt
        ball = _trimmed(ball[:target], g, rigid)
        if ball is not None:
            return ball
    return mem[:1]


def _block_diag(mats):
    """``scipy.sparse.block_diag(mats, format="csr")`` of dense 2D blocks (every entry of a block
    stored, zeros too, rows in column order: the same arrays), assembled directly as CSR."""
    nr = np.array([a.shape[0] for a in mats], np.int64)
    nc = np.array([a.shape[1] for a in mats], np.int64)
    c0 = np.concatenate([[0], np.cumsum(nc)])
    indptr = np.concatenate([[0], np.cumsum(np.repeat(nc, nr))])
    indices = np.concatenate([np.tile(np.arange(c0[k], c0[k + 1]), nr[k]) for k in range(len(mats))])
    data = np.concatenate([np.asarray(a, float).ravel() for a in mats])
    return sps.csr_matrix((data, indices, indptr), shape=(int(nr.sum()), int(c0[-1])))


def _seeds_solve(seeds, g):
    """Block-diagonal dense least-``K^+``-norm operators of the seeds (one per cluster) on their
    own contacts: the arrays :meth:`Equilibrator._tree` reads (``seed_Y`` and ``seed_A`` sparse)."""
    Ys, As, es, ds = [], [], [], []
    for s in seeds:
        A, Kl, se, sd = _seed_matrix(s, g)
        if not len(se) or not len(sd):
            continue
        KA = Kl @ A.T
        M = A @ KA
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        keep = w > _RANK_TOL * w.max()
        Ys.append(KA @ (V[:, keep] / w[keep]) @ V[:, keep].T)
        As.append(A)
        es.append(se)
        ds.append(sd)
    if not Ys:
        return dict(seed_Y=None, seed_e=np.zeros(0, np.int64))
    se = np.concatenate(es)
    # A is B^T on the seed (12 unknowns per contact component): its block's zeros are not kept (the
    # same products: a sum without its +-0 terms; issue 26, 15 times fewer entries, 0.4 GiB at 1e6)
    A = _block_diag(As)
    A.eliminate_zeros()
    return dict(seed_Y=_block_diag(Ys), seed_A=A,
                seed_e=se, seed_dofs=np.concatenate(ds), seed_Q=g.Q[se])


def _rigid_columns(lab, x, pdof, d, ncl):
    """``R`` (ndof, ncl (d + r)): the rigid motions of each cluster (translations; rotations
    ``u_i = w x (x_i - x_k)``, ``x_k`` the cluster's centroid, and the rotation unknowns ``w``)."""
    rot = rotational_dofs(d)
    nr = d + rot
    cnt = np.bincount(lab, minlength=ncl).astype(float)
    cen = np.stack([np.bincount(lab, x[:, a], ncl) for a in range(d)], axis=1) / np.maximum(cnt, 1)[:, None]
    arm = x - cen[lab]
    rows, cols, vals = [], [], []

    def put(r, cidx, v):
        ok = r >= 0
        rows.append(r[ok])
        cols.append(cidx[ok])
        vals.append(np.broadcast_to(v, r.shape)[ok])
    for a in range(d):
        put(pdof[:, a], nr * lab + a, 1.0)
    for b in range(rot):
        put(pdof[:, d + b], nr * lab + d + b, 1.0)
        if d == 2:     # spin w: u = w (-y, x)
            put(pdof[:, 0], nr * lab + 2, -arm[:, 1])
            put(pdof[:, 1], nr * lab + 2, arm[:, 0])
        else:          # u = e_b x arm
            e = np.eye(3)[b]
            u = np.cross(e[None, :], arm)
            for a in range(3):
                if a != b:
                    put(pdof[:, a], nr * lab + d + b, u[:, a])
    ndof = pdof.max(initial=-1) + 1
    return sps.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(ndof, nr * ncl))


def _coarse_solver(asm, R):
    """``z -> y`` solving ``R^T H R y = z`` (singular by the global translations and the floppy
    modes, on which ``K B R y`` vanishes), by ``COARSE_BACKEND`` (3D; ``COARSE_BACKEND_2D`` in
    2D): ``"amg"`` CG preconditioned by smoothed aggregation (``microhom.coarse_solve.amg_solver``,
    memory O(nnz)), a back end of ``microhom.factor.factor`` the shifted factor and three
    refinement steps (``coarse_solve.factor_solver``, the former solve)."""
    from .coarse_solve import amg_solver, factor_solver
    if asm.H is not None:
        Hc = (R.T @ (asm.H @ R)).tocsr()
    else:       # the hierarchy dropped H (microhom.shared_h): H = Bs^T Ks Bs without pre-stress
        BR = asm.Bs @ R
        Hc = (BR.T @ (asm.Ks @ BR)).tocsr()
    d = asm.net.dim
    backend = COARSE_BACKEND if d == 3 else COARSE_BACKEND_2D
    if backend == "amg":
        solve = amg_solver(Hc, d + rotational_dofs(d), d)
    else:
        solve = factor_solver(Hc, d, backend)
    return solve, Hc.shape[0], Hc.nnz


ROUNDS = 2
#: the two-level statics' coarse solve in 3D: a back end of ``microhom.factor.factor`` ("auto",
#: "pardiso", "cholmod", "splu": a shifted factor, refined) or "amg" (CG with smoothed aggregation,
#: memory O(nnz); docs/theory.md section 12, "The coarse solve"). "auto" stays the default: measured
#: (docs/results/spheres.md, "The statics' coarse solve without a factor"), the factor takes no more
#: memory up to 1.08e5 spheres and 0.7 of "amg"'s with 2 744 clusters, and "amg" solves 50-70 times
#: slower, missing its tolerance (then the factor) with 2 744 clusters
COARSE_BACKEND = "auto"
#: the same in 2D (the factor: 2D results unchanged)
COARSE_BACKEND_2D = "auto"
UNIT_MAX = 8


def _two_level(asm, g0, neq, size, regular0):
    """The two-level statics (docs/theory.md section 12, "Two-level statics"): clusters of about
    ``size`` particles (boxes of the cell; particles without enough contacts inside their box
    moved to the neighbouring one), each grown by statics from its own seed on its own contacts;
    particles that do not attach become clusters of their own; the coarse step on the clusters'
    rigid motions. None when the cell holds fewer than ``2^d`` boxes of that size. ``regular0``
    (N,): :func:`_regular` on ``g0``."""
    net = asm.net
    N, d = net.n_particles, net.dim
    lab = _box_labels(net, size)
    if lab is None:
        return None
    pairs, nk = g0.pairs, g0.nk
    # force components a particle needs inside its cluster: its unknowns, 9 for a sphere with
    # rotations (three contacts: two leave a twist)
    need = np.where((d == 3) & (neq == 6), 9, neq)
    lab = _reassign(lab, pairs, g0.usable, nk, need)
    BIG = 1 << 60
    live = neq > 0
    for rnd in range(ROUNDS):
        inner = g0.usable & (lab[pairs[:, 0]] == lab[pairs[:, 1]])
        x, inner = _unwrap(net, inner, N)
        g = g0._replace(usable=inner)
        cut = np.zeros(N, bool)              # particles with a contact of g0 not used here
        cut[pairs[g0.usable & ~inner].ravel()] = True
        regular = _regular(neq, g, np.flatnonzero(cut), regular0)
        deg = np.bincount(pairs[inner].ravel(), minlength=N)
        if rnd == 0:              # the seeds stay (attached first, they never move)
            order = np.argsort(lab, kind="stable")
            bounds = np.searchsorted(lab[order], np.arange(lab.max() + 2))
            seeds = [_cluster_seed(order[bounds[k]:bounds[k + 1]], deg, 12 if d == 2 else 30, g, regular)
                     for k in range(len(bounds) - 1) if bounds[k + 1] > bounds[k]]
        idx, members, uptr = _bootstrap(np.concatenate(seeds), regular, neq, g, UNIT_MAX, True)
        alone = np.flatnonzero(live & (idx == BIG))
        if rnd == ROUNDS - 1 or not len(alone):
            break
        # an unattached particle moves to the cluster it has the most contact components to among the
        # attached particles
        att = idx < BIG
        i, j = pairs[g0.usable, 0], pairs[g0.usable, 1]
        w = g0.nk[g0.usable].astype(float)
        M = sps.coo_matrix((np.concatenate([w * att[j], w * att[i]]), (np.concatenate([i, j]), np.concatenate([lab[j], lab[i]]))),
                           shape=(N, lab.max() + 1)).tocsr()[alone]
        best = _argmax_rows(M)
        lab = lab.copy()
        lab[alone] = best
    n_tree = len(uptr) - 1
    idx[idx == BIG] = n_tree + 1
    lab = lab.copy()
    lab[alone] = lab.max() + 1 + np.arange(len(alone))        # a cluster of its own each
    _, lab = np.unique(lab, return_inverse=True)
    ncl = int(lab.max()) + 1
    tree, _ = _operators(members, uptr, idx, g)
    local = dict(C=pairs.shape[0], d=d, graph=g, tree=tree, n_tree=n_tree, block=None, Lres=None)
    local.update(_seeds_solve(seeds, g))
    # what the peeling reads is kept (it reads B from the assembly's Bs); the adjacency, the dense
    # B and the stiffness were for the construction (issue 26: 408 bytes per contact, 1.4 GB at 1e6)
    none = np.zeros(0, np.int64)
    local["graph"] = g._replace(adj_e=none, adj_s=none, adj_q=none, Kq=np.zeros((0, d, d)),
                                B=np.zeros((0,) + g.B.shape[1:]))
    local["rows"] = _bs_rows(asm)
    R = _rigid_columns(lab, x, g.pdof, d, ncl)
    solve, nc, nnz = _coarse_solver(asm, R)
    stats = dict(n_clusters=ncl - len(alone), n_alone=len(alone), n_seed=int(sum(len(s) for s in seeds)),
                 n_attached=int(uptr[n_tree]), coarse_dofs=nc, coarse_nnz=nnz)
    return dict(R=R, solve=solve, local=local, Bs=asm.Bs, Ks=asm.Ks, stats=stats)
