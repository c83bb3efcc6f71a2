"""The two-level statics' faster setup (issue 26; microhom.dual_bound): each shortcut against a
plain, independent computation of what it stands for.

- a unit's load test (``_try_unit``): the Gram shortcut (``_clear_accept``) and the counting rule
  (``_short``) against the eigenvalues of ``A Kl A^T`` (numpy) on the unit's matrices;
- ``_regular`` recomputed at a few particles against a full recomputation;
- the seed trimming against a plain trimming that computes the rank (numpy) of every ball;
- the row argmax against scipy's, the block-diagonal CSR against scipy's ``block_diag``;
- the unwrap's continuation against a plain breadth-first walk in Python.
"""
import numpy as np
import pytest
import scipy.sparse as sps

from microhom import dual_bound as db
from microhom.kinematics import assemble, rotational_dofs
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular

NETS = {"2D": diluted_triangular(300, z=4.6, kt=0.5, seed=1),
        "3D": fcc_network(256, keep=0.65, kt=0.5, seed=2)}
_f = NETS["3D"]
NETS["3D sliding"] = _f.with_stiffness(sliding=np.random.default_rng(3).random(_f.n_contacts) < 0.15)


def _graph(net):
    """The :class:`_Graph` build_equilibrator makes of ``net`` (all contacts but self-images usable)."""
    asm = assemble(net, pin=False)
    N, d = asm.net.n_particles, asm.net.dim
    pairs = np.ascontiguousarray(asm.net.pairs, dtype=np.int64)
    Q, nk, Kq = db._force_basis(asm)
    pdof = db._particle_dofs(asm)
    ptr, adj_e, adj_s, adj_q = db._adjacency(pairs, N)
    return db._Graph(ptr, adj_e, adj_s, adj_q, pairs[:, 0] != pairs[:, 1], pdof, pairs,
                     np.ascontiguousarray(asm.matrices.B), Q, nk, Kq, d + rotational_dofs(d)), asm


def _plain_accept(mem, idx, before, g):
    """The unit test by numpy's eigenvalues of ``A Kl A^T`` (``_unit_local``'s matrices)."""
    slot = np.full(g.pdof.shape[0], -1, np.int64)
    slot[mem] = np.arange(len(mem))
    A, Kl, _, _ = db._unit_local(np.asarray(mem, np.int64), slot, idx, before, g)
    if A.shape[0] == 0 or A.shape[1] < A.shape[0]:
        return False
    M = A @ Kl @ A.T
    w = np.linalg.eigvalsh(0.5 * (M + M.T))
    return bool(w[0] > db._ACCEPT * w[-1])


def _units(g, rng, n=300):
    """Random units of one to four neighbouring particles."""
    N = g.pdof.shape[0]
    out = []
    for _ in range(n):
        mem = [int(rng.integers(N))]
        for _ in range(int(rng.integers(0, 4))):
            p = mem[int(rng.integers(len(mem)))]
            nb = [int(q) for q in g.adj_q[g.ptr[p]:g.ptr[p + 1]] if int(q) not in mem]
            if nb:
                mem.append(nb[int(rng.integers(len(nb)))])
        out.append(np.array(mem, np.int64))
    return out


@pytest.mark.parametrize("name", list(NETS))
def test_unit_test_as_the_eigenvalues(name):
    """``_try_unit`` answers as the eigenvalue test on random units and random built sets (both
    answers occur); a unit ``_short`` calls short has a rank-deficient ``A`` (numpy's rank)."""
    g, _ = _graph(NETS[name])
    N = g.pdof.shape[0]
    rng = np.random.default_rng(0)
    seen, short = set(), 0
    for frac in (0.0, 0.4, 0.7):
        idx = np.where(rng.random(N) < frac, 5, 0).astype(np.int64)
        for mem in _units(g, rng):
            idx_u = idx.copy()
            idx_u[mem] = 1 << 60
            slot = np.full(N, -1, np.int64)
            want = _plain_accept(mem, idx_u, 1, g)
            assert db._try_unit(mem, slot, idx_u, 1, g) == want, mem
            assert (slot == -1).all()
            seen.add(want)
            slot[mem] = np.arange(len(mem))
            if db._short(mem, slot, idx_u, 1, g):
                short += 1
                A = db._unit_local(mem, slot, idx_u, 1, g)[0]
                assert A.shape[0] == 0 or np.linalg.matrix_rank(A) < A.shape[0], mem
    assert seen == {True, False} and short > 0


def test_clear_accept_agrees_with_the_eigenvalues():
    """Where the Gram shortcut decides, it answers ``w_min > _ACCEPT w_max`` as numpy's eigenvalues
    do, on random positive semi-definite matrices with eigenvalue ratios around the threshold;
    both clear answers and the undecided band occur."""
    rng = np.random.default_rng(1)
    got = set()
    for k in range(3000):
        n = int(rng.integers(1, 13))
        V = np.linalg.qr(rng.normal(size=(n, n)))[0]
        w = rng.uniform(1, 2, n) * 10.0 ** rng.uniform(-1, 3)
        w[0] = w.max() * db._ACCEPT * 10.0 ** rng.uniform(-2, 2) * (k % 7 != 0)
        M = (V * w) @ V.T
        M = 0.5 * (M + M.T)
        c = db._clear_accept(M)
        got.add(int(c))
        if c >= 0:
            ev = np.linalg.eigvalsh(M)
            assert bool(c) == bool(ev[0] > db._ACCEPT * ev[-1]), (ev[0] / ev[-1], c)
    assert got == {-1, 0, 1}


@pytest.mark.parametrize("name", list(NETS))
def test_regular_recomputed_where_contacts_change(name):
    """``_regular`` at the particles whose usable contacts changed, from the answer on all
    contacts, equals a full recomputation after dropping a third of the contacts."""
    g, _ = _graph(NETS[name])
    neq = (g.pdof >= 0).sum(axis=1)
    full = db._regular(neq, g)
    keep = g.usable & (np.random.default_rng(2).random(len(g.usable)) < 0.67)
    g2 = g._replace(usable=keep)
    cut = np.zeros(len(neq), bool)
    cut[g.pairs[g.usable & ~keep].ravel()] = True
    assert np.array_equal(db._regular(neq, g2, np.flatnonzero(cut), full), db._regular(neq, g2))
    assert not np.array_equal(db._regular(neq, g2), full)


def _plain_trim(ball, g, rigid):
    """Trim by computing the rank (numpy) of every ball: drop the member with the fewest usable
    contacts inside (a contact with its own image once) until rank = unknowns - ``rigid``."""
    ball = list(ball)
    while len(ball) >= 2:
        A, Kl, se, sd = db._seed_matrix(np.array(ball, np.int64), g)
        if len(se):
            w = np.linalg.eigvalsh(A @ Kl @ A.T)
            if int((w > db._RANK_TOL * w.max()).sum()) == len(sd) - rigid:
                return ball
        inner = [sum(1 for e in range(len(g.pairs)) if g.usable[e] and (g.pairs[e] == p).any()
                     and g.pairs[e, 0] in ball and g.pairs[e, 1] in ball) for p in ball]
        ball.pop(int(np.argmin(inner)))
    return None


@pytest.mark.parametrize("name", list(NETS))
def test_trimmed_as_the_plain_trimming(name):
    """The seed trimming (which skips the rank of balls short by counting) returns the ball the
    plain trimming returns, from balls around several particles (some trimmed a lot)."""
    g, asm = _graph(NETS[name])
    d = asm.net.dim
    rigid = d + rotational_dofs(d)
    regular = np.ones(g.pdof.shape[0], bool)
    trims = 0
    for start in range(0, g.pdof.shape[0], max(1, g.pdof.shape[0] // 6)):
        ball = db._ball(start, 30 if d == 3 else 12, g.ptr, g.adj_q, regular)
        want = _plain_trim(ball, g, rigid)
        got = db._trimmed(list(ball), g, rigid)
        assert (got is None) == (want is None)
        if want is not None:
            assert np.array_equal(got, want)
            trims += len(ball) - len(want)
    assert trims > 0


def test_argmax_rows_as_scipy():
    """Row argmax as scipy's ``argmax(axis=1)``: duplicates, explicit zeros, negative values,
    empty and full rows."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        n, m = int(rng.integers(1, 9)), int(rng.integers(1, 7))
        k = int(rng.integers(0, 3 * n * m))
        v = rng.choice([-2.0, -1.0, 0.0, 1.0, 2.0, 3.0], size=k)
        M = sps.coo_matrix((v, (rng.integers(0, n, k), rng.integers(0, m, k))), shape=(n, m)).tocsr()
        want = np.asarray(M.copy().argmax(axis=1)).ravel()
        assert np.array_equal(db._argmax_rows(M), want)
    full = sps.csr_matrix(np.array([[0.0, -1.0], [-3.0, -2.0]]))
    assert np.array_equal(db._argmax_rows(full), np.asarray(full.argmax(axis=1)).ravel())


def test_block_diag_as_scipy():
    """The seeds' block-diagonal CSR: scipy's ``block_diag`` arrays (zeros stored alike)."""
    rng = np.random.default_rng(5)
    mats = [np.where(rng.random((a, b)) < 0.3, 0.0, rng.normal(size=(a, b)))
            for a, b in rng.integers(1, 6, size=(7, 2))]
    got, want = db._block_diag(mats), sps.block_diag(mats, format="csr")
    assert got.shape == want.shape
    for k in ("data", "indices", "indptr"):
        assert np.array_equal(getattr(got, k), getattr(want, k)), k


def test_unwrap_as_a_plain_walk():
    """The unwrap's positions on a network's contacts inside boxes: where the network is a tree
    (no wrap), each particle at its breadth-first parent's position plus the branch vector, as a
    plain Python walk from the same roots; the contacts it keeps satisfy ``x_j - x_i = c_ij``."""
    net = NETS["3D"]
    N = net.n_particles
    lab = db._box_labels(net, 30)
    inner = (lab[net.pairs[:, 0]] == lab[net.pairs[:, 1]]) & (net.pairs[:, 0] != net.pairs[:, 1])
    x, ok = db._unwrap(net, inner, N)
    e = np.flatnonzero(ok)
    c = np.asarray(net.branch)
    assert len(e) > 0.9 * inner.sum()
    assert np.abs(x[net.pairs[e, 1]] - x[net.pairs[e, 0]] - c[e]).max() <= 1e-9
    # a plain walk along the kept contacts' spanning forest reproduces x from the roots
    y = np.full_like(x, np.nan)
    adj = {p: [] for p in range(N)}
    for k in e:
        i, j = net.pairs[k]
        adj[i].append((j, c[k]))
        adj[j].append((i, -c[k]))
    for r in range(N):
        if np.isnan(y[r, 0]):
            y[r] = x[r]
            todo = [r]
            while todo:
                p = todo.pop()
                for q, step in adj[p]:
                    if np.isnan(y[q, 0]):
                        y[q] = y[p] + step
                        todo.append(q)
    assert np.allclose(y, x, atol=1e-9)


def test_continue_as_a_loop():
    """The continuation kernel as the Python loop it replaced, bit for bit."""
    rng = np.random.default_rng(6)
    n = 50
    pr = np.array([int(rng.integers(0, k)) for k in range(1, n)])
    ch = np.arange(1, n)
    step = rng.normal(size=(n - 1, 3))
    order = rng.permutation(n - 1)
    order = order[np.argsort(ch[order], kind="stable")]          # a parent before its children
    x = rng.normal(size=(n, 3))
    y = x.copy()
    for k in order:
        y[ch[k]] = y[pr[k]] + step[k]
    db._continue(x, ch, pr, step, order)
    assert np.array_equal(x, y)
