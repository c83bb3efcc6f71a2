"""The dual bound's sums over contacts taken chunk by chunk and the statics' loads a few columns at a
time (microhom.dual_bound ``CHUNK``, ``TWO_COLS``; issue 26: the transient memory at 1e6 spheres).

Checked against the same bound with every sum in one chunk (each dot product of length d C summed in
pieces only reorders the round-off: the tensors agree to 1e-12), against the exact sparse solver
(dem.analysis.stiffness: still a lower bound in the Loewner order) and against the statics taking all
columns at once."""
import numpy as np
import pytest

import microhom.dual_bound as db
from dem.analysis.stiffness import stiffness
from microhom.dual_bound import build_equilibrator, dual_lower_bound
from microhom.kinematics import assemble
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular


def _nets():
    tri = diluted_triangular(300, z=4.6, kt=0.5, seed=1)
    rng = np.random.default_rng(3)
    tri_s = tri.with_stiffness(sliding=rng.random(tri.n_contacts) < 0.15)
    return {"2D sliding": (tri_s, None), "3D": (fcc_network(100, keep=0.65, kt=0.5, seed=2), None),
            "3D two-level": (fcc_network(500, keep=0.65, kt=0.5, seed=2), 50)}


NETS = _nets()


def _setup(name):
    net, clusters = NETS[name]
    asm = assemble(net, prestress=False, pin=False)
    eq = build_equilibrator(asm, clusters=clusters) if clusters else build_equilibrator(asm)
    assert (eq.n_clusters > 0) == bool(clusters)
    X = np.linalg.lstsq(asm.H.toarray(), -asm.F, rcond=None)[0]
    return net, asm, eq, X


@pytest.mark.parametrize("name", list(NETS))
def test_chunked_sums_give_the_one_chunk_bound(name, monkeypatch):
    """With 7 contacts a chunk (tens of chunks) the bound, its gap and margin are those of one chunk to
    round-off, and the bound stays below the exact tensor, with or without a trial span."""
    net, asm, eq, X = _setup(name)
    ex = stiffness(net)
    rng = np.random.default_rng(5)
    Xp = X * (1 + 1e-2 * rng.normal(size=X.shape))
    W = [rng.normal(size=(asm.ndof, 3)), X - Xp]
    assert asm.net.n_contacts < db.CHUNK
    for kw in ({}, dict(trial=W)):
        one = dual_lower_bound(asm, Xp, net.volume, eq, **kw)
        with monkeypatch.context() as mp:
            mp.setattr(db, "CHUNK", 7)
            many = dual_lower_bound(asm, Xp, net.volume, eq, **kw)
        scale = np.abs(one.C_lower).max()
        assert np.abs(many.C_lower - one.C_lower).max() <= 1e-12 * scale, kw
        assert np.abs(many.gap - one.gap).max() <= 1e-12 * np.abs(one.gap).max() + 1e-300
        assert 0.5 * one.margin <= many.margin <= 2 * one.margin
        for b in (one, many):
            assert b.valid
            w = np.linalg.eigvalsh(ex.C_mandel - b.C_lower)
            assert w.min() >= -1e-10 * np.abs(ex.C_mandel).max(), (kw, w.min())


def test_chunks_cover_the_contacts(monkeypatch):
    """The contact ranges cover every contact once, in order, at most CHUNK each (one empty range
    for no contact); the compliance of a range is that range of the whole."""
    monkeypatch.setattr(db, "CHUNK", 2)
    assert db._chunks(0) == [(0, 0)]
    assert db._chunks(5) == [(0, 2), (2, 4), (4, 5)]
    assert db._chunks(4) == [(0, 2), (2, 4)]
    for name in ("2D sliding", "3D"):
        asm = assemble(NETS[name][0], prestress=False, pin=False)
        assert np.allclose(db._compliance(asm, 3, 10), db._compliance(asm)[3:10], rtol=1e-15, atol=0)


@pytest.mark.parametrize("name", list(NETS))
def test_statics_columns_alone(name):
    """The statics in groups of columns (2 in the two-level 3D statics, else 6) balances each load as
    all columns at once do, to round-off."""
    net, asm, eq, _ = _setup(name)
    assert eq.group == (db.TWO_COLS if name == "3D two-level" else 6)
    r = np.asarray(asm.Bs.T @ np.random.default_rng(2).normal(size=(asm.Bs.shape[0], 7)))
    c = eq.correct(r)
    for k in (1, 7):
        c2 = eq.correct(r, chunk=k)
        assert np.abs(c2 - c).max() <= 1e-12 * np.abs(c).max()
    res = np.asarray(asm.Bs.T @ c.reshape(-1, 7)) - r
    assert np.abs(res).max() <= 1e-11 * np.abs(r).max()


def test_coarse_forces_by_chunks_bit_for_bit(monkeypatch):
    """The two-level statics' coarse forces ``K B u`` taken CHUNK contacts' rows at a time (and
    added in place) are ``Ks @ (Bs @ u)`` to the last bit, and the statics' corrections with tiny
    chunks equal those with one chunk."""
    net, asm, eq, _ = _setup("3D two-level")
    T = eq._data["two"]
    u = np.random.default_rng(4).normal(size=(asm.ndof, 5))
    ref = np.asarray(T["Ks"] @ (T["Bs"] @ u))
    r = np.asarray(asm.Bs.T @ np.random.default_rng(6).normal(size=(asm.Bs.shape[0], 6)))
    c_one = eq.correct(r)
    monkeypatch.setattr(db, "CHUNK", 7)
    out = np.empty_like(ref)
    db._coarse_forces(T, u, out)
    assert np.array_equal(out, ref)
    db._coarse_forces(T, u, out, add=True)
    assert np.array_equal(out, ref + ref)
    assert np.array_equal(eq.correct(r), c_one)
