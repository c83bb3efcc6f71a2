"""Cost of the exact 3D solve alone on the built sphere networks of ``studies.bench_spheres``.

    NUMBA_NUM_THREADS=1 python -m studies.bench_exact3d --n 10000 [--max-memory BYTES] [--prestress]
    NUMBA_NUM_THREADS=1 python -m studies.bench_exact3d --dump FILE [--prestress]

One size per process (the peak resident memory is the process's): the network
(:func:`studies.bench_spheres.fcc_network`, or a LAMMPS dump read as ``dem analyse`` reads it), then
:func:`dem.analysis.stiffness.stiffness` with the solver's default choices. Prints one line of
figures: spheres, contacts, unknowns, the CPU time (user + system) and wall time of the solve, the
load average before and after, the peak RSS of the process, the solver, the floppy and negative
modes (and the turns deflated), K and G, and the named steps' wall times. The machine is shared:
the CPU time is the figure to read.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import time
import warnings


def _cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="spheres at least (built FCC network)")
    ap.add_argument("--dump", default=None, help="a LAMMPS dump instead of the built network")
    ap.add_argument("--max-memory", type=float, default=None, help="bytes, the solve's max_memory")
    ap.add_argument("--prestress", action="store_true", help="the Cauchy tangent with the pre-stress")
    ap.add_argument("--no-deflate", action="store_true", help="leave the two-contact turns to the count")
    a = ap.parse_args(argv)
    from dem.analysis.stiffness import stiffness
    if a.dump:
        from dem.analysis.analyse import load_network
        net, info = load_network(a.dump, kn=1.0, kt=1.0)
        arm = info.get("spin_arm", "radius")
    else:
        from studies.bench_spheres import fcc_network
        net, arm = fcc_network(a.n), "contact"
    if a.prestress and net.fn is None:
        import dataclasses
        delta = net.radii[net.pairs[:, 0]] + net.radii[net.pairs[:, 1]] - net.lengths
        net = dataclasses.replace(net, fn=net.kn * delta)
    load0 = os.getloadavg()[0]
    c0, w0 = _cpu(), time.perf_counter()
    with warnings.catch_warnings(record=True) as ws:
        warnings.simplefilter("always")
        r = stiffness(net, max_memory=a.max_memory, prestress=a.prestress, spin_arm=arm,
                      deflate=not a.no_deflate)
    cpu, wall = _cpu() - c0, time.perf_counter() - w0
    row = dict(N=net.n_particles, contacts=net.n_contacts, ndof=r.n_dof, cpu_s=round(cpu, 2),
               wall_s=round(wall, 2), load=(round(load0, 1), round(os.getloadavg()[0], 1)),
               peak_gib=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20, 3),
               solver=r.solver, floppy=r.n_floppy, turns=r.n_turns, unstable=r.n_unstable,
               K=r.K, G=r.G, count=r.count_method, relax=r.relax_path, residual=r.residual,
               steps={k: round(v, 2) for k, v in r.step_times.items()},
               warnings=[str(w.message)[:200] for w in ws])
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
