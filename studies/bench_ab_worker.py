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

Under ``valgrind --tool=callgrind --instr-atstart=no`` (``python -m studies.bench_throughput
--against REV --instructions``) it counts instead of timing: after the warm-up, callgrind's
counters are zeroed, ``CHUNKS`` x ``CHUNK_STEPS`` steps run and the counts are dumped (the dump
named ``steps``); the instructions retired per step are read from that dump by the caller. The
client requests go through a small C helper compiled with ``cc`` against
``valgrind/callgrind.h`` (:func:`callgrind`).
"""
import ctypes
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

_CG_SOURCE = r"""
#include <valgrind/callgrind.h>
void cg_start(void) { CALLGRIND_START_INSTRUMENTATION; }
void cg_zero(void) { CALLGRIND_ZERO_STATS; }
void cg_dump(const char *name) { CALLGRIND_DUMP_STATS_AT(name); }
int cg_running(void) { return RUNNING_ON_VALGRIND; }
"""


def callgrind():
    """Callgrind's client requests (``cg_start``, ``cg_zero``, ``cg_dump(bytes)``) as a ctypes
    library, or None when this process does not run under valgrind. Compiled with ``cc`` into a
    temporary folder (needs the valgrind headers: Debian ``valgrind``)."""
    if "valgrind" not in os.environ.get("LD_PRELOAD", "") and not os.environ.get("DEM_CALLGRIND"):
        return None
    folder = tempfile.mkdtemp(prefix="dem-cg-")
    src, lib = os.path.join(folder, "cg.c"), os.path.join(folder, "libcg.so")
    with open(src, "w") as fh:
        fh.write(_CG_SOURCE)
    subprocess.run(["cc", "-O1", "-shared", "-fPIC", "-o", lib, src], check=True)
    cg = ctypes.CDLL(lib)
    if not cg.cg_running():
        return None
    cg.cg_start()
    return cg


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
    cg = callgrind()
    if cg is not None:   # instructions, not time: the caller reads the dump named "steps"
        cg.cg_zero()
        sim.run(chunks * chunk_steps)
        cg.cg_dump(b"steps")
        digest = hashlib.sha1(st.x.tobytes() + st.v.tobytes()).hexdigest()[:16]
        print(json.dumps({"steps": chunks * chunk_steps, "n": st.n, "hash": digest,
                          "contacts": int(sim.measure()["n_contacts"])}))
        return 0
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
