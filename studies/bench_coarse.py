"""The two-level statics' coarse solve: factor against smoothed-aggregation CG (issue 26;
docs/results/spheres.md, "The statics' coarse solve without a factor").

    python -m studies.bench_coarse [--n 10000 32000 100000] [--clusters 400]
                                   [--backends pardiso amg splu] [--repeat 2]

On the benchmark's built network (``studies.bench_spheres.fcc_network``) the two-level statics
(``build_equilibrator(clusters=...)``) is built, its coarse matrix ``Hc = R^T H R`` written to a
temporary file, and each back end of ``microhom.coarse_solve`` (a ``microhom.factor`` back end:
``factor_solver``; ``"amg"``: ``amg_solver``) timed in a child process of its own, interleaved
``--repeat`` times: setup and one solve of six coarse loads ``R^T B^T g`` (CPU), the child's
``VmHWM`` above its value after loading ``Hc`` [GiB], tracemalloc's peak (numpy's share) and the
largest relative residual ``|z - Hc y| / |z|``. Set ``NUMBA_NUM_THREADS=1`` and one BLAS/MKL
thread for CPU times.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc

import numpy as np
import scipy.sparse as sps


def _vm(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 2 ** 20
    return float("nan")


def solve_one(path, backend):
    """Child: one back end on the saved ``Hc`` and loads; returns the measured row (dict)."""
    import pyamg  # noqa: F401 - imported before the measurement
    from microhom import coarse_solve as cs
    dat = np.load(path)
    Hc = sps.csr_matrix((dat["data"], dat["indices"], dat["indptr"]), shape=tuple(dat["shape"]))
    Z = dat["Z"]
    h0 = _vm("VmHWM")
    tracemalloc.start()
    t = time.process_time()
    solve = cs.amg_solver(Hc, 6, 3) if backend == "amg" else cs.factor_solver(Hc, 3, backend)
    ts = time.process_time() - t
    t = time.process_time()
    y = solve(Z)
    tc = time.process_time() - t
    peak = tracemalloc.get_traced_memory()[1] / 2 ** 30
    rel = float((np.linalg.norm(Z - Hc @ y, axis=0) / np.linalg.norm(Z, axis=0)).max())
    return dict(backend=backend, setup_cpu=ts, solve_cpu=tc, hwm_gib=_vm("VmHWM") - h0, traced_gib=peak, residual=rel)


def coarse_problem(n, clusters, path):
    """Build the network and statics, save ``Hc`` and six coarse loads to ``path``; the sizes."""
    from microhom.dual_bound import build_equilibrator
    from microhom.kinematics import assemble
    from studies.bench_spheres import fcc_network
    net = fcc_network(n)
    asm = assemble(net, prestress=False, pin=False)
    eq = build_equilibrator(asm, clusters=clusters)
    T = eq._data["two"]
    R = T["R"]
    Hc = (R.T @ (asm.H @ R)).tocsr()
    g = np.random.default_rng(1).normal(size=(asm.Bs.shape[0], 6))
    Z = np.asarray(R.T @ np.asarray(asm.Bs.T @ g))
    np.savez(path, data=Hc.data, indices=Hc.indices, indptr=Hc.indptr, shape=np.array(Hc.shape), Z=Z)
    st = T["stats"]
    return dict(N=net.n_particles, clusters=st["n_clusters"], alone=st["n_alone"], coarse=Hc.shape[0], nnz=Hc.nnz)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[10000, 32000])
    ap.add_argument("--clusters", type=int, default=400)
    ap.add_argument("--backends", nargs="+", default=["pardiso", "amg"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps({k: (v if isinstance(v, str) else float(v)) for k, v in solve_one(*a.child).items()}))
        return None
    rows = []
    for n in a.n:
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "coarse.npz")
            size = coarse_problem(n, a.clusters, path)
            print(f"N {size['N']} clusters {size['clusters']} alone {size['alone']} coarse unknowns "
                  f"{size['coarse']} nnz {size['nnz']}", flush=True)
            for _ in range(a.repeat):
                for b in a.backends:
                    out = subprocess.run([sys.executable, "-m", "studies.bench_coarse", "--child", path, b],
                                         capture_output=True, text=True, check=True).stdout
                    row = dict(size, **json.loads(out.strip().splitlines()[-1]))
                    print(f"  {b:8s} setup {row['setup_cpu']:7.2f} s  solve (6 loads) {row['solve_cpu']:7.2f} s CPU  "
                          f"VmHWM +{row['hwm_gib']:.3f} GiB  traced {row['traced_gib']:.3f} GiB  "
                          f"residual {row['residual']:.1e}", flush=True)
                    rows.append(row)
    return rows


if __name__ == "__main__":
    main()
