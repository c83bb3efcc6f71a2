"""Large packings on LAMMPS: the :mod:`dem.engine.packing` protocol as a LAMMPS input, run, read back.

For packings too large for the numba engine (10^5-10^6 disks), :func:`pack_lammps` writes a LAMMPS
input that prepares a packing with the same contact law and, as far as LAMMPS (29 Sep 2021, GRANULAR
package) allows, the same protocol as :func:`dem.engine.packing.pack`; runs it with ``mpirun -np K lmp``
(serial ``lmp`` if K = 1 or no ``mpirun``); and reads the result back with :mod:`dem.io` into a
:class:`microhom.network.ContactNetwork` with the contact forces LAMMPS computed. The protocol
side by side with :mod:`dem.engine.packing`, and what differs, is in ``docs/scale_out.md``.

Protocol (the input's comments give the details): a proportional pressure servo with the law and
cap of :class:`dem.engine.cell.PressureServo` (``fix deform`` with a variable rate from the virial-only
pressure and the affine stiffness) from the gas on; a compaction phase at light drag that ends when
the packing has jammed (pressure within ``jam_p``, unbalanced force below ``jam_unbalanced``, a
contact network with Z >= ``jam_z``); equilibrium phases at ``mu_prep`` then ``mu`` with a stronger
drag, ended by ``fix halt`` on dem's three stop criteria. Measured against :func:`dem.engine.packing.pack`
in ``docs/scale_out.md``.

Units: any consistent set (the input uses ``units lj``, which does no unit conversion: the numbers
are the caller's). 2D, per unit thickness: LAMMPS's ``dimension 2`` forces and its 2D pressure
(virial over the cell *area*) are then forces per length, as in :mod:`dem.analysis.measure`.
``write_inputs(..., dimension=3)`` (``pack_lammps`` passes it on) writes the same input for
spheres (``docs/spheres.md``): forces [N], pressure [Pa] over the cell volume, the tangential
force of a contact a vector.

Conventions (checked by ``tests/test_lammps.py`` against LAMMPS's own computes):

* contact law ``pair_style gran/hooke/history kn kt gamma_n gamma_t mu 1``: normal force
  ``kn (r_i + r_j - d)`` — LAMMPS's hooke ``kn`` is the force per unit overlap, the same number as
  this project's ``kn`` (OVAL's is twice it); tangential spring ``kt`` on the accumulated shear
  displacement (history), Coulomb cap ``mu |F_n|``. Disks: ``set density/disc`` (mass
  ``rho pi r^2``) and ``fix nve/sphere disc`` (inertia ``m r^2 / 2``), ``fix enforce2d``.
* contacts: ``compute contact/atom`` counts the neighbours with ``d <= r_i + r_j``; the network is
  built with ``from_overlaps(..., tolerance=0)``, the same test.
* stress: ``compute pressure NULL virial`` (no kinetic term; with a temperature compute LAMMPS
  adds ``N k T / A``) gives ``P_ab = (1/A) sum (x_i - x_j)_a f_i,b``; with this project's
  tension-positive Love-Weber stress ``sigma`` (:func:`dem.analysis.measure.stress`, ``symmetric=False``)
  ``P = -sigma^T`` and LAMMPS's scalar pressure ``(P_xx + P_yy)/2`` (2D) equals ``-tr(sigma)/2``.
* contact forces: ``compute pair/local dist force p1 p2 p3`` (``force`` = ``|F_n|`` with the
  sign of a repulsion, ``p1..p3`` = tangential force on the first atom) with
  ``compute property/local patom1 patom2``, dumped once the velocities are zeroed (so the contact
  dashpots carry nothing and ``run 0`` does not advance the shear history).
"""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import time
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import io
from ..io.lammps_run import INPUT_NAME, LammpsRun, read_dump_local, read_run
from .contact_laws import LinearFriction, damping_ratio
from .integrate import critical_dt
from .packing import PackingProtocol, random_gas

__all__ = ["LammpsRun", "write_inputs", "run_lammps", "read_run", "pack_lammps", "lammps_available",
           "read_dump_local", "INPUT_NAME"]


def lammps_available(lmp="lmp") -> bool:
    """True if the LAMMPS binary ``lmp`` is on PATH."""
    return shutil.which(lmp) is not None


def _num(x) -> str:
    """A float as LAMMPS input text, exact (repr round-trips)."""
    return repr(float(x))


def _gas_3d(p):
    """The 3D starting gas of protocol ``p``: ``p.n`` spheres at uniform, independent (seeded by
    ``p.seed``) positions in a cubic periodic cell at solid (volume) fraction ``phi0``; radii
    ``radius`` or uniform in ``radius (1 +- dispersity)``. Returns (positions (N, 3) [m],
    radii (N,) [m], cell side L [m])."""
    if not p.gas_overlaps:
        raise ValueError("gas_overlaps must be True for a 3D LAMMPS packing (the 3D gas is "
                         "uniform and independent; its overlaps are pushed apart by the "
                         "compaction), got False")
    rng = np.random.default_rng(p.seed)
    r = np.full(p.n, float(p.radius))
    if p.dispersity > 0:
        r = p.radius * (1.0 + p.dispersity * rng.uniform(-1.0, 1.0, p.n))
    L = float((4.0 / 3.0 * np.pi * np.sum(r ** 3) / p.phi0) ** (1.0 / 3.0))
    return rng.uniform(0.0, L, (p.n, 3)), r, L


def _possible_contacts_3d(r):
    """(N,) upper bound on the smallest spheres touching each sphere: the sphere of directions
    over the cap each one covers, ``2 / (1 - cos theta)``, ``sin theta = r_min / (r + r_min)``
    (14 for identical spheres, whose kissing number is 12)."""
    rmin = r.min()
    s = rmin / (r + rmin)
    return np.floor(2.0 / (1.0 - np.sqrt(1.0 - s * s)) + 1e-9)


def write_inputs(folder, protocol, *, max_steps=2_000_000, drag=0.1, drag_compaction=0.01,
                 jam_z=3.0, skin=None, dt=None, dimension=2) -> dict:
    """Write ``gas.data`` and ``in.packing`` into ``folder`` for the packing ``protocol`` (a
    :class:`dem.engine.packing.PackingProtocol`, validated there); return the parameters used.

    The protocol is mapped, not repeated: the starting gas is :func:`dem.engine.packing.random_gas` of
    the protocol (``n``, ``seed``, ``radius``, ``dispersity``, ``rho``, ``phi0``,
    ``gas_overlaps``), so both engines start from the same configuration; the contact law takes
    ``kn``, ``kt``, ``mu_prep`` then ``mu`` and ``restitution`` (a normal and tangential
    dashpot ``gamma_n = 2 zeta sqrt(kn / m_eff)`` for a pair of mean disks, ``zeta`` from
    :func:`dem.engine.contact_laws.damping_ratio`: LAMMPS's ``gamma_n`` is one constant for all pairs);
    the servo ``p_target``, ``alpha``, ``max_strain_per_step``; the compaction ends on ``jam_p``
    and ``jam_unbalanced``; the equilibrium phases on ``tol_p``, ``tol_unbalanced``, ``tol_ke``,
    checked every ``check_every`` steps; the time step is ``dt_over_dtcrit`` times
    :func:`dem.engine.integrate.critical_dt`. Not mapped: ``damping``, ``damping_compaction`` and
    ``fire`` (dem's dissipation; LAMMPS 2021 has no Cundall local damping: the drags below play
    their part, and the compaction phase always runs). A protocol with ``growth_dispersity`` > 0
    is refused (no LAMMPS counterpart).

    Parameters
    ----------
    folder : path
        Folder of the run (created if missing).
    protocol : dem.engine.packing.PackingProtocol
        The packing protocol.
    max_steps : int
        Cap on the steps of each phase, >= 1.
    drag, drag_compaction : float
        Global viscous drag ``F = -drag sqrt(kn m) v`` (``fix viscous``), m the mass of a disk of
        the mean radius, >= 0 [-]. It acts on translation only: the spins are zeroed once at the
        start of each equilibrium phase (a lightly loaded disk spinning after the compaction
        would otherwise hold the kinetic-energy criterion for tens of thousands of steps;
        zero-temperature ``fix langevin ... omega yes`` damps the spins too but was 5x slower,
        measured). Light (``drag_compaction``) during the compaction phase, ``drag`` in the
        equilibrium phases (the analogue of dem's ``damping_compaction`` / ``damping``).
    jam_z : float
        The compaction also needs a mean contact number of the disks that have contacts of at
        least ``jam_z``, in [0, 6) (a contact network exists; lower it for mu_prep >~ 1, where
        jammed packings approach Z = 3).
    skin : float or None
        Neighbour skin [m] (default 0.2 mean radius).
    dt : float or None
        Time step [s] overriding the protocol's ``dt_over_dtcrit``.
    dimension : int
        2 (disks, the default) or 3 (spheres). The 3D input is the same deck with the
        dimension's lines (``dimension 3``, ``set density``, ``fix nve/sphere``, no
        ``enforce2d``, a servo on x, y and z, the volume fraction, LAMMPS's 3D pressure). The
        protocol's fields then read: ``radius`` the mean sphere radius [m], ``phi0`` the volume
        fraction of the gas (uniform, independent centres: ``gas_overlaps`` must be True),
        ``rho`` the mass density [kg/m^3] (None: a sphere of the mean radius has unit mass), and
        the target pressure [Pa] is ``p_over_kn * kn / (2 radius)`` (``p_over_kn`` is then
        ``p D / kn``, D the mean diameter: the typical overlap over D, as p/kn is in 2D).
        ``jam_z`` in [0, 12). The time step is ``dt_over_dtcrit`` times
        ``min_i sqrt(m_i / K_i)``, ``K_i`` = the spheres that can touch sphere i times
        ``law.dt_stiffness()``.

    Returns the dict of the values written (``kn``, ``kt``, ``mu``, ``p_target``, ``dt``, ...,
    and ``protocol``, its ``as_dict()``).
    """
    _check_knobs(protocol, dimension, max_steps=max_steps, drag=drag,
                 drag_compaction=drag_compaction, jam_z=jam_z, skin=skin, dt=dt)
    p = protocol
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    law = LinearFriction(kn=p.kn, kt=p.kt, mu=p.mu_prep)
    gas = _start_2d(p, law, dt) if dimension == 2 else _start_3d(p, law, dt)
    _write_gas(folder / "gas.data", p, gas, dimension)
    prm = _parameters(p, gas, dimension, max_steps=max_steps, drag=drag,
                      drag_compaction=drag_compaction, jam_z=jam_z, skin=skin)
    (folder / INPUT_NAME).write_text(_input_text(prm))
    return prm


def _check_knobs(protocol, dimension, **knobs):
    """The checks of :func:`write_inputs`' arguments: a protocol LAMMPS can run, the dimension, and
    each knob in its range (a ValueError naming it and the range)."""
    if not isinstance(protocol, PackingProtocol):
        raise TypeError(f"write_inputs takes a dem.engine.packing.PackingProtocol, got "
                        f"{type(protocol).__name__}")
    if dimension not in (2, 3):
        raise ValueError(f"dimension must be 2 (disks) or 3 (spheres), got {dimension!r}")
    zmax = 6 if dimension == 2 else 12
    if protocol.growth_dispersity > 0:
        raise ValueError(f"growth_dispersity must be 0 for the LAMMPS writer (no LAMMPS "
                         f"counterpart of the grow/restore phases), got {protocol.growth_dispersity}")
    max_steps, drag, drag_compaction = knobs["max_steps"], knobs["drag"], knobs["drag_compaction"]
    jam_z, skin, dt = knobs["jam_z"], knobs["skin"], knobs["dt"]
    for name, val, allowed, ok in (
            ("max_steps", max_steps, "an integer >= 1", int(max_steps) == max_steps >= 1),
            ("drag", drag, ">= 0", drag >= 0), ("drag_compaction", drag_compaction, ">= 0",
                                                  drag_compaction >= 0),
            ("jam_z", jam_z, f"in [0, {zmax})", 0 <= jam_z < zmax),
            ("skin", skin, "None or > 0 [m]", skin is None or skin > 0),
            ("dt", dt, "None or > 0 [s]", dt is None or dt > 0)):
        if not ok or (val is not None and not math.isfinite(val)):
            raise ValueError(f"{name} must be {allowed}, got {val!r}")


class _Gas(NamedTuple):
    """The starting gas of a deck and the numbers derived from it (SI, or the caller's units)."""
    x: np.ndarray          #: (N, d) positions [m]
    r: np.ndarray          #: (N,) radii [m]
    h: np.ndarray          #: (d, d) periodic cell, columns = cell vectors [m]
    rho: float             #: density [kg/m^2] (2D) or [kg/m^3] (3D)
    dt: float              #: time step [s]
    m1: float              #: mass of a particle of the mean radius [kg]
    solid: float           #: area (2D) or volume (3D) of the particles [m^2] or [m^3]
    p_target: float        #: target pressure [N/m] (2D) or [Pa] (3D)


def _start_2d(p, law, dt) -> _Gas:
    """The disks' gas: :func:`dem.engine.packing.random_gas` of ``p``; the time step
    ``dt_over_dtcrit`` times :func:`dem.engine.integrate.critical_dt` unless ``dt`` is given."""
    st = random_gas(p, spins=True)
    x, r, h, rho = st.x, st.radius, st.h, float(st.rho)
    if dt is None:
        dt = p.dt_over_dtcrit * critical_dt(st, law)
    m1 = float(rho * math.pi * p.radius ** 2)
    solid = float(np.pi * np.sum(r ** 2))
    return _Gas(x, r, h, rho, dt, m1, solid, p.p_target)


def _start_3d(p, law, dt) -> _Gas:
    """The spheres' gas: :func:`_gas_3d`; the time step ``dt_over_dtcrit`` times
    ``min_i sqrt(m_i / K_i)`` (``K_i``: :func:`_possible_contacts_3d` times
    ``law.dt_stiffness()``) unless ``dt`` is given; the target pressure ``p_over_kn kn / D``."""
    x, r, L = _gas_3d(p)
    h = np.diag([L, L, L])
    rho = 1.0 / (4.0 / 3.0 * np.pi * p.radius ** 3) if p.rho is None else float(p.rho)
    mass = rho * 4.0 / 3.0 * np.pi * r ** 3
    if dt is None:
        dt = p.dt_over_dtcrit * float(np.min(np.sqrt(
            mass / (_possible_contacts_3d(r) * law.dt_stiffness()))))
    m1 = float(rho * 4.0 / 3.0 * math.pi * p.radius ** 3)
    solid = float(4.0 / 3.0 * np.pi * np.sum(r ** 3))
    p_target = p.p_over_kn * p.kn / (2.0 * p.radius)
    return _Gas(x, r, h, rho, dt, m1, solid, p_target)


def _write_gas(path, p, gas, dimension):
    """The gas as the LAMMPS data file ``path`` (``atom_style sphere``, ids 1..N, no velocities)."""
    n = len(gas.r)
    cfg = io.Configuration(positions=gas.x, radii=gas.r, cell=gas.h, ids=np.arange(1, n + 1),
                           fields={"density": np.full(n, gas.rho)})
    maker = ("dem.engine.packing.random_gas" if dimension == 2 else "dem.engine.lammps._gas_3d")
    io.write_lammps_data(path, cfg, velocities=False,
                         title=f"random gas: {maker}(n={p.n}, seed={p.seed}, phi0={p.phi0})")


def _parameters(p, gas, dimension, *, max_steps, drag, drag_compaction, jam_z, skin) -> dict:
    """The values the deck is written from (:func:`write_inputs`' return value): the protocol's,
    the gas's, and the derived contact dashpot ``gamma_n``, drags, servo rate cap and ``<l^2>``."""
    dt, m1, r = gas.dt, gas.m1, gas.r
    gn = 0.0
    if p.restitution is not None:
        gn = 2.0 * damping_ratio(p.restitution) * math.sqrt(p.kn / (0.5 * m1))
    skin = 0.2 * p.radius if skin is None else float(skin)
    # mean squared branch length of a contact, (r_i + r_j)^2 for independent radii: the affine
    # isotropic stiffness K = sum_c kn |l_c|^2 / (d V) of dem.engine.cell.PressureServo is then
    # kn Nc <l^2> / (d V) (overlaps neglected: a relative error ~ p/kn)
    l2 = float(2.0 * np.mean(r ** 2) + 2.0 * np.mean(r) ** 2)
    return dict(n=p.n, dimension=int(dimension), p_target=gas.p_target, kn=p.kn, kt=p.kt,
                mu=p.mu, mu_prep=p.mu_prep, radius=p.radius, dispersity=p.dispersity,
                rho=gas.rho, seed=p.seed, phi0=p.phi0, dt=float(dt), drag=float(drag),
                drag_compaction=float(drag_compaction),
                gamma_drag=drag * math.sqrt(p.kn * m1),
                gamma_compaction=drag_compaction * math.sqrt(p.kn * m1),
                gamma_n=gn, skin=skin, rate=p.max_strain_per_step / dt, alpha=p.alpha, l2=l2,
                jam_unbalanced=p.jam_unbalanced, jam_p=p.jam_p, jam_z=float(jam_z),
                tol_p=p.tol_p, tol_unbalanced=p.tol_unbalanced, tol_ke=p.tol_ke,
                max_steps=int(max_steps), check_every=p.check_every,
                disk_area=gas.solid, m1=m1, protocol=p.as_dict())


def _drag_fix(drag, p) -> str:
    """Global viscous drag ``drag sqrt(kn m)`` (m: mass of a particle of the mean radius)."""
    gamma = drag * math.sqrt(p["kn"] * p["m1"])
    return f"fix             drag all viscous {_num(gamma)}"


def _dim_lines(d, p) -> dict:
    """The lines of the input that depend on the dimension d (2 disks, 3 spheres)."""
    N = _num
    axes = "xy" if d == 2 else "xyz"
    if d == 2:
        return dict(
            units="2D, per unit thickness", KV="2 A", density=f"density/disc {N(p['rho'])}",
            nve="fix             nve all nve/sphere disc\nfix             e2d all enforce2d",
            omega="omegaz", f2="fx*fx+fy*fy", v2="vx*vx+vy*vy",
            # rotational energy of a disk: I w^2 / 2 = m r^2 w^2 / 4
            rot="0.25*mass*c_prop[1]*c_prop[1]*c_prop[2]*c_prop[2]", volume="lx*ly",
            axes=axes, vel="vx vy fx fy", omega0="0.0 0.0 0.0",
            pres="pxx=$(c_pv[1]:%.17g) pyy=$(c_pv[2]:%.17g) pxy=$(c_pv[4]:%.17g)",
            thermo="c_pv[1] c_pv[2] c_pv[4]", box="lx=$(lx:%.17g) ly=$(ly:%.17g) xy=$(xy:%.17g)")
    return dict(
        units="3D", KV="3 V", density=f"density {N(p['rho'])}", nve="fix             nve all nve/sphere",
        omega="omegax omegay omegaz", f2="fx*fx+fy*fy+fz*fz", v2="vx*vx+vy*vy+vz*vz",
        # rotational energy of a sphere: I |w|^2 / 2 = m r^2 |w|^2 / 5
        rot="0.2*mass*c_prop[1]*c_prop[1]*(c_prop[2]*c_prop[2]+c_prop[3]*c_prop[3]+c_prop[4]*c_prop[4])",
        volume="lx*ly*lz", axes=axes, vel="vx vy vz fx fy fz", omega0="0.0 0.0 0.0",
        pres="pxx=$(c_pv[1]:%.17g) pyy=$(c_pv[2]:%.17g) pzz=$(c_pv[3]:%.17g) pxy=$(c_pv[4]:%.17g) "
             "pxz=$(c_pv[5]:%.17g) pyz=$(c_pv[6]:%.17g)",
        thermo="c_pv[1] c_pv[2] c_pv[3] c_pv[4] c_pv[5] c_pv[6]",
        box="lx=$(lx:%.17g) ly=$(ly:%.17g) lz=$(lz:%.17g) xy=$(xy:%.17g) xz=$(xz:%.17g) "
            "yz=$(yz:%.17g)")


_REPORT = ("steps=$(step) converged=$(v_conv) phi=$(v_phi:%.6f) Z=$(v_Z:%.5f) Zc=$(v_Zc:%.5f) "
           "pressure=$(c_pv:%.10g) rel_p_err=$(v_perr:%.3e) unbalanced=$(v_unb:%.3e) "
           "ke_rel=$(v_kerel:%.3e)")


def _input_text(p) -> str:
    """The input script of the parameters ``p`` (:func:`_parameters`): its blocks in the order
    LAMMPS reads them, separated by a blank line."""
    d = int(p.get("dimension", 2))
    D = _dim_lines(d, p)
    relen = "\n".join(f"variable        l{a}0 equal $(l{a})" for a in D["axes"])
    blocks = [_header_text(p, d, D), _setup_text(p, d, D), _contact_law_text(p, D),
              _measurements_text(p, D), _servo_text(p, d, D, relen),
              _compaction_text(p), _equilibrium_text(p, relen)]
    if p["mu"] != p["mu_prep"]:
        blocks.append(_friction_switch_text(p, relen))
    blocks.append(_final_text(p, D))
    return "\n".join(blocks)


def _header_text(p, d, D) -> str:
    """Comment lines: how to run the deck, the units, the main parameters, the protocol."""
    return f"""\
# LAMMPS input written by dem.engine.lammps.write_inputs: the dem.engine.packing protocol (docs/scale_out.md).
#   lmp -in {INPUT_NAME}            or   mpirun -np K lmp -in {INPUT_NAME}
# Units: the caller's consistent set ('units lj' does no conversion); {D['units']}.
# N={p['n']} p_target={p['p_target']!r} kn={p['kn']!r} kt={p['kt']!r} mu_prep={p['mu_prep']!r} mu={p['mu']!r} seed={p['seed']}{'' if d == 2 else ' dimension=3'}
# protocol {json.dumps(p['protocol'])}
"""


def _setup_text(p, d, D) -> str:
    """Initialization (units, dimension, atom style, periodic boundaries) and the atoms (the gas
    file, their density)."""
    return f"""\
units           lj
dimension       {d}
atom_style      sphere
boundary        p p p
comm_modify     vel yes
newton          on
read_data       gas.data
set             group all {D['density']}
"""


def _contact_law_text(p, D) -> str:
    """The pair style (contact law at ``mu_prep``), the neighbour list, the integrator and the
    time step."""
    N = _num
    return f"""\
# ---- contact law: linear kn (force per overlap, = dem's kn), tangential spring kt with history,
#      Coulomb mu (mu_prep first); contact dashpot gamma_n (0 unless restitution was given) ----
pair_style      gran/hooke/history {N(p['kn'])} {N(p['kt'])} {N(p['gamma_n'])} {N(p['gamma_n'])} {N(p['mu_prep'])} 1
pair_coeff      * *
neighbor        {N(p['skin'])} bin
neigh_modify    delay 0 every 1 check yes
{D['nve']}
timestep        {N(p['dt'])}
"""


def _measurements_text(p, D) -> str:
    """The computes and variables of the stop criteria (pressure, contacts, unbalanced force,
    kinetic energy) and the thermo output."""
    N = _num
    return f"""\
# ---- measurements: pressure without kinetic term (virial only: contact forces), contacts,
#      unbalanced force, kinetic energy of the disks in contact ----
compute         pv all pressure NULL virial
compute         cn all contact/atom
compute         zsum all reduce sum c_cn
variable        hasc atom c_cn>0
compute         nwith all reduce sum v_hasc
compute         pl all pair/local force
compute         fsum all reduce sum c_pl
compute         prop all property/atom radius {D['omega']}
variable        fres atom sqrt({D['f2']})
compute         fres all reduce ave v_fres
variable        kea atom (c_cn>0)*(0.5*mass*({D['v2']})+{D['rot']})
compute         kec all reduce sum v_kea
variable        nc equal c_zsum/2
variable        Z equal c_zsum/atoms
variable        Zc equal c_zsum/(c_nwith+1.0e-300)
variable        phi equal {N(p['disk_area'])}/({D['volume']})
variable        fmean equal c_fsum/(v_nc+1.0e-300)
variable        unb equal c_fres/(v_fmean+1.0e-300)
variable        eel equal v_nc*v_fmean*v_fmean/(2.0*{N(p['kn'])})
variable        kerel equal c_kec/(v_eel+1.0e-300)
variable        perr equal abs(c_pv-{N(p['p_target'])})/{N(p['p_target'])}
variable        conv equal (v_perr<{N(p['tol_p'])})*(v_unb<{N(p['tol_unbalanced'])})*(v_kerel<{N(p['tol_ke'])})
variable        jammed equal (v_perr<{N(p['jam_p'])})*(v_unb<{N(p['jam_unbalanced'])})*(v_Zc>={N(p['jam_z'])})
thermo_style    custom step atoms v_phi v_Z v_Zc c_pv v_perr v_unb v_kerel cpu
thermo_modify   norm no flush yes
thermo          {max(10000, 10 * p['check_every'])}
"""


def _servo_text(p, d, D, relen) -> str:
    """The pressure servo: the strain rate variables and ``fix deform`` on every axis."""
    N = _num
    dl = "\n".join(f"variable        dl{a} equal l{a}*exp(v_edot*{N(p['dt'])})-v_l{a}0"
                   for a in D["axes"])
    vl = "\n".join(f"variable        vl{a} equal v_edot*l{a}" for a in D["axes"])
    deform = " ".join(f"{a} variable v_dl{a} v_vl{a}" for a in D["axes"])
    return f"""\
# ---- pressure servo (dem.engine.cell.PressureServo): isotropic true strain rate
#      edot = -alpha (p_t - p) / (K dt), K = kn Nc <l^2> / ({D['KV']}) the affine stiffness, capped at
#      +-max_strain_per_step/dt (the cap is the rate while there are no contacts). fix deform
#      'variable' sets the box length change since the start of the run: lx(t+dt) = lx exp(edot dt)
#      (lx0, ly0 = the lengths at the start of each run, re-read before every run); fix ave/time
#      every step makes LAMMPS tally the virial on every step (fix deform does not ask for it) ----
variable        Kaff equal {N(p['kn'] * p['l2'] / d)}*v_nc/({D['volume']})
variable        eraw equal -{N(p['alpha'])}*({N(p['p_target'])}-c_pv)/((v_Kaff+{N(1e-12 * p['kn'])})*{N(p['dt'])})
variable        edot equal (v_eraw<{N(-p['rate'])})*{N(-p['rate'])}+(v_eraw>{N(p['rate'])})*{N(p['rate'])}+(v_eraw>={N(-p['rate'])})*(v_eraw<={N(p['rate'])})*v_eraw
{dl}
{vl}
{relen}
fix             ptally all ave/time 1 1 1 c_pv
fix             servo all deform 1 {deform} remap x
"""


def _halted_run(p, k, condition, phase) -> str:
    """A run of at most ``max_steps`` ended by ``fix halt`` on ``condition`` (checked every
    ``check_every`` steps), then a report line ``PACK_PHASE name=<phase> ...``."""
    return f"""\
fix             h{k} all halt {p['check_every']} {condition} > 0.5 error continue
run             {p['max_steps']}
unfix           h{k}
run             0 post no
print           "PACK_PHASE name={phase} {_REPORT}"
"""


def _compaction_text(p) -> str:
    """Phase 1: the servo from the gas at the light drag until the packing has jammed."""
    return f"""\
# ---- 1. compaction (dem: phase 'compact'): servo from the gas (overlaps pushed apart, the cell
#      may grow first) with a light drag, until the packing has jammed ----
{_drag_fix(p['drag_compaction'], p)}
""" + _halted_run(p, 1, "v_jammed", "compact")


def _equilibrium_text(p, relen) -> str:
    """Phase 2: equilibrium at ``mu_prep`` with the equilibrium drag, spins zeroed."""
    return f"""\
# ---- 2. equilibrium at mu_prep with the equilibrium drag; stop criteria (dem: phase 'prep') ----
unfix           drag
{_drag_fix(p['drag'], p)}
set             group all omega 0.0 0.0 0.0
{relen}
""" + _halted_run(p, 2, "v_conv", "prep")


def _friction_switch_text(p, relen) -> str:
    """Phase 3 (when ``mu != mu_prep``): the pair style at the test friction ``mu`` (the contacts'
    shear history kept), equilibrium again."""
    N = _num
    return f"""\
# ---- 3. switch to the test friction mu and equilibrate again (pair history is kept) ----
pair_style      gran/hooke/history {N(p['kn'])} {N(p['kt'])} {N(p['gamma_n'])} {N(p['gamma_n'])} {N(p['mu'])} 1
pair_coeff      * *
set             group all omega 0.0 0.0 0.0
{relen}
""" + _halted_run(p, 3, "v_conv", "test")


def _final_text(p, D) -> str:
    """The final state: servo and drag off, velocities zeroed, the per-atom and per-contact dumps,
    the result line ``PACK_RESULT ...`` and the data file."""
    return f"""\
variable        convf equal $(v_conv)
unfix           servo
unfix           ptally
unfix           drag

# ---- 4. final state: velocities zeroed (no dashpot force; run 0 does not advance the history),
#      positions/radii/forces/contact counts, per-contact forces, LAMMPS's own pressure ----
velocity        all set 0.0 0.0 0.0
set             group all omega 0.0 0.0 0.0
compute         pf all pair/local dist force p1 p2 p3
compute         pp all property/local patom1 patom2
dump            d1 all custom 1 final.dump id type radius x y z {D['vel']} c_cn
dump_modify     d1 format float %.17g sort id first yes
dump            d2 all local 1 contacts.dump c_pp[1] c_pp[2] c_pf[1] c_pf[2] c_pf[3] c_pf[4] c_pf[5]
dump_modify     d2 format float %.17g first yes
thermo_style    custom step atoms v_phi v_Z c_pv {D['thermo']} v_unb
thermo          1
run             0
undump          d1
undump          d2
print           "PACK_RESULT N=$(atoms) steps=$(step) converged=${{convf}} phi=$(v_phi:%.17g) Z=$(v_Z:%.17g) pressure=$(c_pv:%.17g) {D['pres']} unbalanced=$(v_unb:%.6e) {D['box']}"
write_data      final.data nocoeff
"""


def run_lammps(folder, *, np=1, lmp="lmp", mpirun="mpirun", input_name=INPUT_NAME, timeout=None,
               extra_args=()) -> dict:
    """Run ``lmp -in input_name`` in ``folder`` (``mpirun -np np`` when np > 1 and mpirun exists).

    Returns ``{"wall_s", "np", "command", "log", "returncode"}``; raises RuntimeError (with the
    log's tail) if LAMMPS fails. Runs as root get OpenMPI's allow-run-as-root variables set, and
    ``--oversubscribe`` lets np exceed the cores (slower, but runs).
    """
    folder = Path(folder)
    if shutil.which(lmp) is None:
        raise FileNotFoundError(f"LAMMPS binary {lmp!r} not found on PATH (Debian: apt-get install lammps)")
    cmd = [lmp, "-in", input_name, "-log", "log.lammps", "-screen", "none", *extra_args]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    used_np = 1
    if np > 1 and shutil.which(mpirun):
        cmd = [mpirun, "-np", str(int(np)), "--oversubscribe", *cmd]
        used_np = int(np)
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=folder, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    log = folder / "log.lammps"
    if proc.returncode != 0:
        tail = log.read_text(errors="replace")[-3000:] if log.exists() else ""
        raise RuntimeError(f"LAMMPS failed (exit {proc.returncode}): {' '.join(cmd)}\n"
                           f"{proc.stdout[-2000:]}{proc.stderr[-2000:]}\n--- log tail ---\n{tail}")
    return {"wall_s": wall, "np": used_np, "command": " ".join(cmd), "log": str(log),
            "returncode": proc.returncode}


def pack_lammps(protocol, folder, *, np=1, lmp="lmp", timeout=None, **knobs) -> LammpsRun:
    """Write the inputs of ``protocol`` (a :class:`dem.engine.packing.PackingProtocol`;
    :func:`write_inputs`, with its LAMMPS ``knobs``), run LAMMPS (:func:`run_lammps` with ``np``
    MPI ranks) and read the result (:func:`read_run`)."""
    prm = write_inputs(folder, protocol, **knobs)
    info = run_lammps(folder, np=np, lmp=lmp, timeout=timeout)
    t0 = time.perf_counter()
    res = read_run(folder, prm)
    return replace(res, run=info, timing={**res.timing, "read_s": time.perf_counter() - t0,
                                          "lammps_wall_s": info["wall_s"]})
