"""The dual bound's two-level statics (microhom.dual_bound ``build_equilibrator(clusters=...)``;
docs/theory.md section 12, "Two-level statics"): clusters of bounded size, each carried to its
own seed, after a coarse equilibrium step on the clusters' rigid motions.

Checked against what it does not use: the assembly's own ``B^T`` for the equilibrium, the exact
sparse solver (dem.analysis.stiffness) for the bound, an exact factorisation of ``H`` for the
least possible gap ``r^T H^+ r`` of the amplification; the coarse step and the clusters are each
shown to matter (without the coarse step the field is not balanced; one cluster is the one-seed
statics)."""
import numpy as np
import pytest

from dem.analysis.stiffness import stiffness
from microhom import factor as fa
from microhom.dual_bound import _compliance, build_equilibrator, dual_lower_bound
from microhom.kinematics import assemble
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular

#: (network, particles per cluster): several clusters in each (at least 2 boxes per axis)
CASES = {"2D": (diluted_triangular(400, z=4.6, kt=0.5, seed=1), 40),
         "3D": (fcc_network(256, keep=0.65, kt=0.5, seed=2), 30)}
_f = CASES["3D"][0]
CASES["3D sliding"] = (_f.with_stiffness(sliding=np.random.default_rng(3).random(_f.n_contacts) < 0.15), 30)


def _loads(asm, k=4, seed=0):
    """Loads in the range of ``B^T``: random contact forces' and the affine load ``-F``."""
    g = np.random.default_rng(seed).normal(size=(asm.Bs.shape[0], k))
    return np.hstack([np.asarray(asm.Bs.T @ g), -asm.F])


def _imaged(net, seed=1):
    """The same network with each particle represented by a random periodic image."""
    rng = np.random.default_rng(seed)
    k = rng.integers(-1, 2, size=net.positions.shape)
    return net.__class__(positions=net.positions + k @ np.asarray(net.cell).T, radii=net.radii, cell=net.cell,
                         pairs=net.pairs, branch=net.branch, kn=net.kn, kt=net.kt, sliding=net.sliding)


@pytest.mark.parametrize("name", list(CASES))
def test_two_level_correction_is_in_equilibrium(name):
    """B^T c = r to round-off with several clusters, whatever image of the periodic cell holds each
    particle (the clusters at the cell's boundary are continued along their contacts); without
    the coarse step the clusters' statics cannot balance the loads."""
    net, size = CASES[name]
    for n2 in (net, _imaged(net)):
        asm = assemble(n2, pin=False)
        eq = build_equilibrator(asm, clusters=size)
        assert eq.n_clusters >= 2 ** n2.dim, eq
        r = _loads(asm)
        c = eq.correct(r)
        res = np.asarray(asm.Bs.T @ c.reshape(-1, r.shape[1])) - r
        assert np.abs(res).max() <= 1e-9 * np.abs(r).max(), np.abs(res).max() / np.abs(r).max()
    two = eq._data["two"]
    keep = two["solve"]
    try:                                   # the coarse step a no-op: the clusters' net loads stay
        two["solve"] = lambda z: np.zeros_like(z)
        c0 = eq.correct(r)
    finally:
        two["solve"] = keep
    res0 = np.asarray(asm.Bs.T @ c0.reshape(-1, r.shape[1])) - r
    assert np.abs(res0).max() >= 1e-3 * np.abs(r).max()


@pytest.mark.parametrize("name", list(CASES))
def test_two_level_bound_below_exact(name):
    """The bound with the two-level statics is valid, below the exact tensor in the Loewner order
    for poor and good trial relaxations, and tight at the exact relaxation."""
    net, size = CASES[name]
    ex = stiffness(net)
    asm = assemble(net, pin=False)
    eq = build_equilibrator(asm, clusters=size)
    X = np.linalg.lstsq(asm.H.toarray(), -asm.F, rcond=None)[0]
    rng = np.random.default_rng(5)
    for pert in (0.0, 1e-3, 0.3):
        b = dual_lower_bound(asm, X * (1 + pert * rng.normal(size=X.shape)), net.volume, eq)
        assert b.valid, (pert, b.residual)
        w = np.linalg.eigvalsh(ex.C_mandel - b.C_lower)
        assert w.min() >= -1e-10 * np.abs(ex.C_mandel).max(), (pert, w.min())
        if pert == 0.0:
            assert abs(b.K_lower - ex.K) <= 1e-6 * ex.K and abs(b.G_lower - ex.G) <= 1e-6 * ex.G


def test_clusters_argument_checked():
    asm = assemble(CASES["2D"][0], pin=False)
    for bad in (0, 7, 2.5, "100", True):
        with pytest.raises(ValueError, match="clusters must be None or an integer >= 8"):
            build_equilibrator(asm, clusters=bad)
    eq = build_equilibrator(asm, clusters=10 ** 6)     # fewer than 2^d clusters: the one-seed statics
    assert eq.n_clusters == 0


def _amplification(asm, eq, r, z):
    c = eq.correct(r)
    gap = np.einsum("cxs,cxy,cys->s", c, _compliance(asm), c)
    return gap / np.einsum("ij,ij->j", r, z)


def test_two_level_amplification_smaller():
    """On 4000 spheres the one-seed statics' gap is 1e4-1e6 times the least possible r^T H^+ r
    (an exact factorisation of the pinned H); the two-level statics' (clusters of about 400) is at
    least 5 times smaller in total over the loads, random and affine."""
    net = fcc_network(4000)
    asm = assemble(net, pin=False)
    r = _loads(asm, k=2)
    N, d = net.n_particles, net.dim
    keep = np.ones(asm.ndof, bool)
    p0 = int(np.argmax(np.bincount(asm.net.pairs.ravel(), minlength=N)))
    keep[asm.dof_map[d * p0:d * p0 + d]] = False
    f = fa.factor(asm.H[keep][:, keep].tocsc(), spd=True, dim=3)
    z = np.zeros_like(r)
    z[keep] = np.asarray(f.solve(r[keep])).reshape(z[keep].shape)
    one = _amplification(asm, build_equilibrator(asm), r, z)
    two = _amplification(asm, build_equilibrator(asm, clusters=400), r, z)
    assert one.min() > 1e3
    assert two.sum() * 5 <= one.sum(), (one, two)


def test_hierarchy_default_two_level_interval_holds_exact(monkeypatch):
    """The hierarchy's default in 3D (``DUAL_CLUSTERS``) on 500 spheres (8 clusters): certified
    to ``tol``, and the interval holds the exact solver's K and G."""
    import microhom.hierarchy as hi
    seen = []

    def record(asm, **kw):
        eq = build_equilibrator(asm, **kw)
        seen.append(eq.n_clusters)
        return eq
    monkeypatch.setattr(hi, "build_equilibrator", record)
    net = fcc_network(500)
    ex = stiffness(net)
    h = hi.relaxation_hierarchy(net, tol=1e-3, soft_modes=0, spectral_bound="none", dual_bound=True)
    assert hi.DUAL_CLUSTERS is not None and seen and seen[0] >= 8, seen
    assert h.valid, h.reasons
    assert h.K.lower <= ex.K * (1 + 1e-12) and ex.K <= h.K.upper * (1 + 1e-12)
    assert h.G.lower <= ex.G * (1 + 1e-12) and ex.G <= h.G.upper * (1 + 1e-12)
    assert h.K.upper - h.K.lower <= 1e-3 * h.K.upper and h.G.upper - h.G.lower <= 1e-3 * h.G.upper


def test_bench_statics_rows():
    """The amplification study on 500 spheres: finite amplifications, balanced corrections, and
    the two-level construction order shallower than the one-seed one; bench_spheres refuses a
    cluster size below 8."""
    from studies import bench_spheres, bench_statics
    (rows,) = bench_statics.main(["--n", "500", "--clusters", "60"])
    one, two = rows
    assert one["clusters"] is None and two["clusters"] == 60 and two["n_clusters"] >= 8
    for r in rows:
        assert np.all(np.isfinite(r["amp"])) and np.all(r["amp"] > 0.99) and r["residual"] <= 1e-8
    assert two["depth_max"] < one["depth_max"]
    with pytest.raises(SystemExit):
        bench_spheres.main(["--n", "100", "--exact", "no", "--dual-clusters", "3"])


def test_coarse_solver_without_the_assemblys_h():
    """The relaxation hierarchy drops the assembly's H in its lean 3D path (microhom.shared_h);
    the two-level statics' coarse matrix is then ``R^T Bs^T Ks Bs R``: the same field to
    round-off, balanced."""
    from dataclasses import replace
    net, size = CASES["3D sliding"]
    asm = assemble(net, pin=False)
    r = _loads(asm)
    c = build_equilibrator(asm, clusters=size).correct(r)
    c2 = build_equilibrator(replace(asm, H=None), clusters=size).correct(r)
    res = np.asarray(asm.Bs.T @ c2.reshape(-1, r.shape[1])) - r
    assert np.abs(res).max() <= 1e-9 * np.abs(r).max()
    assert np.abs(c2 - c).max() <= 1e-8 * np.abs(c).max()
