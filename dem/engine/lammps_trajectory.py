"""The same state run in this engine and in LAMMPS ``gran/hooke/history``: trajectories compared.

:func:`lammps_trajectory` writes a :class:`dem.engine.state.State` and a
:class:`dem.engine.contact_laws.LammpsHookeHistory` law as a LAMMPS data file and input (``units lj``,
``dimension 2``, ``atom_style sphere``, ``fix nve/sphere disc``, ``fix enforce2d``), runs it and
reads back positions, velocities and spins at the requested steps. :func:`engine_trajectory` runs
the same state here with ``startup="lammps"``; :func:`divergence` compares two trajectories.

Conventions handled here:

* **Masses.** This LAMMPS build's ``read_data`` sets the mass of a ``sphere`` atom to
  ``4/3 pi r^3 rho`` even in 2D; the input re-sets it with ``set ... density/disc`` (mass
  ``pi r^2 rho``, computed in LAMMPS as ``(pi r) r rho``; the engine's state is given the same
  expression, so both codes start with bit-identical masses).
* **Velocities.** LAMMPS (velocity Verlet) stores ``v(n)`` at the integer step; this engine stores
  ``v(n - 1/2)``. LAMMPS' dumps are converted to ``v(n - 1/2) = v(n) - dt/2 F(n)/m`` (and the
  spins with ``dt/2 T(n)/(m r^2/2)``, LAMMPS' ``fix nve/sphere disc`` inertia) with the force and
  torque dumped at the same step, which is exactly the engine's stored velocity.
* **Start-up.** LAMMPS' setup force call does not advance the shear history and its first kick is
  ``dt/2``: ``Simulation(..., startup="lammps")``.
* **Round-off reference.** LAMMPS run with ``newton on`` and ``newton off`` differs by the order in
  which it sums the forces of pairs across the periodic boundary: that difference, in the same
  run, is the round-off level the engine is compared against (:func:`divergence`).
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from microhom import lattices
from microhom.results import Result

from .. import io
from .contact_laws import LammpsHookeHistory
from .integrate import Guard, Loop, Simulation
from .lammps import lammps_available, run_lammps
from .state import State

__all__ = ["Trajectory", "Divergence", "lammps_trajectory", "engine_trajectory", "divergence",
           "lammps_masses", "pair_style_line", "start_state", "equivalence_laws", "KN", "DT"]

KN = 1e4
DT = 0.002
GAMMA = 2 * 0.05 * math.sqrt(KN / 0.5)  # damping ratio 0.05 for a pair of unit masses (benchmark)


def equivalence_laws():
    """The laws of issue 14: the benchmark law, frictionless, kt = 2/7 kn (gamma_t NULL),
    sliding with mu = 0.05, undamped."""
    return {
        "benchmark": LammpsHookeHistory(kn=KN, kt=KN, gamma_n=GAMMA, gamma_t=GAMMA, mu=0.5),
        "frictionless": LammpsHookeHistory(kn=KN, kt=KN, gamma_n=GAMMA, gamma_t=GAMMA, mu=0.0),
        "kt_2/7_kn_gamma_t_NULL": LammpsHookeHistory(kn=KN, kt=2 / 7 * KN, gamma_n=GAMMA, mu=0.5),
        "sliding_mu_0.05": LammpsHookeHistory(kn=KN, kt=KN, gamma_n=GAMMA, gamma_t=GAMMA, mu=0.05),
        "undamped": LammpsHookeHistory(kn=KN, kt=KN, gamma_n=0.0, gamma_t=0.0, mu=0.5),
    }


def start_state(nside=24, seed=1):
    """nside^2 polydisperse disks (d = 1 +- 5 %) on a squeezed (0.985), perturbed triangular
    lattice, random velocities (rms 0.05 d per time unit) and spins (rms 0.1), areal density
    4/pi, LAMMPS' disk masses."""
    rng = np.random.default_rng(seed)
    net = lattices.triangular(nside, nside, diameter=1.0)
    sq = 0.985
    x = net.positions * sq + rng.uniform(-0.03, 0.03, net.positions.shape)
    r = 0.5 * (1 + rng.uniform(-0.05, 0.05, net.n_particles))
    rho = 4 / math.pi
    st = State.from_disks(x, r, net.cell * sq, rho=rho, spins=True)
    st.mass = lammps_masses(r, rho)
    st.inertia = 0.5 * st.mass * r ** 2
    st.v[:] = rng.normal(0, 0.05, st.v.shape)
    st.omega[:] = rng.normal(0, 0.1, st.n)
    return st


@dataclass(frozen=True)
class Trajectory(Result):
    """Snapshots of a run, particles in the state's ``ids`` order.

    steps : (S,) step numbers; x : (S, N, 2) positions [length] (wrapped into the cell, any image);
    v : (S, N, 2) half-step velocities v(n - 1/2) [length/time]; omega : (S, N) half-step spins
    [1/time]; cell : (2, 2) the cell ``h``; source : ``"engine"`` or ``"lammps newton on|off"``.
    """
    steps: np.ndarray
    x: np.ndarray = field(metadata={"export": False})
    v: np.ndarray = field(metadata={"export": False})
    omega: np.ndarray = field(metadata={"export": False})
    cell: np.ndarray
    source: str


@dataclass(frozen=True)
class Divergence(Result):
    """Per step, the largest difference between two trajectories ``a`` and ``b`` (dimensionless).

    Attributes
    ----------
    steps : (S,) int array
        The compared time steps.
    dx : (S,) array
        ``max |x_a - x_b|`` (nearest periodic image) over the mean disk diameter.
    dv : (S,) array
        ``max |v_a - v_b|`` over the rms velocity of ``b``.
    domega : (S,) array
        ``max |w_a - w_b|`` over the rms spin of ``b`` (0 where the rms is 0 and the spins agree).
    """
    steps: np.ndarray
    dx: np.ndarray
    dv: np.ndarray
    domega: np.ndarray


def lammps_masses(radius, rho):
    """(N,) disk masses as LAMMPS' ``set density/disc`` computes them: ``(pi r) r rho``, for radii
    (N,) [m] and an areal density ``rho`` [kg/m^2] (the rounding order matters for bit equality)."""
    r = np.asarray(radius, dtype=np.float64)
    return math.pi * r * r * rho


def pair_style_line(law) -> str:
    """``pair_style gran/hooke/history`` line for a :class:`~dem.engine.contact_laws.LammpsHookeHistory` law."""
    if not isinstance(law, LammpsHookeHistory):
        raise TypeError(f"law must be a LammpsHookeHistory, got {type(law).__name__}")
    gt = "NULL" if law.gamma_t is None else repr(float(law.gamma_t))
    return (f"pair_style gran/hooke/history {law.kn!r} {law.kt!r} {float(law.gamma_n)!r} {gt} "
            f"{float(law.mu)!r} {int(law.dampflag)}")


def _next_dump_expr(steps):
    """LAMMPS equal-style expression: the first dump step after the current one."""
    s = sorted(set(int(k) for k in steps if k > 0))
    terms = [f"(step<{s[0]})*{s[0]}"]
    for a, b in zip(s[:-1], s[1:]):
        terms.append(f"(step>={a})*(step<{b})*{b}")
    terms.append(f"(step>={s[-1]})*{s[-1] + 10 ** 9}")
    return "+".join(terms)


def _check_state(state):
    if state.h[0, 1] != 0.0 or state.h[1, 0] != 0.0:
        raise ValueError("lammps_trajectory: the cell must be orthogonal (h diagonal)")
    if state.omega is None:
        raise ValueError("lammps_trajectory: the state needs spins (State.from_disks(..., spins=True))")
    if not np.allclose(state.mass, lammps_masses(state.radius, state.rho), rtol=1e-15, atol=0):
        raise ValueError("lammps_trajectory: masses must be pi r^2 rho (state.rho) for LAMMPS' "
                         "set density/disc; use lammps_masses()")


def write_inputs(folder, state, law, dt, steps, dump_steps, *, newton="on", skin=None):
    """Write ``state.data`` and ``in.trajectory`` into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = state.n
    cfg = io.Configuration(positions=state.x, radii=state.radius, cell=state.h, ids=np.arange(1, n + 1),
                           velocities=state.v, fields={"density": np.full(n, state.rho), "omegaz": state.omega})
    io.write_lammps_data(folder / "state.data", cfg, title="dem.engine.lammps_trajectory state")
    skin = 0.2 * float(np.mean(state.radius)) if skin is None else float(skin)
    text = f"""# written by dem.engine.lammps_trajectory: the same state as the engine's, run {steps} steps
units           lj
dimension       2
atom_style      sphere
boundary        p p p
comm_modify     vel yes
newton          {newton}
read_data       state.data
# read_data gave the 3D mass 4/3 pi r^3 rho: set the disk mass pi r^2 rho
set             group all density/disc {state.rho!r}
{pair_style_line(law)}
pair_coeff      * *
neighbor        {skin!r} bin
neigh_modify    delay 0 every 1 check yes
fix             nve all nve/sphere disc
fix             e2d all enforce2d
timestep        {float(dt)!r}
thermo          {max(1, int(steps))}
variable        nextdump equal "{_next_dump_expr(dump_steps)}"
dump            d all custom 1 traj.dump id x y vx vy omegaz fx fy tqz mass radius
dump_modify     d format float %.17g sort id every v_nextdump
run             {int(steps)}
"""
    (folder / "in.trajectory").write_text(text)


def _read_frames(path):
    """Frames of the text dump written by :func:`write_inputs`: {step: (N, 10) array}."""
    frames = {}
    lines = Path(path).read_text().splitlines()
    k = 0
    while k < len(lines):
        if lines[k].startswith("ITEM: TIMESTEP"):
            step = int(lines[k + 1])
            nat = int(lines[k + 3])
            cols = lines[k + 8].split()[2:]
            rows = lines[k + 9:k + 9 + nat]
            frames[step] = (cols, np.array([r.split() for r in rows], dtype=np.float64))
            k += 9 + nat
        else:
            k += 1
    return frames


def lammps_trajectory(state, law, dt, steps, dump_steps, *, newton="on", skin=None, folder=None,
                      lmp="lmp", timeout=600) -> Trajectory:
    """Run ``state`` (not modified) for ``steps`` steps in LAMMPS and return the snapshots at
    ``dump_steps`` (positive step numbers), with half-step velocities (module docstring)."""
    if not lammps_available(lmp):
        raise FileNotFoundError(f"LAMMPS binary {lmp!r} not on PATH")
    _check_state(state)
    with tempfile.TemporaryDirectory(prefix="dem-lammps-traj-") as tmp:
        work = Path(folder) if folder is not None else Path(tmp)
        write_inputs(work, state, law, dt, steps, dump_steps, newton=newton, skin=skin)
        run_lammps(work, lmp=lmp, input_name="in.trajectory", timeout=timeout)
        frames = _read_frames(work / "traj.dump")
    want = sorted(set(int(s) for s in dump_steps))
    missing = [s for s in want if s not in frames]
    if missing:
        raise RuntimeError(f"LAMMPS dump has no frame at steps {missing}")
    order = np.asarray(state.ids, dtype=np.int64)  # LAMMPS id = original label + 1, sorted by id
    xs, vs, ws = [], [], []
    for s in want:
        cols, a = frames[s]
        c = {name: a[:, m] for m, name in enumerate(cols)}
        dtf = 0.5 * float(dt)
        dtfm = dtf / c["mass"]
        vx = c["vx"] - dtfm * c["fx"]
        vy = c["vy"] - dtfm * c["fy"]
        dtirot = (dtf / 0.5) / (c["radius"] * c["radius"] * c["mass"])
        w = c["omegaz"] - dtirot * c["tqz"]
        idx = np.argsort(c["id"].astype(np.int64))
        sel = idx[order]
        xs.append(np.column_stack([c["x"], c["y"]])[sel])
        vs.append(np.column_stack([vx, vy])[sel])
        ws.append(w[sel])
    return Trajectory(np.array(want), np.array(xs), np.array(vs), np.array(ws), state.h.copy(),
                      f"lammps newton {newton}")


def engine_trajectory(state, law, dt, steps, dump_steps, *, skin=None, startup="lammps") -> Trajectory:
    """Run a copy of ``state`` for ``steps`` steps here (no local damping, no spatial sorting)."""
    st = state.copy()
    sim = Simulation(st, law, dt=dt, damping=0.0, startup=startup, guard=Guard(check_every=0, unsafe_dt=True),
                     loop=Loop(skin=skin, sort_every=0))
    want = sorted(set(int(s) for s in dump_steps))
    xs, vs, ws = [], [], []
    done = 0
    for s in want:
        sim.run(s - done)
        done = s
        inv = np.argsort(st.ids)
        xs.append(st.x[inv].copy())
        vs.append(st.v[inv].copy())
        ws.append(st.omega[inv].copy())
    if steps > done:
        sim.run(steps - done)
    return Trajectory(np.array(want), np.array(xs), np.array(vs), np.array(ws), state.h.copy(), "engine")


def divergence(a: Trajectory, b: Trajectory, diameter) -> Divergence:
    """Largest differences of ``a`` from ``b`` at their common steps (see :class:`Divergence`)."""
    if not np.array_equal(a.steps, b.steps):
        raise ValueError("trajectories must have the same steps")
    h = b.cell
    hinv = np.linalg.inv(h)
    dx, dv, dw = [], [], []
    for k in range(len(a.steps)):
        d = a.x[k] - b.x[k]
        d -= (np.rint(d @ hinv.T)) @ h.T
        dx.append(np.max(np.hypot(d[:, 0], d[:, 1])) / diameter)
        vr = math.sqrt(np.mean(np.sum(b.v[k] ** 2, axis=1)))
        dv.append(np.max(np.hypot(*(a.v[k] - b.v[k]).T)) / vr)
        wr = math.sqrt(np.mean(b.omega[k] ** 2))
        e = np.max(np.abs(a.omega[k] - b.omega[k]))
        dw.append(e / wr if wr > 0 else (0.0 if e == 0 else math.inf))
    return Divergence(a.steps.copy(), np.array(dx), np.array(dv), np.array(dw))
