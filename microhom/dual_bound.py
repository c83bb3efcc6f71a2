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
from .results import Result

__all__ = ["DualBound", "Equilibrator", "build_equilibrator", "dual_lower_bound"]

_RANK_TOL = 1e-9       # eigenvalue of the local A K A^T below this fraction of the largest: rank-deficient
_ACCEPT = 1e-4         # a unit joins only if every eigenvalue of its A K A^T is above this fraction (cond <= 1e4)
_U = np.finfo(float).eps
_VALID_RESIDUAL = 1e-9  # relative equilibrium residual above which the field is not taken as balanced


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
            e, q = adj_e[t], adj_q[t]
            if usable[e] and ((slot[q] >= 0 and adj_s[t] == 0) or (slot[q] < 0 and idx[q] < before)):
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
def _try_unit(mem, slot, idx, before, g):
    """Does the unit carry any load on its contacts to the built particles (full row rank)?"""
    for u in range(mem.shape[0]):
        slot[mem[u]] = u
    A, Kl, _, _ = _unit_local(mem, slot, idx, before, g)
    for u in range(mem.shape[0]):
        slot[mem[u]] = -1
    if A.shape[0] == 0 or A.shape[1] < A.shape[0]:
        return False
    M = A @ Kl @ A.T
    w = np.linalg.eigvalsh(0.5 * (M + M.T))
    return w[0] > _ACCEPT * w[-1]


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
def _bootstrap(seed, regular, neq, g, kmax):
    """Construction order from the seed: a regular particle joins once its usable contacts to the
    particles already in carry any load (full row rank), or, failing that, together with unbuilt
    neighbours as one unit of up to ``kmax`` particles (in 3D two contacts leave a sphere a twist
    about the line of its contact points, which a contact to a neighbour resists). Returns ``idx``
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
    while True:
        _drain(o, regular, neq, g)
        progressed = False      # stalled: units of several particles on the frontier, pass by pass
        for q in range(N):
            if o.idx[q] < BIG or not regular[q] or o.cnt[q] == 0:
                continue
            mem = _grow(q, kmax, o, regular, g)
            if mem.shape[0]:
                _attach(mem, o)
                progressed = True
                _drain(o, regular, neq, g)
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
def _peel(load, c, tree, g, a0, a1):
    """Leaf to root: each unit ``a0 <= a < a1`` of the :class:`_Tree` ``tree`` (reversed
    construction order) hands its load to its parent contacts (``c`` += forces, (C, d, s)); the
    reactions load the other ends (:class:`_Graph` ``g``). ``load`` (ndof, s) keeps what is left
    (round-off where the local solve has full rank)."""
    pptr, pe, rptr, rdof, yptr, Y = tree
    pdof, pairs, B, Q, nk, nl = g.pdof, g.pairs, g.B, g.Q, g.nk, g.nl
    d = B.shape[1]
    s = load.shape[1]
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
            for side in range(2):
                q = pairs[e, side]
                for k in range(nl):
                    g = pdof[q, k]
                    if g < 0:
                        continue
                    kk = side * nl + k
                    for j in range(s):
                        v = 0.0
                        for x in range(d):
                            v += B[e, x, kk] * f[x, j]
                        load[g, j] -= v


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

    def correct(self, r: np.ndarray, chunk: int = 6) -> np.ndarray:
        """Forces ``c`` (C, d, s) with ``B^T c = r`` for loads ``r`` (ndof, s) in the range of
        ``B^T`` (orthogonal to the rigid translations)."""
        r = np.asarray(r, dtype=float)
        one = r.ndim == 1
        r = r[:, None] if one else r
        out = np.concatenate([self._correct(r[:, a:a + chunk]) for a in range(0, r.shape[1], chunk)],
                             axis=2) if r.shape[1] else np.zeros((self._data["C"], self._data["d"], 0))
        return out[:, :, 0] if one else out

    def _correct(self, r):
        D = self._data
        c, left = self._tree(r)
        if D["Lres"] is not None:       # the seed's leftover (net moment): the reserved cycles
            # c = T(r) + sum_u alpha_u (u - T(B^T u)), B^T (u - T(B^T u)) = Lres[:, u] on the seed
            alpha = D["Lres_pinv"] @ left[D["seed_dofs"]]
            c2, _ = self._tree(D["BtU"] @ alpha)
            c -= c2
            for t, e in enumerate(D["res_e"]):
                c[e] += D["Ures"][t] @ alpha[D["res_cols"][t]]
        return c

    def _tree(self, r):
        D = self._data
        load = np.array(r, dtype=float, order="C", copy=True)
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
        _peel(load, c, D["tree"], D["graph"], 0, D["n_tree"])
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
    usable, pdof, pairs, B, Q, nk, Kq, nl = g.usable, g.pdof, g.pairs, g.B, g.Q, g.nk, g.Kq, g.nl
    d = B.shape[1]
    ins = np.zeros(pdof.shape[0], bool)
    ins[seed] = True
    se = np.flatnonzero(usable & ins[pairs[:, 0]] & ins[pairs[:, 1]])
    sd = pdof[seed].ravel()
    sd = sd[sd >= 0]
    pos = np.full(pdof.max(initial=0) + 1, -1, np.int64)
    pos[sd] = np.arange(len(sd))
    A = np.zeros((len(sd), d * len(se)))
    for a, e in enumerate(se):
        for side in range(2):
            for k in range(nl):
                g = pdof[pairs[e, side], k]
                if g >= 0:
                    A[pos[g], d * a:d * a + nk[e]] += B[e, :, side * nl + k] @ Q[e, :, :nk[e]]
    Kl = np.zeros((d * len(se), d * len(se)))
    for a, e in enumerate(se):
        Kl[d * a:d * a + d, d * a:d * a + d] = Kq[e]
    return A, Kl, se, sd


def _seed(deg, target, g, regular, tries=20):
    """A rigid seed cluster: a ball around a well-connected particle, trimmed (the particle with
    the fewest contacts inside first) until its internal contacts carry every self-equilibrated
    load (rank = unknowns - rigid motions)."""
    ptr, adj_q, usable, pairs, pdof = g.ptr, g.adj_q, g.usable, g.pairs, g.pdof
    d = g.B.shape[1]
    rigid = d + rotational_dofs(d)
    cand = np.argsort(-np.where(regular, deg, -1), kind="stable")[:tries]
    for start in cand:
        ball = _ball(start, target, ptr, adj_q, regular)
        while len(ball) >= 2:
            A, Kl, se, sd = _seed_matrix(np.array(ball), g)
            if len(se):
                w = np.linalg.eigvalsh(A @ Kl @ A.T)
                if int((w > _RANK_TOL * w.max()).sum()) == len(sd) - rigid:
                    return np.array(ball, dtype=np.int64)
            ins = np.zeros(pdof.shape[0], bool)
            ins[ball] = True
            inner = [int((ins[pairs[usable & ((pairs[:, 0] == p) | (pairs[:, 1] == p))]].all(axis=1)).sum())
                     for p in ball]
            ball.pop(int(np.argmin(inner)))
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


def build_equilibrator(asm: Assembly, seed_size=None, block_max: int = 300_000) -> Equilibrator:
    """The statics of ``asm`` (module docstring): construction order, local operators, seed and
    reserved contacts. O(C) time and memory."""
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
    data = dict(C=C, d=d, nl=nl, pairs=pairs, B=B, Q=Q, nk=nk, pdof=pdof, graph=g, tree=tree,
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


@numba.njit(cache=True)
def _regular(neq, g):
    """Particles whose whole usable contact set carries any load (:class:`_Graph` ``g``)."""
    N = neq.shape[0]
    idx = np.zeros(N, np.int64)
    slot = np.full(N, -1, np.int64)
    out = np.zeros(N, np.bool_)
    one = np.empty(1, np.int64)
    for p in range(N):
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


def _compliance(asm: Assembly):
    """Per-contact ``K^+`` (C, d, d): ``nn/kn + (I - nn)/kt_eff`` (``nn/kn`` when sliding) [m/N]."""
    net = asm.net
    n = net.normals
    nn = n[:, :, None] * n[:, None, :]
    kn = np.asarray(net.kn, float) * np.ones(net.n_contacts)
    kt = net.effective_kt
    inv_kt = np.where(kt > 0, 1.0 / np.where(kt > 0, kt, 1.0), 0.0)
    eye = np.eye(net.dim)
    return nn / kn[:, None, None] + inv_kt[:, None, None] * (eye - nn)


def _gersh(A):
    A = np.maximum(A, A.T)
    return float(A.sum(axis=1).max(initial=0.0))


def _iso(C):
    from .tensors import isotropic_moduli
    return isotropic_moduli(C)


def _best_in_span(asm, G0, W, eq, Kp, passes):
    """The Loewner-best equilibrated field ``G0 + Phi beta``, ``Phi = Pi K B W`` (each column of
    ``K B W`` balanced by the statics, ``passes`` times): with ``S = Phi^T K^+ Phi`` and
    ``b = Phi^T (D - K^+ G0)`` the bound is ``L0 + b^T beta + beta^T b - beta^T S beta``
    ``= L0 + b^T S^+ b - (beta - S^+ b)^T S (beta - S^+ b)`` (docs/theory.md section 12), so
    ``beta = S^+ b``. Any ``beta`` is a bound: the pseudo-inverse's accuracy decides only how
    tight."""
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[0] != asm.ndof or not np.all(np.isfinite(W)):
        raise ValueError(f"trial must be a finite array of shape (ndof, p) = ({asm.ndof}, p), got "
                         f"shape {W.shape}" + ("" if W.ndim != 2 or W.shape[0] != asm.ndof else " with non-finite entries"))
    if not W.shape[1]:
        return G0
    d, p = asm.net.dim, W.shape[1]
    Phi = np.asarray(asm.Ks @ (asm.Bs @ W))
    for _ in range(passes):
        # in place, six columns at a time (the statics' own chunks: the same numbers), without a
        # second Phi and the whole correction beside it (issue 26: 3 p columns of dC floats were live)
        for a in range(0, p, 6):
            k = min(6, p - a)
            Phi[:, a:a + k] += eq.correct(-np.asarray(asm.Bs.T @ Phi[:, a:a + k])).reshape(-1, k)
    KpPhi = np.einsum("cxy,cyp->cxp", Kp, Phi.reshape(-1, d, p)).reshape(-1, p)
    S = Phi.T @ KpPhi
    b = Phi.T @ asm.Df - KpPhi.T @ G0
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > 1e-12 * w.max(initial=0.0)
    if not keep.any():
        return G0
    beta = (V[:, keep] / w[keep]) @ (V[:, keep].T @ b)
    return G0 + Phi @ beta


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
    of the corrected iterate. ``trial``: None (default) or trial relaxations ``W`` (ndof, p); the
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
    m = asm.Df.shape[1]
    d = asm.net.dim
    Kp = _compliance(asm)
    G = np.asarray(asm.Ks @ (asm.Df + asm.Bs @ X))                      # (dC, m)
    for _ in range(passes):
        G += eq.correct(-np.asarray(asm.Bs.T @ G)).reshape(-1, m)       # in place (issue 26)
    corr = G - np.asarray(asm.Ks @ (asm.Df + asm.Bs @ X))              # the statics' correction
    gap = corr.T @ np.einsum("cxy,cym->cxm", Kp, corr.reshape(-1, d, m)).reshape(-1, m) / volume
    del corr
    if trial is not None:
        G = _best_in_span(asm, G, trial, eq, Kp, passes)
    rho = np.asarray(asm.Bs.T @ G)
    c3 = eq.correct(-rho).reshape(-1, m)                                  # distance to exact equilibrium
    KpG = np.einsum("cxy,cym->cxm", Kp, G.reshape(-1, d, m)).reshape(-1, m)
    L = G.T @ asm.Df
    L = L + L.T - G.T @ KpG
    L = 0.5 * (L + L.T)
    # margins: the exactly equilibrated field G + c3* (c3 its computed estimate, taken twice) and the
    # evaluation of L (dot products over the d C contact components)
    # (each term's arrays freed before the next: issue 26; the same numbers)
    aK = np.abs(Kp)
    ac3 = np.abs(c3)
    del c3
    t1 = _gersh(ac3.T @ np.abs(asm.Df - KpG))
    Kc3 = np.einsum("cxy,cym->cxm", aK, ac3.reshape(-1, d, m)).reshape(-1, m)
    t2 = _gersh(ac3.T @ Kc3)
    del Kc3, ac3
    n = G.shape[0]
    g_n = np.sqrt(n) * _U
    aG = np.abs(G)
    t3 = _gersh(2 * aG.T @ np.abs(asm.Df) + aG.T @ np.abs(KpG))
    del KpG
    t4 = _gersh(aG.T @ np.einsum("cxy,cym->cxm", aK, aG.reshape(-1, d, m)).reshape(-1, m))
    margin = 2 * 2 * t1 + 4 * t2 + g_n * t3 + (d + 1) * _U * t4
    margin /= volume
    C_lower = L / volume - margin * np.eye(m)
    scale = asm.F_scale if asm.F_scale > 0 else 1.0
    K_l, G_l = _iso(C_lower)
    res = float(np.abs(rho).max(initial=0.0) / scale)
    return DualBound(C_lower=C_lower, K_lower=float(K_l), G_lower=float(G_l), margin=float(margin),
                     residual=res, gap=0.5 * (gap + gap.T), time=time.perf_counter() - t0,
                     valid=bool(eq.block_solved and res <= _VALID_RESIDUAL))
