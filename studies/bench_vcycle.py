"""pyamg's V-cycle against the parallel one of ``microhom.vcycle`` on the sphere benchmark (issue 26).

    python -m studies.bench_vcycle [--n 32000] [--repeat 2] [--gil]
    python -m studies.bench_vcycle --hierarchy {numba,pyamg} -- [bench_spheres arguments]

The first form builds the network of ``studies.bench_spheres`` (``fcc_network``), its assembly and
multilevel setup, and times one application of the V-cycle to 6 columns (what a CG order does):
pyamg's (``aspreconditioner(cycle="V")``, one column at a time) and ``VCycle`` with 1 and with 2
numba threads, interleaved ``repeat`` times (numba, pyamg, numba, pyamg, ...), each line with the
wall and process CPU time, the load average and the peak RSS; it checks the results are equal
bit for bit. ``--gil`` first measures whether pyamg's V-cycle and scipy's ``H @ X`` release the
GIL: two Python threads with 3 columns each against one thread with 6 (the process CPU over
wall: about 1 core's share either way when the GIL is held). Run it with ``NUMBA_NUM_THREADS=2``
(the number of threads is set per line with ``numba.set_num_threads``).

The second form runs ``studies.bench_spheres`` (its arguments after ``--``) with the hierarchy's
V-cycle forced to pyamg's (``pyamg``) or left to ``VCycle`` (``numba``, the default path); the
number of threads is ``NUMBA_NUM_THREADS``.
"""
from __future__ import annotations

import argparse
import os
import resource
import threading
import time

import numpy as np


def _peak_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20


def _timed(f, *a):
    """(result, wall [s], process CPU [s]) of ``f(*a)``."""
    w, c = time.perf_counter(), time.process_time()
    out = f(*a)
    return out, time.perf_counter() - w, time.process_time() - c


def _line(label, wall, cpu):
    print(f"  {label:34s} wall {wall:7.2f} s  cpu {cpu:7.2f} s  cpu/wall {cpu / wall:4.2f}  "
          f"load {os.getloadavg()[0]:4.1f}  peak RSS {_peak_gb():5.2f} GiB", flush=True)


def _in_threads(f, parts):
    ts = [threading.Thread(target=f, args=(p,)) for p in parts]
    for t in ts:
        t.start()
    for t in ts:
        t.join()


def gil_check(ml, H, B, X):
    """Two Python threads (3 columns each) against one (6 columns): pyamg's V-cycle and ``H @ X``
    (CSR, 6 columns, 5 times)."""
    vc = ml.aspreconditioner(cycle="V")

    def cycles(rows):
        for b in rows:
            vc @ b

    def products(x):
        for _ in range(5):
            H @ x
    print("GIL: one Python thread against two", flush=True)
    _line("pyamg V-cycle, 1 thread x 6", *_timed(cycles, B)[1:])
    _line("pyamg V-cycle, 2 threads x 3", *_timed(_in_threads, cycles, [B[:3], B[3:]])[1:])
    _line("H @ X x5, 1 thread x 6", *_timed(products, X)[1:])
    _line("H @ X x5, 2 threads x 3", *_timed(_in_threads, products, [X[:, :3], X[:, 3:]])[1:])


def compare(n, repeat=2, gil=False):
    """The module docstring's first form; returns {label: [(wall, cpu), ...]}."""
    import numba
    import scipy.sparse as sp

    from microhom.kinematics import assemble
    from microhom.multilevel import amg_preconditioner
    from microhom.vcycle import VCycle
    from studies.bench_spheres import fcc_network
    net = fcc_network(n)
    asm = assemble(net, pin=False)
    P, info = amg_preconditioner(asm)
    ml, order, _ = P.amg
    sizes = ", ".join(f"{lvl.A.shape[0]} ({lvl.A.nnz} nnz)" for lvl in ml.levels)
    r = np.random.default_rng(0).standard_normal((asm.ndof, 6))
    B = np.ascontiguousarray(r[order].T)
    vc, fast = ml.aspreconditioner(cycle="V"), VCycle.of(ml)
    fast(B[:1])                                           # compile outside the timings
    print(f"N = {net.n_particles}, ndof {asm.ndof}; levels {sizes}; setup {info.setup_time:.1f} s; "
          f"numba threads available {numba.config.NUMBA_NUM_THREADS} ({numba.threading_layer()})", flush=True)
    if gil:
        gil_check(ml, sp.csc_matrix(asm.H).T, B, np.asfortranarray(r))
    threads = [t for t in (1, 2) if t <= numba.config.NUMBA_NUM_THREADS]
    out = {}
    print("one V-cycle application to 6 columns", flush=True)
    for rep in range(repeat):
        for t in threads:
            numba.set_num_threads(t)
            X, w, c = _timed(fast, B)
            _line(f"numba VCycle, {t} thread(s)", w, c)
            out.setdefault(f"numba{t}", []).append((w, c))
            ref, w, c = _timed(lambda: np.stack([vc @ b for b in B]))
            _line("pyamg, one column at a time", w, c)
            out.setdefault("pyamg", []).append((w, c))
            if not np.array_equal(X, ref):
                raise AssertionError("the parallel V-cycle differs from pyamg's")
    print("  (bit-identical: checked)", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--gil", action="store_true", help="first check whether pyamg and scipy release the GIL")
    ap.add_argument("--hierarchy", choices=("numba", "pyamg"), default=None,
                    help="run studies.bench_spheres (arguments after --) with this V-cycle")
    ap.add_argument("rest", nargs=argparse.REMAINDER)
    a = ap.parse_args(argv)
    if a.hierarchy is None:
        if a.n < 1 or a.repeat < 1:
            ap.error(f"--n and --repeat must be >= 1, got {a.n}, {a.repeat}")
        return compare(a.n, a.repeat, a.gil)
    from microhom.vcycle import VCycle
    from studies import bench_spheres
    rest = a.rest[1:] if a.rest[:1] == ["--"] else a.rest
    print(f"V-cycle: {a.hierarchy}; NUMBA_NUM_THREADS {os.environ.get('NUMBA_NUM_THREADS', 'default')}", flush=True)
    if a.hierarchy == "pyamg":
        of = VCycle.__dict__["of"]
        VCycle.of = classmethod(lambda cls, ml: None)
        try:
            return bench_spheres.main(rest)
        finally:
            VCycle.of = of
    return bench_spheres.main(rest)


if __name__ == "__main__":
    main()
