"""The dual bound's statics: how much it amplifies a residual, one seed against the two-level
statics (issue 26; docs/results/spheres.md, "A statics of bounded depth").

    python -m studies.bench_statics [--n 1400 4000 10000 32000] [--clusters 200 400 1000]
                                    [--exact-max 20000]

On the benchmark's built network (``studies.bench_spheres.fcc_network``), for residuals ``r`` (the
multilevel block CG's at orders 2, 3 and 4, first two Mandel columns, and two random loads
``B^T g``) the gap of the statics' correction ``c`` (``B^T c = r``), ``c^T K^+ c``, over the least
possible one, ``r^T H^+ r`` (an exact factorisation of ``H`` pinned at one sphere up to
``--exact-max`` spheres, else CG preconditioned by the V-cycle to a relative residual of 1e-12).
Per statics: the setup's CPU time, the depth of the construction order (a unit's depth is one
more than the deepest unit its parent contacts reach; the seeds 0), the clusters, the particles
that are a cluster of their own, the coarse unknowns, each residual's amplification and their
geometric mean. One process; set ``NUMBA_NUM_THREADS=1`` and one BLAS thread for CPU times.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse.linalg as spla

from microhom import factor as fa
from microhom.dual_bound import _compliance, build_equilibrator
from microhom.hierarchy import _BlockPCG, block_preconditioner
from microhom.kinematics import assemble
from microhom.multilevel import amg_preconditioner
from studies.bench_spheres import fcc_network


def depths(eq) -> np.ndarray:
    """Depth of each unit of the construction order of ``eq`` (one seed or two-level)."""
    D = eq._data["two"]["local"] if eq._data.get("two") is not None else eq._data
    pptr, pe, rptr, rdof, _, _ = D["tree"]
    g = D["graph"]
    N = g.pdof.shape[0]
    dof2p = np.full(g.pdof.max() + 1, -1)
    for k in range(g.pdof.shape[1]):
        ok = g.pdof[:, k] >= 0
        dof2p[g.pdof[ok, k]] = np.flatnonzero(ok)
    n = D["n_tree"]
    unit = np.full(N, -1)
    for a in range(n):
        unit[np.unique(dof2p[rdof[rptr[a]:rptr[a + 1]]])] = a
    dep = np.zeros(n, np.int64)
    for a in range(n):
        ends = unit[g.pairs[pe[pptr[a]:pptr[a + 1]]].ravel()]
        ends = ends[(ends >= 0) & (ends < a)]
        dep[a] = 1 + (dep[ends].max() if len(ends) else 0)
    return dep


def residuals(asm, orders=(2, 3, 4), cols=2, seed=0):
    """The CG residuals at ``orders`` (first ``cols`` Mandel columns) and two random loads."""
    P, _ = amg_preconditioner(asm)
    M = block_preconditioner(asm)[0]
    cg = _BlockPCG(asm.H, M, P, -asm.F, full=True)
    R = []
    for k in range(1, max(orders) + 1):
        cg.step()
        if k in orders:
            R.append((-asm.F - asm.H @ cg.X)[:, :cols])
    g = np.random.default_rng(seed).normal(size=(asm.Bs.shape[0], 2))
    R.append(np.asarray(asm.Bs.T @ g))
    return np.hstack(R), P


def least(asm, R, P, exact):
    """``r^T H^+ r`` per column of ``R``."""
    net = asm.net
    N, d = net.n_particles, net.dim
    if exact:
        keep = np.ones(asm.ndof, bool)
        p0 = int(np.argmax(np.bincount(net.pairs.ravel(), minlength=N)))
        keep[asm.dof_map[d * p0:d * p0 + d]] = False
        f = fa.factor(asm.H[keep][:, keep].tocsc(), spd=True, dim=d)
        z = np.zeros_like(R)
        z[keep] = np.asarray(f.solve(R[keep])).reshape(z[keep].shape)
    else:
        Pop = spla.LinearOperator(asm.H.shape, matvec=lambda v: np.asarray(P @ v.reshape(-1, 1)).ravel())
        z = np.column_stack([spla.cg(asm.H, R[:, j], M=Pop, rtol=1e-12, maxiter=2000)[0]
                             for j in range(R.shape[1])])
    return np.einsum("ij,ij->j", R, z)


def amplification(asm, eq, R, lst):
    c = eq.correct(R)
    gap = np.einsum("cxs,cxy,cys->s", c, _compliance(asm), c)
    res = np.abs(np.asarray(asm.Bs.T @ c.reshape(-1, R.shape[1])) - R).max() / np.abs(R).max()
    return gap / lst, res


def run(n, clusters, exact_max):
    net = fcc_network(n)
    asm = assemble(net, prestress=False, pin=False)
    R, P = residuals(asm)
    lst = least(asm, R, P, net.n_particles <= exact_max)
    rows = []
    for cl in [None] + list(clusters):
        t = time.process_time()
        eq = build_equilibrator(asm, clusters=cl)
        ts = time.process_time() - t
        a, res = amplification(asm, eq, R, lst)
        dep = depths(eq)
        st = eq._data["two"]["stats"] if eq._data.get("two") is not None else {}
        row = dict(N=net.n_particles, ndof=asm.ndof, clusters=cl, setup_cpu=ts, n_clusters=eq.n_clusters,
                   alone=st.get("n_alone", 0), coarse=st.get("coarse_dofs", 0), depth_max=int(dep.max()),
                   depth_mean=float(dep.mean()), residual=res, amp=a, amp_gmean=float(np.exp(np.log(a).mean())))
        print(f"N {row['N']:7d} clusters {str(cl):5s} setup {ts:6.1f} s cpu  clusters {eq.n_clusters:5d} "
              f"alone {row['alone']:5d} coarse {row['coarse']:6d}  depth max {row['depth_max']:4d} "
              f"mean {row['depth_mean']:6.1f}  residual {res:.1e}  amp gmean {row['amp_gmean']:.3g}  "
              + " ".join(f"{v:.2g}" for v in a), flush=True)
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1400, 4000, 10000, 32000])
    ap.add_argument("--clusters", type=int, nargs="*", default=[200, 400, 1000])
    ap.add_argument("--exact-max", type=int, default=20000)
    a = ap.parse_args(argv)
    return [run(n, a.clusters, a.exact_max) for n in a.n]


if __name__ == "__main__":
    main()
