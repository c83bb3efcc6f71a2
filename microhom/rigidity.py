"""Rigidity percolation by the pebble game: floppy modes, redundant constraints and rigid clusters
of a 2D contact network, frictionless or frictional (``docs/theory.md``, "Counting rules and the
pebble game").

The constraint graph (one vertex per load-bearing disk; rattlers as
:func:`microhom.structural_sums.rattlers` defines them are left out):

* a contact with no tangent stiffness (``effective_kt == 0``: frictionless, or sliding at the
  Coulomb limit) is **one bar** along the normal; it never constrains a spin (the normal passes
  through both centres);
* a sticking frictional contact (``effective_kt > 0``) is **two bars** through the contact point
  (a pin joint between two rigid bodies);
* a disk with a sticking contact is a **body** with 3 degrees of freedom (two translations and
  its spin; 3 pebbles); a disk with none is a **joint** with 2 (its spin is decoupled: 2 pebbles).

A frictionless packing is thus the (2, 3) pebble game of Jacobs & Thorpe (PRL 75, 4051, 1995;
Jacobs & Hendrickson, J. Comput. Phys. 137, 346, 1997) on the central-force bar network, and a
frictional one the (3, 3) game on the multigraph of Henkes, Quint, Fily & Schwarz (PRL 116,
028301, 2016), with sliding contacts one bar and disks without a sticking contact joints.

**Periodic boundaries: the network on the torus with the cell fixed.** The rigidity matrix is
the one of :mod:`microhom.kinematics` at zero strain (``Delta = B q``): its trivial motions are
the 2 global translations only (a global rotation does not keep the periodic images in place).
Counting on the fixed torus (Ross, "Inductive constructions for frameworks on a two-dimensional
fixed torus", 2015, extended here from bars to the bodies and joints above): a set of bars spanning
vertices V' is independent iff every subset satisfies ``|E'| <= sum_{V'} k_v - 3`` when its cycles
have zero net lattice translation (its gain group is trivial: it does not wrap around the torus)
and ``|E'| <= sum_{V'} k_v - 2`` otherwise. The game gathers 4 pebbles on a bar's ends as usual;
when only 3 come, the bar is still independent if the smallest tight set blocking it (the vertices
reachable from its ends) wraps once the bar is added (the gain is tracked with a weighted
union-find on the lattice image shifts of the contacts). Without a cell the count is the plane's
(3 trivial motions, ``k - 3`` for every subset). The counts are checked against the numerical rank
of :func:`rigidity_matrix` (``tests/test_rigidity.py``).

**Rigid clusters** (Jacobs & Hendrickson's decomposition): from a base (a body, or a bar between two
joints) with its pebbles pinned, a neighbour is rigid with the base iff no free pebble can be
brought to it; a failed search marks every vertex it visited as rigid (they close a tight set). On
the torus a tight set that wraps with one free pebble more than its translations is not rigid, and
the search is then counted as successful. Clusters are edge-disjoint; a body is in exactly one
cluster; a joint may be shared by several (a hinge), and its particle label is the largest of them.
A contact joining two different clusters (a hinge between bodies) has no cluster (label -1).

**Generic counts.** The game gives the rank of a generic framework with this graph. Disks are not
always generic: straight rows of contacts, and the gears of frictional disks (an even ring of
sticking contacts counter-rotates, ``omega_i = +-omega / r_i``, with no translation, whatever the
positions) have floppy modes the count does not see (``docs/theory.md`` section 11, pinned by
``tests/test_rigidity.py``). On the disordered packings of the closure corpus the counts equal the
numerical ones (``studies.closure_rigidity``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np
import scipy.sparse as sp

from .network import ContactNetwork
from .results import Result
from .structural_sums import rattlers

__all__ = ["RigidityResult", "pebble_game", "rigidity_matrix", "numerical_floppy_modes"]


# ---- the pebble game (numba) ---------------------------------------------------------------------
class _Graph(NamedTuple):
    """The directed pebble graph of n bodies: pebble capacity ``kcap`` and free pebbles ``free``
    (n,); per body its out-bars ``outv`` (target body), ``oute`` (bar), ``outs`` (lattice shift, 2)
    in the first ``outdeg`` slots (n, 3)."""
    kcap: np.ndarray
    free: np.ndarray
    outdeg: np.ndarray
    outv: np.ndarray
    oute: np.ndarray
    outs: np.ndarray


class _Scratch(NamedTuple):
    """Work arrays of the searches (n bodies): visit stamps ``seen`` and the running ``stamp`` (1,),
    the breadth-first parents, queue ``vis`` and its length ``nvis`` (1,), a stack, the union-find
    of the wrap test (``par``, lattice potentials ``pot`` (n, 2), ``rank``) and its ``roots`` (3,)."""
    seen: np.ndarray
    stamp: np.ndarray
    parent_v: np.ndarray
    parent_s: np.ndarray
    stack: np.ndarray
    vis: np.ndarray
    nvis: np.ndarray
    par: np.ndarray
    pot: np.ndarray
    rank: np.ndarray
    roots: np.ndarray


@numba.njit(cache=True)
def _scratch(n):
    """Fresh :class:`_Scratch` for n bodies."""
    return _Scratch(np.zeros(n, np.int64), np.zeros(1, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64),
                    np.zeros(n + 1, np.int64), np.zeros(n + 1, np.int64), np.zeros(1, np.int64), np.arange(n),
                    np.zeros((n, 2), np.int64), np.zeros(n, np.int64), np.zeros(3, np.int64))


@numba.njit(cache=True)
def _search(w, p1, p2, g, sc, st):
    """Breadth-first search from ``w`` along the pebble directions of :class:`_Graph` ``g`` for a
    free pebble held by a vertex other than ``p1``, ``p2`` (pinned; they can be passed through),
    visit stamp ``st``. On success the path is reversed and the pebble moves to ``w``; on failure
    ``sc.vis[:sc.nvis[0]]`` lists the vertices reached."""
    free, outdeg, outv, oute, outs = g.free, g.outdeg, g.outv, g.oute, g.outs
    seen, parent_v, parent_s, vis, nvis = sc.seen, sc.parent_v, sc.parent_s, sc.vis, sc.nvis
    seen[w] = st
    vis[0] = w
    nv = 1
    head = 0
    found = -1
    while head < nv and found < 0:   # breadth first: the nearest free pebble
        x = vis[head]
        head += 1
        for s in range(outdeg[x]):
            y = outv[x, s]
            if seen[y] == st:
                continue
            seen[y] = st
            parent_v[y] = x
            parent_s[y] = s
            vis[nv] = y
            nv += 1
            if free[y] > 0 and y != p1 and y != p2:
                found = y
                break
    nvis[0] = nv
    if found < 0:
        return False
    y = found
    free[y] -= 1
    while y != w:   # reverse the path: each edge p -> y becomes y -> p
        p = parent_v[y]
        s = parent_s[y]
        e = oute[p, s]
        sx, sy = outs[p, s, 0], outs[p, s, 1]
        last = outdeg[p] - 1
        outv[p, s] = outv[p, last]
        oute[p, s] = oute[p, last]
        outs[p, s, 0] = outs[p, last, 0]
        outs[p, s, 1] = outs[p, last, 1]
        outdeg[p] = last
        d = outdeg[y]
        outv[y, d] = p
        oute[y, d] = e
        outs[y, d, 0] = -sx
        outs[y, d, 1] = -sy
        outdeg[y] = d + 1
        y = p
    free[w] += 1
    return True


@numba.njit(cache=True)
def _gather(u, v, target, g, sc):
    """Bring free pebbles to ``u`` and ``v`` (``v = -1``: ``u`` alone) until they hold ``target``
    or none can be found; returns the number they hold."""
    kcap, free, stamp = g.kcap, g.free, sc.stamp
    while True:
        have = free[u] + (free[v] if v >= 0 else 0)
        if have >= target:
            return have
        got = False
        if free[u] < kcap[u]:
            stamp[0] += 1
            got = _search(u, u, v, g, sc, stamp[0])
        if not got and v >= 0 and free[v] < kcap[v]:
            stamp[0] += 1
            got = _search(v, u, v, g, sc, stamp[0])
        if not got:
            return have


@numba.njit(cache=True)
def _uf_root(x, par, pot):
    """Root of ``x`` and the potential (lattice offset) of ``x`` relative to it."""
    px = 0
    py = 0
    while par[x] != x:
        px += pot[x, 0]
        py += pot[x, 1]
        x = par[x]
    return x, px, py


@numba.njit(cache=True)
def _wraps(nroots, extra_a, extra_b, ex, ey, g, sc, st):
    """True if the set reachable from ``sc.roots[:nroots]`` along the pebble directions of ``g``
    (closed: its induced accepted bars are the out-bars of its vertices), with the extra bar
    ``a -> b`` of shift ``(ex, ey)`` (``a = -1``: none), has a cycle of nonzero net lattice
    translation (visit stamp ``st``)."""
    outdeg, outv, outs = g.outdeg, g.outv, g.outs
    roots, seen, stack, par, pot, rank = sc.roots, sc.seen, sc.stack, sc.par, sc.pot, sc.rank
    nv = 0
    for r in range(nroots):
        x = roots[r]
        if seen[x] != st:
            seen[x] = st
            stack[nv] = x
            nv += 1
    i = 0
    while i < nv:
        x = stack[i]
        i += 1
        for s in range(outdeg[x]):
            y = outv[x, s]
            if seen[y] != st:
                seen[y] = st
                stack[nv] = y
                nv += 1
    for i in range(nv):
        x = stack[i]
        par[x] = x
        pot[x, 0] = 0
        pot[x, 1] = 0
        rank[x] = 0
    for i in range(nv + 1):
        if i < nv:
            x = stack[i]
            ns = outdeg[x]
        else:
            ns = 1 if extra_a >= 0 else 0
        for s in range(ns):
            if i < nv:
                a, b, gx, gy = x, outv[x, s], outs[x, s, 0], outs[x, s, 1]
            else:
                a, b, gx, gy = extra_a, extra_b, ex, ey
            ra, pax, pay = _uf_root(a, par, pot)
            rb, pbx, pby = _uf_root(b, par, pot)
            if ra == rb:
                if pbx - pax != gx or pby - pay != gy:
                    return True
            elif rank[ra] >= rank[rb]:   # pot(b) - pot(a) = g
                par[rb] = ra
                pot[rb, 0] = pax + gx - pbx
                pot[rb, 1] = pay + gy - pby
                if rank[ra] == rank[rb]:
                    rank[ra] += 1
            else:
                par[ra] = rb
                pot[ra, 0] = pbx - gx - pax
                pot[ra, 1] = pby - gy - pay
    return False


@numba.njit(cache=True)
def _play(n, kcap, ba, bb, bsx, bsy, periodic):
    """The game over the bars ``(ba, bb)`` with lattice shifts ``(bsx, bsy)`` in order; returns the
    per-bar independence and the :class:`_Graph`."""
    nb = ba.shape[0]
    g = _Graph(kcap, kcap.copy(), np.zeros(n, np.int64), np.full((n, 3), -1, np.int64), np.full((n, 3), -1, np.int64),
               np.zeros((n, 3, 2), np.int64))
    free, outdeg, outv, oute, outs = g.free, g.outdeg, g.outv, g.oute, g.outs
    sc = _scratch(n)
    stamp, roots = sc.stamp, sc.roots
    independent = np.zeros(nb, np.bool_)
    for e in range(nb):
        u, v = ba[e], bb[e]
        have = _gather(u, v, 4, g, sc)
        ok = have >= 4
        if not ok and have == 3 and periodic:
            stamp[0] += 1
            roots[0] = u
            roots[1] = v
            ok = _wraps(2, u, v, bsx[e], bsy[e], g, sc, stamp[0])
        if ok:
            independent[e] = True
            if free[u] > 0:
                t, h, sx, sy = u, v, bsx[e], bsy[e]
            else:
                t, h, sx, sy = v, u, -bsx[e], -bsy[e]
            d = outdeg[t]
            outv[t, d] = h
            oute[t, d] = e
            outs[t, d, 0] = sx
            outs[t, d, 1] = sy
            outdeg[t] = d + 1
            free[t] -= 1
    return independent, g


# long: one numba loop over the contacts (the cluster growth), its state kept in local arrays
@numba.njit(cache=True)
def _clusters(n, contacts, adjacency, g, periodic):
    """Jacobs-Hendrickson decomposition of the played :class:`_Graph` ``g`` over the ``contacts``
    ``(ci, cj)`` with the particles' ``adjacency`` ``(ptr, body, contact)`` (:func:`_adjacency`):
    contact labels (-1: none), and the flat member lists of the clusters
    (``members[ptr[c]:ptr[c + 1]]``)."""
    ci, cj = contacts
    adj_ptr, adj_v, adj_c = adjacency
    kcap, free = g.kcap, g.free
    sc = _scratch(n)
    stamp, roots, nvis, vis = sc.stamp, sc.roots, sc.nvis, sc.vis
    nc = ci.shape[0]
    label = np.full(nc, -1, np.int64)
    processed = np.zeros(nc, np.bool_)
    body_cluster = np.full(n, -1, np.int64)
    in_c = np.full(n, -1, np.int64)
    flop = np.full(n, -1, np.int64)
    queue = np.zeros(n + 1, np.int64)
    members = np.zeros(n + 2 * nc + 1, np.int64)
    ptr = np.zeros(n + nc + 2, np.int64)
    nm = 0
    cid = 0
    for c in range(nc):
        if processed[c]:
            continue
        u, v = ci[c], cj[c]
        if kcap[u] == 3 or kcap[v] == 3:
            b1 = u if kcap[u] == 3 else v
            b2 = -1
            if body_cluster[b1] >= 0:
                processed[c] = True
                continue
        else:
            b1, b2 = u, v
        pinned = _gather(b1, b2, 3, g, sc)
        in_c[b1] = cid
        queue[0] = b1
        nq = 1
        if b2 >= 0:
            in_c[b2] = cid
            queue[1] = b2
            nq = 2
        q = 0
        while q < nq:
            x = queue[q]
            q += 1
            for a in range(adj_ptr[x], adj_ptr[x + 1]):
                w = adj_v[a]
                if in_c[w] == cid or flop[w] == cid:
                    continue
                if free[w] > 0:
                    flop[w] = cid
                    continue
                stamp[0] += 1
                if _search(w, b1, b2, g, sc, stamp[0]):
                    flop[w] = cid
                    continue
                nv = nvis[0]
                if periodic and pinned >= 3:   # a wrapping tight set with a spare pebble flexes
                    stamp[0] += 1
                    roots[0] = w
                    roots[1] = b1
                    roots[2] = b2 if b2 >= 0 else b1
                    if _wraps(3, -1, -1, 0, 0, g, sc, stamp[0]):
                        flop[w] = cid
                        continue
                for t in range(nv):
                    y = vis[t]
                    if in_c[y] != cid:
                        in_c[y] = cid
                        queue[nq] = y
                        nq += 1
        processed[c] = True
        ptr[cid] = nm
        for t in range(nq):
            x = queue[t]
            members[nm] = x
            nm += 1
            if kcap[x] == 3:
                body_cluster[x] = cid
            for a in range(adj_ptr[x], adj_ptr[x + 1]):
                w = adj_v[a]
                if in_c[w] == cid:
                    cc = adj_c[a]
                    label[cc] = cid
                    processed[cc] = True
        cid += 1
    ptr[cid] = nm
    return label, members[:nm], ptr[:cid + 1]


def _adjacency(n, ci, cj):
    """CSR adjacency of the contacts: neighbours and contact ids per vertex."""
    nc = ci.shape[0]
    src = np.concatenate([ci, cj])
    dst = np.concatenate([cj, ci])
    cid = np.concatenate([np.arange(nc), np.arange(nc)])
    order = np.argsort(src, kind="stable")
    ptr = np.zeros(n + 1, np.int64)
    np.add.at(ptr, src + 1, 1)
    return np.cumsum(ptr), dst[order].astype(np.int64), cid[order].astype(np.int64)


# ---- the public API ------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RigidityResult(Result):
    """Constraint counting, floppy modes and rigid clusters of a 2D contact network (pebble game;
    module docstring). Counts are dimensionless integers; fractions and densities are per particle
    of the network (rattlers included in N).

    Attributes
    ----------
    n_particles : int
        N, every particle of the network.
    n_load_bearing : int
        Particles that are not rattlers (the vertices of the game).
    n_bodies : int
        Load-bearing disks with a sticking frictional contact (3 dof each; the others have 2).
    n_contacts : int
        Load-bearing contacts (between two non-rattlers).
    n_dof : int
        Degrees of freedom of the load-bearing particles, ``2 n_load_bearing + n_bodies``.
    n_constraints : int
        Bars: 1 per contact without tangent stiffness, 2 per sticking contact.
    n_independent : int
        Independent constraints (the generic rank of the rigidity matrix).
    n_redundant : int
        Overconstrained (redundant) bars, ``n_constraints - n_independent`` (the states of self-stress).
    n_trivial : int
        Global motions that deform nothing: 2 translations on the torus with the cell fixed, 3 rigid
        motions without a cell (0 without contacts).
    n_floppy : int
        Floppy modes: ``n_dof - n_independent - n_trivial`` (the nontrivial zero-energy motions).
    periodic : bool
        Counted on the torus with the cell fixed (True) or in the plane (False).
    frictional : bool
        At least one sticking contact (the game on bodies, Henkes et al. 2016).
    n_clusters : int
        Rigid clusters of at least two particles.
    largest_cluster : int
        Particles in the largest rigid cluster.
    largest_cluster_fraction : float
        ``largest_cluster / n_particles`` [-].
    floppy_density, redundant_density : float
        ``n_floppy / n_particles``, ``n_redundant / n_particles`` [-].
    contact_cluster : (C,) int
        Rigid cluster of each contact of the network (-1: a rattler's contact, or a hinge between
        two clusters).
    particle_cluster : (N,) int
        Rigid cluster of each particle (the largest, for a joint shared by several; -1: rattler).
    cluster_sizes : (n,) int
        Particles per cluster, indexed by label (singletons included).
    redundant : (C,) bool
        Contacts carrying a redundant bar (for the game's order of the contacts; the count is
        order-independent, which bars are flagged is not).
    rattlers : (N,) bool
        Rattlers (:func:`microhom.structural_sums.rattlers`), outside the game.
    """

    n_particles: int
    n_load_bearing: int
    n_bodies: int
    n_contacts: int
    n_dof: int
    n_constraints: int
    n_independent: int
    n_redundant: int
    n_trivial: int
    n_floppy: int
    periodic: bool
    frictional: bool
    n_clusters: int
    largest_cluster: int
    largest_cluster_fraction: float
    floppy_density: float
    redundant_density: float
    contact_cluster: np.ndarray = field(metadata={"export": False})
    particle_cluster: np.ndarray = field(metadata={"export": False})
    cluster_sizes: np.ndarray = field(metadata={"export": False})
    redundant: np.ndarray = field(metadata={"export": False})
    rattlers: np.ndarray = field(metadata={"export": False})


def _check(network):
    if not isinstance(network, ContactNetwork):
        raise TypeError(f"network must be a microhom.network.ContactNetwork, got {type(network).__name__}")
    if network.dim != 2:
        raise ValueError(f"the pebble game here is for disks (2D networks); network has dimension {network.dim}")


def _game_graph(network, min_contacts):
    """Vertices (load-bearing particles, their pebbles) and bars of the network."""
    ratt, active = rattlers(network, min_contacts)
    idx = np.flatnonzero(active)
    i, j = network.pairs[idx, 0], network.pairs[idx, 1]
    stick = np.asarray(network.effective_kt)[idx] > 0
    N = network.n_particles
    kcap = np.zeros(N, np.int64)
    lb = ~ratt & (np.bincount(np.concatenate([i, j]), minlength=N) > 0)
    kcap[lb] = 2
    body = np.zeros(N, bool)
    body[i[stick]] = True
    body[j[stick]] = True
    kcap[body] = 3
    shifts = np.asarray(network.image_shifts(), dtype=np.int64)[idx]
    reps = np.where(stick, 2, 1)
    bar_contact = np.repeat(np.arange(idx.size), reps)
    return ratt, idx, i, j, kcap, lb, body, shifts, bar_contact


def pebble_game(network: ContactNetwork, *, min_contacts=None) -> RigidityResult:
    """Floppy modes, redundant constraints and rigid clusters of a 2D contact network by the pebble
    game (module docstring): frictionless contacts and sliding ones (``effective_kt == 0``) are one
    bar, sticking ones two; rattlers (``min_contacts``: as
    :func:`microhom.structural_sums.rattlers`) are left out. Periodic networks are counted on the
    torus with the cell fixed. The counts are the generic rank: where disk geometry is special
    (straight rows of contacts, gears of bipartite sticking rings, ``docs/theory.md`` section 11)
    the numerical rank is lower. Cost once compiled: N = 1000 packings in 0.002-0.07 s, N = 4000
    in 0.02-0.6 s; on rigid networks it grows about as N^1.9 (25600 disks: 9-19 s)."""
    _check(network)
    N = network.n_particles
    ratt, idx, i, j, kcap, lb, body, shifts, bar_contact = _game_graph(network, min_contacts)
    periodic = network.cell is not None
    ba, bb = i[bar_contact], j[bar_contact]
    indep, g = _play(N, kcap, ba.astype(np.int64), bb.astype(np.int64), shifts[bar_contact, 0].copy(),
                     shifts[bar_contact, 1].copy(), periodic)
    adj_ptr, adj_v, adj_c = _adjacency(N, i.astype(np.int64), j.astype(np.int64))
    lab, members, ptr = _clusters(N, (i.astype(np.int64), j.astype(np.int64)), (adj_ptr, adj_v, adj_c), g,
                                  periodic)
    contact_cluster = np.full(network.n_contacts, -1, np.int64)
    contact_cluster[idx] = lab
    sizes = np.diff(ptr)
    particle_cluster = np.full(N, -1, np.int64)
    cl_of_member = np.repeat(np.arange(sizes.size), sizes)
    order = np.argsort(sizes[cl_of_member], kind="stable")     # largest cluster written last wins
    particle_cluster[members[order]] = cl_of_member[order]
    alone = lb & (particle_cluster < 0)                          # a joint held by no cluster
    particle_cluster[alone] = sizes.size + np.arange(int(alone.sum()))
    sizes = np.concatenate([sizes, np.ones(int(alone.sum()), np.int64)])
    n_dof = int(kcap.sum())
    n_ind = int(indep.sum())
    n_triv = 0 if idx.size == 0 else (2 if periodic else 3)
    redundant = np.zeros(network.n_contacts, bool)
    redundant[idx[np.unique(bar_contact[~indep])]] = True
    n_floppy = n_dof - n_ind - n_triv
    largest = int(sizes.max()) if sizes.size else 0
    return RigidityResult(
        n_particles=N, n_load_bearing=int(lb.sum()), n_bodies=int(body.sum()), n_contacts=int(idx.size),
        n_dof=n_dof, n_constraints=int(ba.size), n_independent=n_ind, n_redundant=int(ba.size) - n_ind,
        n_trivial=n_triv, n_floppy=n_floppy, periodic=periodic, frictional=bool(body.any()),
        n_clusters=int((sizes >= 2).sum()), largest_cluster=largest, largest_cluster_fraction=largest / max(N, 1),
        floppy_density=n_floppy / max(N, 1), redundant_density=(int(ba.size) - n_ind) / max(N, 1),
        contact_cluster=contact_cluster, particle_cluster=particle_cluster, cluster_sizes=sizes,
        redundant=redundant, rattlers=ratt)


def rigidity_matrix(network: ContactNetwork, *, min_contacts=None):
    """The rigidity (compatibility) matrix the game counts, from :mod:`microhom.kinematics`:
    rows the normal relative displacement of every load-bearing contact and the tangential one of
    every sticking contact (``Delta = B q`` at zero strain, cell fixed); columns the translations
    of the load-bearing particles and the spins of the bodies. Returns (R (rows, n_dof) CSR
    [1 for translations, m for spins], n_trivial)."""
    from .kinematics import contact_matrices
    _check(network)
    N = network.n_particles
    ratt, idx, i, j, kcap, lb, body, shifts, bar_contact = _game_graph(network, min_contacts)
    net = network.select_contacts(np.isin(np.arange(network.n_contacts), idx))
    B = contact_matrices(net).B                                 # (C, 2, 6) on (u_i, w_i, u_j, w_j)
    n = net.normals
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    dof = np.full(3 * N, -1, np.int64)
    tr = np.flatnonzero(lb)
    dof[2 * tr], dof[2 * tr + 1] = 2 * np.arange(tr.size), 2 * np.arange(tr.size) + 1
    dof[2 * N + np.flatnonzero(body)] = 2 * tr.size + np.arange(int(body.sum()))
    ldof = np.stack([dof[2 * i], dof[2 * i + 1], dof[2 * N + i], dof[2 * j], dof[2 * j + 1], dof[2 * N + j]], axis=1)
    rn = np.einsum("ca,cak->ck", n, B)
    rt = np.einsum("ca,cak->ck", t, B)
    stick = np.asarray(net.effective_kt) > 0
    rows = np.concatenate([rn, rt[stick]])
    cols = np.concatenate([ldof, ldof[stick]])
    r = np.repeat(np.arange(rows.shape[0]), 6)
    keep = cols.ravel() >= 0
    R = sp.csr_matrix((rows.ravel()[keep], (r[keep], cols.ravel()[keep])),
                      shape=(rows.shape[0], int(kcap.sum())))
    n_triv = 0 if idx.size == 0 else (2 if network.cell is not None else 3)
    return R, n_triv


def numerical_floppy_modes(network: ContactNetwork, *, min_contacts=None, rtol=1e-9) -> tuple[int, int]:
    """(floppy modes, redundant constraints) from the singular values of the dense
    :func:`rigidity_matrix` (an independent check of :func:`pebble_game`; small networks only:
    cost O(n_dof^3)). Columns are scaled to unit norm; a singular value below ``rtol`` times the
    largest counts as zero."""
    R, n_triv = rigidity_matrix(network, min_contacts=min_contacts)
    A = R.toarray()
    if A.size == 0:
        return A.shape[1] - n_triv, A.shape[0]
    A = A / np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    s = np.linalg.svd(A, compute_uv=False)
    rank = int((s > rtol * s[0]).sum())
    return A.shape[1] - rank - n_triv, A.shape[0] - rank
