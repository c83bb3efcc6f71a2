"""Cross-check of :func:`dem.analysis.peers.jaxmd_elasticity` against jax-md itself (optional peer).

    pip install -e ".[peers]" && python -m studies.peer_jaxmd [--n 64 256] [--steps 40000]

For each N: a bidisperse (radii 0.5 / 0.7, 50:50) packing of harmonic soft disks at phi = 0.90 in
a square periodic box is minimised with jax-md's FIRE; then jax-md's
``elasticity.athermal_moduli`` (its defaults: tether 1e-10, CG tolerance 1e-7, and tight
settings: 1e-14, 1e-12) and our exact solve are run on the same positions, and the relative
differences of B, G and of the whole tensor are printed. Without jax-md the script says so and
exits (the tests never need it). Timings include jax's compilation and depend on the machine's
load, printed with them.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from dem.analysis.peers import jaxmd_elasticity
from studies.common import add_out, cli_out_dir, report_to


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--steps", type=int, default=40_000, help="FIRE steps of the minimisation")
    add_out(ap, "peer_jaxmd")
    args = ap.parse_args(argv)
    report_to(cli_out_dir(args.out, cache=False))   # the printed figures, also in OUT/report.txt
    os.environ.setdefault("JAX_ENABLE_X64", "1")
    try:  # optional peer: extra "peers"
        import jax
        import jax.numpy as jnp
        from jax_md import elasticity, energy, minimize, space
    except ImportError:
        print("jax-md is not installed (pip install -e '.[peers]'); nothing to compare", file=sys.stderr)
        return []
    jax.config.update("jax_enable_x64", True)
    print(f"load average {os.getloadavg()}")
    rows = []
    for n in args.n:
        rng = np.random.default_rng(n)
        species = np.where(np.arange(n) < n // 2, 0, 1)
        rad = np.where(species == 0, 0.5, 0.7)
        L = np.sqrt(np.pi * (rad ** 2).sum() / 0.90)
        box = jnp.array([[L, 0.0], [0.0, L]])
        disp, shift = space.periodic_general(box, fractional_coordinates=True)
        sigma = jnp.array([[1.0, 1.2], [1.2, 1.4]])           # r_i + r_j per species pair
        efn = energy.soft_sphere_pair(disp, species=jnp.array(species), sigma=sigma, epsilon=1.0, alpha=2.0)
        init, apply = minimize.fire_descent(efn, shift, dt_start=0.05, dt_max=0.1)
        st = init(jnp.array(rng.uniform(size=(n, 2))))
        st = jax.lax.fori_loop(0, args.steps, lambda i, s: apply(s), st)
        R = st.position
        print(f"N = {n}: max |grad U| after FIRE {float(jnp.abs(jax.grad(efn)(R)).max()):.1e}")
        t = time.perf_counter()
        C_def = np.array(elasticity.athermal_moduli(efn)(R, box))
        t_def = time.perf_counter() - t
        C_tight = np.array(elasticity.athermal_moduli(efn, tether_strength=1e-14, cg_tol=1e-12)(R, box))
        t = time.perf_counter()
        ours = jaxmd_elasticity(np.array(R), rad, np.array(box), fractional_coordinates=True)
        t_ours = time.perf_counter() - t
        for name, C in (("defaults", C_def), ("tight", C_tight)):
            m = elasticity.extract_isotropic_moduli(C)
            B, G = float(m["B"]), float(m["G"])
            rows.append((n, name, abs(ours.B / B - 1), abs(ours.G / G - 1),
                         np.abs(ours.C - C).max() / np.abs(C).max()))
            print(f"  jax-md {name:8s}: B = {B:.12g}, G = {G:.12g}; ours differs by "
                  f"{rows[-1][2]:.1e} (B), {rows[-1][3]:.1e} (G), {rows[-1][4]:.1e} (max |dC|/|C|)")
        print(f"  ours: B = {ours.B:.12g}, G = {ours.G:.12g}, K = {ours.K:.6g}, G_cauchy = "
              f"{ours.G_cauchy:.6g}, p = {ours.pressure:.4g}, rattlers {ours.n_rattlers}; "
              f"time ours {t_ours:.3f} s, jax-md (defaults, incl. compilation) {t_def:.1f} s")
    return rows


if __name__ == "__main__":
    from studies.common import run_study

    raise SystemExit(run_study(main))
