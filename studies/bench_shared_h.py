"""H's products in the CG: the assembly's CSR ``H`` against the multilevel copy (issue 26).

    python -m studies.bench_shared_h [--n 32000] [--cols 6] [--repeat 5]

On the benchmark's built sphere network (``studies.bench_spheres.fcc_network``): scipy's CSR
product ``H @ X`` (what the CG used) against :class:`microhom.shared_h.ShiftedCopy` (the numba
BSR kernel, ``prange`` over block rows, on the level-0 matrix of the multilevel hierarchy), with
``NUMBA_NUM_THREADS`` threads (set it in the environment); prints the wall and process CPU time
per product (best of ``--repeat``), the arrays' bytes per non-zero of ``H`` and the largest
difference relative to ``|H| |X|``.
"""
from __future__ import annotations

import argparse
import time

import numba
import numpy as np


def _best(f, repeat):
    wall, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return min(wall), min(cpu)


def main(argv=None):
    from microhom.kinematics import assemble
    from microhom.multilevel import amg_preconditioner
    from microhom.shared_h import ShiftedCopy
    from studies.bench_spheres import fcc_network
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=32000)
    ap.add_argument("--cols", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args(argv)
    asm = assemble(fcc_network(a.n), pin=False)
    op, _ = amg_preconditioner(asm)
    ml, order, _ = op.amg
    S = ShiftedCopy(ml.levels[0].A, order, op.shift)
    H = asm.H.T                                   # the CG's CSR view
    X = np.asfortranarray(np.random.default_rng(0).normal(size=(asm.ndof, a.cols)))
    S @ X                                         # compile
    nnz = asm.H.nnz
    A = S.A
    print(f"N = {asm.net.n_particles}, ndof = {asm.ndof}, nnz(H) = {nnz}, {a.cols} columns, "
          f"numba threads {numba.get_num_threads()}")
    print(f"  bytes per non-zero: CSR {(H.data.nbytes + H.indices.nbytes + H.indptr.nbytes) / nnz:.1f}, "
          f"BSR copy {(A.data.nbytes + A.indices.nbytes + A.indptr.nbytes) / nnz:.1f}")
    for name, f in (("scipy CSR", lambda: H @ X), ("numba BSR copy", lambda: S @ X),
                    ("scipy CSR per column", lambda: [H @ X[:, j] for j in range(a.cols)])):
        w, c = _best(f, a.repeat)
        print(f"  {name:22s} wall {1e3 * w:8.1f} ms  cpu {1e3 * c:8.1f} ms")
    d = np.abs(S @ X - H @ X).max() / np.abs(abs(asm.H) @ np.abs(X)).max()
    print(f"  largest difference / max |H||X|: {d:.2e}")


if __name__ == "__main__":
    main()
