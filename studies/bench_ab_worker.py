"""One timed process of ``python -m studies.bench_throughput --against REV`` (not meant to be run by hand).

    python studies/bench_ab_worker.py STATE.npz LAW.json WARM CHUNKS CHUNK_STEPS

Run with ``PYTHONPATH`` set to the checkout under test (this repository or the revision it is
compared with): it imports only that checkout's engine (``State``, ``Simulation``, the contact
laws), so the same harness times both codes. ``STATE.npz`` holds the tiled benchmark state
(``x`` (N, 2) [m], ``r`` (N,) [m], ``h`` (2, 2) [m], ``rho`` [kg/m^2]); ``LAW.json`` the law
(``{"law": class name, "kwargs": {...}, "startup": ..., "dt": ..., "skin": ...}``). After ``WARM``
untimed steps (numba's compilation included) it runs ``CHUNKS`` chunks of ``CHUNK_STEPS`` steps
and prints one JSON line: the CPU time per step of the fastest and the median chunk [ms], the
CPU and wall rates of the whole timed run [particle-steps/s and contact-steps/s], the number of
contacts at the end, the load average and a hash of the final positions and velocities (equal
hashes: the two codes gave the same trajectory bit for bit).
"""
import hashlib
import json
import os
import sys
import time

import numpy as np


def _engine():
    try:
        from dem.engine import contact_laws
        from dem.engine.integrate import Simulation
        from dem.engine.state import State
    except ImportError:   # revisions before the dem.engine layout (issue 23, part 4)
        from dem import contact_laws
        from dem.integrate import Simulation
        from dem.state import State
    return State, Simulation, contact_laws


def main(argv):
    path, spec_path, warm, chunks, chunk_steps = argv[0], argv[1], int(argv[2]), int(argv[3]), int(argv[4])
    State, Simulation, laws = _engine()
    d = np.load(path)
    spec = json.loads(open(spec_path).read())
    st = State.from_disks(d["x"], d["r"], d["h"], rho=float(d["rho"]), spins=True)
    law = getattr(laws, spec["law"])(**spec["kwargs"])
    loop, guard = dict(skin=spec["skin"], sort_every=50), dict(unsafe_dt=True)
    mod = sys.modules[Simulation.__module__]
    if hasattr(mod, "Loop"):      # the bundles (issue 23); older revisions take the keywords flat
        sim = Simulation(st, law, dt=spec["dt"], damping=0.0, startup=spec["startup"],
                         guard=mod.Guard(**guard), loop=mod.Loop(**loop))
    else:
        sim = Simulation(st, law, dt=spec["dt"], damping=0.0, startup=spec["startup"], **loop, **guard)
    sim.run(warm)
    ts = np.empty(chunks)
    w0 = time.perf_counter()
    for k in range(chunks):
        c0 = time.process_time()
        sim.run(chunk_steps)
        ts[k] = (time.process_time() - c0) / chunk_steps
    wall = time.perf_counter() - w0
    n, steps = st.n, chunks * chunk_steps
    contacts = int(sim.measure()["n_contacts"])
    digest = hashlib.sha1(st.x.tobytes() + st.v.tobytes()).hexdigest()[:16]
    print(json.dumps({"min_ms": 1e3 * ts.min(), "median_ms": 1e3 * float(np.median(ts)),
                      "cpu_ps": n * steps / ts.sum() / chunk_steps, "wall_ps": n * steps / wall,
                      "cpu_cs": contacts * steps / ts.sum() / chunk_steps, "contacts": contacts,
                      "load": os.getloadavg()[0], "hash": digest}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
