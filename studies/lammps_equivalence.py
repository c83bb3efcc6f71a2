"""How closely the engine follows LAMMPS ``gran/hooke/history``: divergence against step, per law.

    python -m studies.lammps_equivalence [--steps 1000] [--n-side 32]

The same state (polydisperse disks d = 1 +- 5 % on a squeezed, perturbed triangular lattice,
random velocities and spins, kn = 1e4, dt = 0.002, skin 0.1) is run in LAMMPS with ``newton on``
and ``newton off`` and in the engine, for each law of issue 14. Printed per law and step: the
largest position difference (over the mean diameter), velocity difference (over the rms velocity)
and spin difference (over the rms spin) of

* ``lammps off``: LAMMPS ``newton off`` against ``newton on`` (LAMMPS' own round-off);
* ``engine``: :class:`dem.engine.contact_laws.LammpsHookeHistory` with ``startup="lammps"``;
* ``default``: the engine's own law (:class:`~dem.engine.contact_laws.LinearFriction`, damping ratio 0.05
  per pair, tangential dashpot, cap ``mu max(fn, 0)``, scalar history) with its leapfrog start-up
  (velocities taken as half-step ones), for contrast (benchmark law only).

Needs ``lmp`` on PATH (says so and exits 1 otherwise).
"""
from __future__ import annotations

import argparse
import math
import os
import time

from dem.engine.contact_laws import LinearFriction
from dem.engine.lammps import lammps_available
from dem.engine.lammps_trajectory import (DT, KN, divergence, engine_trajectory, equivalence_laws, lammps_trajectory,
                                   start_state)
from studies.common import add_out, cli_out_dir, report_to


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--n-side", type=int, default=32, help="lattice side: N = n_side^2 disks")
    add_out(ap, "lammps_equivalence")
    a = ap.parse_args(argv)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    if not lammps_available():
        print("lmp (LAMMPS) not on PATH: nothing to compare (Debian: apt-get install -y lammps)")
        return 1
    st = start_state(a.n_side)
    steps = [s for s in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000) if s <= a.steps]
    e = math.exp(-0.05 * math.pi / math.sqrt(1 - 0.05 ** 2))
    default = LinearFriction(kn=KN, kt=KN, mu=0.5, restitution=e, tangential_damping=True)
    print(f"N = {st.n}, kn = {KN:g}, dt = {DT:g}; loadavg {os.getloadavg()}")
    for name, law in equivalence_laws().items():
        t0 = time.perf_counter()
        on = lammps_trajectory(st, law, DT, steps[-1], steps, newton="on", skin=0.1)
        off = lammps_trajectory(st, law, DT, steps[-1], steps, newton="off", skin=0.1)
        cols = {"lammps off": divergence(off, on, 1.0),
                "engine": divergence(engine_trajectory(st, law, DT, steps[-1], steps, skin=0.1), on, 1.0)}
        if name == "benchmark":
            cols["default"] = divergence(engine_trajectory(st, default, DT, steps[-1], steps, skin=0.1,
                                                           startup="leapfrog"), on, 1.0)
        print(f"\nlaw: {name}  ({time.perf_counter() - t0:.1f} s)")
        head = "  step | " + " | ".join(f"{c:^29s}" for c in cols)
        print(head)
        print("       | " + " | ".join(f"{'dx/d':>9s} {'dv/v_rms':>9s} {'dw/w_rms':>9s}" for _ in cols))
        for k, s in enumerate(steps):
            print(f"{s:6d} | " + " | ".join(f"{d.dx[k]:9.2e} {d.dv[k]:9.2e} {d.domega[k]:9.2e}"
                                              for d in cols.values()))
    return 0


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
