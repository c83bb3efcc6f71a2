import json, warnings, numpy as np
from pathlib import Path
from dem.io.lammps_run import read_run
from dem.analysis.stiffness import stiffness
from microhom.structural_sums import rattlers
warnings.simplefilter("ignore")
for f in sorted(Path("out/spheres/packings").iterdir()):
    row = json.loads((f / "case.json").read_text())
    if row["mu"] == 0:
        continue
    prm = json.loads((f / "params.json").read_text())
    net = read_run(f, prm).network
    rat, act = rattlers(net)
    pr = net.pairs[act]
    cnt = np.bincount(pr.ravel(), minlength=net.n_particles)
    two = np.flatnonzero((cnt == 2) & ~rat)
    # unit normals from each two-contact sphere to its two neighbours
    c = net.branch if hasattr(net, "branch") else None
    dev = []
    for p in two:
        k = np.flatnonzero(act & ((net.pairs[:, 0] == p) | (net.pairs[:, 1] == p)))
        ns = [net.normals[q] * (1 if net.pairs[q, 0] == p else -1) for q in k]
        dev.append(np.linalg.norm(ns[0] + ns[1]))
    dev = np.array(dev)
    r = stiffness(net, prestress=True, spin_arm="radius")
    r0 = stiffness(net, prestress=False)
    print(f.name, "two-contact", len(two), "non-collinear(|n1+n2|>1e-3)", int((dev > 1e-3).sum()),
          "unstable", r.n_unstable, "floppy(no prestress)", r0.n_floppy, "rattlers", r.n_rattlers,
          "K", r.K, "vs cached K_cauchy2", row.get("K_cauchy2"), "G", r.G, row.get("G_cauchy2"),
          "probes K,G", row.get("K_probes"), row.get("G_probes"), "diff2", row.get("probes_difference2"), flush=True)
