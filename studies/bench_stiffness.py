"""Benchmark of the exact stiffness solver (dem.analysis.stiffness) and comparison with jax-md.

    python -m studies.bench_stiffness [--quick] [--no-jax] [--sizes 1e4,1e5,1e6] [--repeats 2]
    python -m studies.bench_stiffness --bound --sizes 1e3,1e4,1e5 --no-jax   # + certified spectral bound
    python -m studies.bench_stiffness --candidates --sizes 1e5 --no-jax      # factorisation back ends

1. Timing on large disordered *frictional* networks. Until the project's DEM packer exists the
   network is built, not packed: a triangular lattice of N disks, positions jittered by +-5 % of D,
   every contact kept with probability 4.1/6 (mean coordination ~4.1 before rattler removal), kn = kt
   = 1, branch vectors from the jittered positions. It is rigid (z > 3 for frictional disks) apart
   from a handful of local zero modes, which the solver reports.
   Solvers: PARDISO (the mkl wheel, the default) and CHOLMOD (scikit-sparse, when installed)
   beside scipy SuperLU (always installed), in the same run, interleaved, each run in its own process (peak memory from getrusage). Printed:
   wall time of the assembly, of the solve (factorisation, mode count, refinement) and in total,
   the CPU time of the call (user + system, all threads: less sensitive to other processes'
   load than the wall time), the time of each named step, and the floppy-count rule used.
   ``--bound``: the certified spectral bound of the hierarchy's pencil (H, M) (what ``dem analyse``
   uses for its two-sided intervals, ``microhom.spectral.certified_bound``) in the same process,
   wall and CPU time beside the exact solve's.
   ``--candidates``: factorisation only (analysis + numeric factorisation + one 3-column solve) of
   the reduced Hessian by every installed back end (PARDISO, CHOLMOD, SuperLU, and the wheels
   cholespy and qdldl when importable), each in its own process.
2. Frictionless harmonic soft disks, bidisperse 1:1.4, phi = 0.88, minimised with scipy L-BFGS:
   exact moduli with pre-stress vs jax-md ``elasticity.athermal_moduli`` (if ``import jax_md``
   works), after the conversion K = B_jaxmd + p/2, G = G_jaxmd - p/2 (full tensor: C = C_jaxmd +
   sym(sigma0 dE) - sigma0 tr dE). Not a CI test.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from dem.analysis.stiffness import have_cholmod, have_pardiso, stiffness
from microhom.tensors import isotropic_moduli, mandel_to_strain, prestress_correction, tensor_to_mandel
from microhom import lattices
from microhom.network import ContactNetwork, from_overlaps
from studies.common import add_out, cli_out_dir, report_to


# ---- networks --------------------------------------------------------------------------------
def diluted_triangular(n, z=4.1, kt=1.0, jitter=0.05, seed=0) -> ContactNetwork:
    """Jittered triangular lattice of ~n disks with contacts kept with probability z/6."""
    rng = np.random.default_rng(seed)
    ny = max(4, int(round(np.sqrt(n * np.sqrt(3) / 2) / 2)) * 2)
    nx = max(3, int(round(n / ny)))
    net = lattices.triangular(nx, ny, kn=1.0, kt=kt)
    sh = net.image_shifts()
    pos = net.positions + jitter * rng.uniform(-1, 1, net.positions.shape)
    i, j = net.pairs.T
    br = pos[j] + sh @ net.cell.T - pos[i]
    keep = rng.random(net.n_contacts) < z / 6
    return ContactNetwork(positions=pos, radii=net.radii, cell=net.cell, pairs=net.pairs[keep],
                          branch=br[keep], kn=1.0, kt=kt, sliding=False)


def soft_disk_packing(n, phi=0.88, seed=0, gtol=1e-13):
    """Bidisperse (1:1.4) harmonic soft disks (U = 1/2 (r_i + r_j - d)^2) in a square periodic box,
    minimised from random positions with scipy L-BFGS. Returns (positions, radii, L)."""
    rng = np.random.default_rng(seed)
    rad = np.where(np.arange(n) < n // 2, 0.5, 0.7)
    L = float(np.sqrt(np.pi * np.sum(rad ** 2) / phi))
    cut = 2 * rad.max()

    def fg(x):
        p = np.mod(x.reshape(n, 2), L)
        pr = cKDTree(p, boxsize=L).query_pairs(cut, output_type="ndarray")
        i, j = pr[:, 0], pr[:, 1]
        d = p[j] - p[i]
        d -= L * np.rint(d / L)
        r = np.hypot(d[:, 0], d[:, 1])
        ov = rad[i] + rad[j] - r
        m = ov > 0
        i, j, d, r, ov = i[m], j[m], d[m], r[m], ov[m]
        f = (ov / r)[:, None] * d                    # dU/dx_j = -f, dU/dx_i = +f
        g = np.zeros((n, 2))
        np.add.at(g, i, f)
        np.add.at(g, j, -f)
        return 0.5 * np.sum(ov ** 2), g.ravel()

    x = rng.uniform(0, L, 2 * n)
    for _ in range(20):
        res = minimize(fg, x, jac=True, method="L-BFGS-B",
                       options=dict(maxiter=200000, gtol=gtol, ftol=0, maxcor=20))
        x = res.x
        if np.abs(fg(x)[1]).max() < 10 * gtol:
            break
    return np.mod(x.reshape(n, 2), L), rad, L


def packing_network(pos, rad, L):
    net = from_overlaps(pos, rad, np.diag([L, L]), kn=1.0, kt=0.0)
    ov = rad[net.pairs[:, 0]] + rad[net.pairs[:, 1]] - net.lengths
    return ContactNetwork(positions=net.positions, radii=net.radii, cell=net.cell,
                          pairs=net.pairs, branch=net.branch, kn=1.0, kt=0.0, sliding=False,
                          fn=ov)


# ---- jax-md peer -----------------------------------------------------------------------------
def jaxmd_moduli(pos, rad, L, cg_tol=1e-7, tether=1e-10):
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from jax_md import elasticity, energy, space

    n = rad.size
    species = (rad > 0.6).astype(np.int32)
    s = np.array([[1.0, 1.2], [1.2, 1.4]])       # sigma_ab = r_a + r_b
    box = jnp.eye(2) * L
    disp, _ = space.periodic_general(box, fractional_coordinates=True)
    # neighbour-list energy (kn = eps/sigma^2 = 1); the list is built once, outside the timing
    nfn, efn = energy.soft_sphere_neighbor_list(
        disp, box, species=jnp.array(species), sigma=jnp.array(s), epsilon=jnp.array(s ** 2),
        alpha=2.0, fractional_coordinates=True, dr_threshold=0.0)
    R = jnp.array(pos / L)
    nbrs = nfn.allocate(R)
    emt = elasticity.athermal_moduli(efn, tether_strength=tether, cg_tol=cg_tol,
                                     check_convergence=True)
    fn = jax.jit(emt)
    t0 = time.perf_counter()
    C, conv = fn(R, box, neighbor=nbrs)
    C.block_until_ready()
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    C, conv = fn(R, box, neighbor=nbrs)
    C.block_until_ready()
    t_run = time.perf_counter() - t0
    return np.asarray(C), bool(conv), t_first, t_run, n


# ---- main ----------------------------------------------------------------------------------
def _solvers():
    return (["pardiso"] if have_pardiso() else []) + (["cholmod"] if have_cholmod() else []) + ["splu"]


def _cpu():
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def one_run(n, solver, prestress=False, bound=False):
    """Build the network, run ``stiffness`` once (and the certified bound of the hierarchy's
    pencil with ``bound``); a dict of figures (peak memory of this process)."""
    t0 = time.perf_counter()
    net = diluted_triangular(n)
    if prestress:     # a small uniform compression: the geometric stiffness enters H
        net = ContactNetwork(positions=net.positions, radii=net.radii, cell=net.cell, pairs=net.pairs,
                             branch=net.branch, kn=1.0, kt=1.0, sliding=False,
                             fn=np.full(net.n_contacts, 1e-3))
    t_net = time.perf_counter() - t0
    c0 = _cpu()
    t0 = time.perf_counter()
    r = stiffness(net, solver=solver, prestress=prestress)
    tt = time.perf_counter() - t0
    cpu = _cpu() - c0
    out = dict(n=net.n_particles, solver=r.solver, dof=r.n_dof, rattlers=r.n_rattlers,
               floppy=r.n_floppy, unstable=r.n_unstable, K_ratio=r.K / r.K_affine,
               G_ratio=r.G / r.G_affine, assembly=r.assembly_time, solve=r.solve_time, total=tt,
               build=t_net, cpu=cpu, residual=r.residual, C=r.C_mandel.tolist(), count=r.count_method,
               steps={k: round(v, 3) for k, v in r.step_times.items()})
    if bound:
        from microhom.hierarchy import block_preconditioner
        from microhom.kinematics import assemble
        from microhom.spectral import certified_bound
        c0 = _cpu()
        t0 = time.perf_counter()
        asm = assemble(net, prestress=prestress, pin=False)
        M, _, S, _ = block_preconditioner(asm)
        b = certified_bound(asm.H, M, psd=not prestress, Minv_sqrt=S,
                            lam_max=None if prestress else 2.0)
        out.update(bound_wall=time.perf_counter() - t0, bound_cpu=_cpu() - c0, bound_lower=b.lower,
                   bound_estimate=b.estimate, bound_zero=b.n_zero, bound_negative=b.n_negative,
                   bound_factorisations=b.n_factorisations, bound_reason=b.reason)
    out["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    return out


def candidate_run(n, backend):
    """Factorise the reduced Hessian ``H + 1e-12 diag H`` of the benchmark network with one back
    end (analysis + numeric factorisation), then one 3-column solve; a dict of figures."""
    import scipy.sparse as sp

    from dem.analysis.stiffness import reduce_system
    from microhom import factor as fm
    from microhom.kinematics import assemble
    net = diluted_triangular(n)
    red = reduce_system(assemble(net))
    A = (red.H + sp.diags(1e-12 * red.d)).tocsr()
    b = -red.F
    c0, t0 = _cpu(), time.perf_counter()
    inertia = None
    if backend in ("pardiso", "splu", "cholmod"):
        f = fm.factor(A, backend=backend, spd=True)
        t1 = time.perf_counter()
        x = f.solve(b)
        ine = f.inertia()
        inertia = None if ine is None else [ine.n_pos, ine.n_neg]
    elif backend == "cholespy":
        from cholespy import CholeskySolverD, MatrixType
        C = A.tocoo()
        f = CholeskySolverD(A.shape[0], C.row.astype(np.int32), C.col.astype(np.int32), C.data,
                            MatrixType.COO)
        t1 = time.perf_counter()
        x = np.zeros_like(b)
        f.solve(np.ascontiguousarray(b), x)
    elif backend == "qdldl":
        import qdldl
        f = qdldl.Solver(sp.triu(A, format="csc"))
        t1 = time.perf_counter()
        x = np.column_stack([f.solve(np.ascontiguousarray(b[:, k])) for k in range(3)])
    else:
        raise ValueError(f"unknown candidate {backend!r}")
    t2 = time.perf_counter()
    return dict(n=net.n_particles, backend=backend, dof=A.shape[0], factor=t1 - t0, solve=t2 - t1,
                cpu=_cpu() - c0, inertia=inertia,
                residual=float(np.abs(A @ x - b).max() / np.abs(b).max()),
                peak_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6)


def _child(n, solver, flags=""):
    """One run in a fresh process, so that its peak resident memory is its own."""
    out = subprocess.run([sys.executable, "-m", "studies.bench_stiffness", "--one",
                          f"{n}:{solver}:{flags}"], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _candidates(sizes):
    names = ["pardiso"] if have_pardiso() else []
    names += (["cholmod"] if have_cholmod() else []) + ["splu"]
    for mod in ("cholespy", "qdldl"):
        try:
            __import__(mod)
            names.append(mod)
        except ImportError:
            pass
    print("## factorisation back ends on the reduced Hessian (analysis + factorisation, one 3-column solve)")
    print(f"load average {os.getloadavg()} on {os.cpu_count()} cores; each run in its own process")
    print(f"{'N':>8} {'backend':>9} {'dof':>8} {'factor s':>9} {'solve s':>8} {'cpu s':>7} "
          f"{'peak GB':>8} {'resid':>8}  inertia")
    for n in sizes:
        for b in names:
            r = _child(n, b, "cand")
            print(f"{r['n']:>8} {r['backend']:>9} {r['dof']:>8} {r['factor']:>9.2f} {r['solve']:>8.3f} "
                  f"{r['cpu']:>7.2f} {r['peak_gb']:>8.2f} {r['residual']:>8.1e}  {r['inertia']}",
                  flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="N = 1e3, 1e4 and a 256-disk jax-md check")
    ap.add_argument("--no-jax", action="store_true")
    ap.add_argument("--sizes", default=None, help="comma-separated N (default 1e4,1e5,1e6)")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved repeats per size")
    ap.add_argument("--splu-max", type=float, default=2e5,
                    help="largest N also solved with SuperLU (1e6 takes ~400 s and ~16 GB)")
    ap.add_argument("--bound", action="store_true",
                    help="also the certified spectral bound of the hierarchy's pencil (dem analyse)")
    ap.add_argument("--prestress", action="store_true",
                    help="pre-stress included (a uniform compression fn = 1e-3 kn)")
    ap.add_argument("--solvers", default=None, help="comma-separated solvers (default: all installed)")
    ap.add_argument("--candidates", action="store_true",
                    help="factorisation back ends only (PARDISO, CHOLMOD, SuperLU, cholespy, qdldl)")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    add_out(ap, "bench_stiffness")
    a = ap.parse_args(argv)
    report_to(cli_out_dir(a.out, cache=False))   # the printed figures, also in OUT/report.txt
    if a.one:
        n, s, flags = a.one.split(":")
        if flags == "cand":
            print(json.dumps(candidate_run(int(float(n)), s)))
        else:
            print(json.dumps(one_run(int(float(n)), s, prestress="p" in flags, bound="b" in flags)))
        return
    sizes = [1000, 10000] if a.quick else [10000, 100000, 1000000]
    if a.sizes:
        sizes = [int(float(s)) for s in a.sizes.split(",")]
    if a.candidates:
        _candidates(sizes)
        return
    flags = ("p" if a.prestress else "") + ("b" if a.bound else "")

    print("## exact stiffness, frictional diluted triangular network (kt = kn, z ~ 4.1)")
    print(f"load average {os.getloadavg()} on {os.cpu_count()} cores; each run in its own process; "
          f"runs interleaved (new solver, SuperLU, new, SuperLU ...)")
    print(f"{'N':>8} {'solver':>8} {'dof':>8} {'ratt':>6} {'flop':>5} {'K/K_aff':>9} {'G/G_aff':>9} "
          f"{'assembly s':>10} {'solve s':>8} {'total s':>8} {'cpu s':>8} {'peak GB':>8} {'resid':>8}")
    for n in sizes:
        runs = {}
        solvers = a.solvers.split(",") if a.solvers else _solvers()
        solvers = [s for s in solvers if s != "splu" or n <= a.splu_max]
        for _ in range(a.repeats if n < 500_000 else 1):
            for s in solvers:
                r = _child(n, s, flags)
                runs.setdefault(s, []).append(r)
                print(f"{r['n']:>8} {r['solver']:>8} {r['dof']:>8} {r['rattlers']:>6} {r['floppy']:>5} "
                      f"{r['K_ratio']:>9.6f} {r['G_ratio']:>9.6f} {r['assembly']:>10.3f} "
                      f"{r['solve']:>8.3f} {r['total']:>8.3f} {r['cpu']:>8.2f} {r['peak_gb']:>8.2f} "
                      f"{r['residual']:>8.1e}  count {r['count']}, unstable {r['unstable']}, "
                      f"steps {r['steps']}", flush=True)
                if "bound_wall" in r:
                    print(f"{'':>8} {'bound':>8} certified lower {r['bound_lower']} (estimate "
                          f"{r['bound_estimate']:.4g}), zero {r['bound_zero']}, negative "
                          f"{r['bound_negative']}, {r['bound_factorisations']} factorisations: wall "
                          f"{r['bound_wall']:.3f} s, cpu {r['bound_cpu']:.2f} s = "
                          f"{r['bound_cpu'] / r['cpu']:.2f} x the exact solve's cpu {r['bound_reason']}",
                          flush=True)
        tot = {s: [r["total"] for r in v] for s, v in runs.items()}
        line = ", ".join(f"{s} {min(v):.3f}-{max(v):.3f} s" for s, v in tot.items())
        if len(runs) >= 2:
            Cs = [np.array(v[0]["C"]) for v in runs.values()]
            d = max(np.abs(c - Cs[-1]).max() for c in Cs[:-1]) / np.abs(Cs[-1]).max()
            line += f"; max |dC| / max |C| between solvers {d:.1e}"
        print(f"  N = {n}: total {line}; load {os.getloadavg()[0]:.2f}", flush=True)

    if a.no_jax:
        return
    try:
        import jax_md  # noqa: F401
    except Exception as exc:   # noqa: BLE001
        print(f"\n(jax-md not importable: {exc}; skipping the peer comparison)")
        return
    print("\n## frictionless harmonic disks with pre-stress vs jax-md athermal_moduli")
    print(f"{'N':>6} {'K':>12} {'G':>12} {'dK rel':>9} {'dG rel':>9} {'dC rel':>9} {'ours s':>8} "
          f"{'jax s':>8} {'jax 1st s':>9} {'ratio':>7} {'p':>9}")
    for n in ([256] if a.quick else [256, 1024, 4096]):
        pos, rad, L = soft_disk_packing(n)
        net = packing_network(pos, rad, L)
        t0 = time.perf_counter()
        r = stiffness(net, prestress=True)
        t_ours = time.perf_counter() - t0
        for cg_tol, tether in ((1e-7, 1e-10), (1e-12, 1e-14)):
            Cj, conv, t1, tj, _ = jaxmd_moduli(pos, rad, L, cg_tol=cg_tol, tether=tether)
            sig0 = mandel_to_strain(r.stress0_mandel)
            p = -0.5 * np.trace(sig0)
            Bj, Gj = isotropic_moduli(tensor_to_mandel(Cj))
            Kc, Gc = Bj + p / 2, Gj - p / 2
            Cc = tensor_to_mandel(Cj) + prestress_correction(sig0)
            dC = np.abs(Cc - r.C_mandel).max() / np.abs(r.C_mandel).max()
            print(f"{n:>6} {r.K:>12.9f} {r.G:>12.9f} {abs(Kc - r.K) / r.K:>9.1e} "
                  f"{abs(Gc - r.G) / r.G:>9.1e} {dC:>9.1e} {t_ours:>8.3f} {tj:>8.3f} {t1:>9.3f} "
                  f"{tj / t_ours:>7.1f} {p:>9.2e}  (cg_tol {cg_tol:g}, tether {tether:g}, "
                  f"converged {conv}, rattlers {r.n_rattlers}, floppy {r.n_floppy})", flush=True)


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
