"""Fill of SuperLU's symmetric-mode factor of 3D sphere Hessians (the memory guard's calibration).

    python -m studies.bench_splu_fill --m 5 7 9

For each FCC size parameter ``m`` (``4 m^3`` spheres of ``studies.bench_spheres.fcc_network``:
keep 0.6, kt = 0.5 kn), in this process: the reduced Hessian ``H`` of ``dem.analysis.stiffness``
(no pre-stress, two-contact turns deflated), then ``microhom.factor.factor(H, backend="splu",
shift=eta, scale=|diag H|)`` exactly as :func:`dem.analysis.stiffness.factorise` calls it. One
line per size: spheres, unknowns, ``L.nnz + U.nnz``, the guard's predicted non-zeros (3D and the
2D formula), the factorisation's CPU time (process) and the peak RSS of the process
(``ru_maxrss``) before and after the factorisation, and the bytes per non-zero their difference
gives (run one size per process for a per-size peak).
"""
from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from dem.analysis.stiffness import _reduce_and_deflate
from microhom import factor as fm
from microhom.kinematics import assemble
from studies.bench_spheres import fcc_network


def fill_row(m, keep=0.6, kt=0.5):
    """(spheres, unknowns, L.nnz + U.nnz, factorisation CPU [s], peak RSS before it [GiB]) of the FCC network of ``4 m^3`` spheres."""
    net = fcc_network(4 * m ** 3, keep=keep, kt=kt)
    asm = assemble(net)
    _, red, _ = _reduce_and_deflate(asm, False, True)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20
    t0 = time.process_time()
    f = fm.factor(red.H, backend="splu", shift=fm.ETA, scale=red.d, max_memory=np.inf, dim=3)
    return net.n_particles, red.H.shape[0], f.nnz, time.process_time() - t0, rss0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[5, 7, 9])
    a = ap.parse_args(argv)
    print("m, spheres, unknowns, nnz(L+U), predicted 3D, predicted 2D formula, factor CPU [s], peak RSS before / after the factor [GiB], bytes per non-zero")
    for m in a.m:
        n_sph, n, nnz, cpu, rss0 = fill_row(m)
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20
        print(f"{m}, {n_sph}, {n}, {nnz}, {fm.predicted_factor_nnz(n, 3):.4g}, {fm.predicted_factor_nnz(n, 2):.4g}, "
              f"{cpu:.2f}, {rss0:.2f} / {rss:.2f}, {(rss - rss0) * 2 ** 30 / nnz:.1f}", flush=True)


if __name__ == "__main__":
    main()
