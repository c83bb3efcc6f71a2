"""Explicit central-difference dynamics of the free-hexagon assembly (numba force kernel).

This is the free-hexagon method's own integrator, state and time-step bound; the disk engine
(``dem.engine.integrate``) is a different method and neither imports the other. Shared: ``dem.runtime``.

Units: SI per m of thickness (N/m, kg/m, J/m). Tension positive.

Time stepping: central differences in leapfrog form (PFC / velocity Verlet order)::

    v^{n+1/2} = v^{n-1/2} + dt M^-1 (f^n - C v^{n-1/2} - alpha M v^{n-1/2})
    u^{n+1}   = u^n + dt v^{n+1/2}
    f^{n+1}   = F(u^{n+1}, t^{n+1})          (interface states are updated inside F, once per step)

``C`` (``Model.cvis``, per dof) holds boundary dashpots (Lysmer-Kuhlemeyer absorbing boundaries);
``Model.kspr`` per-dof ground springs about ``Model.uref`` (a compliant overburden). Both are zero
unless a scene sets them; their work is booked in D_damp and U.

The narrow, swappable pieces: :func:`step` (one step, any ``forces_fn``, pure numpy) and
:func:`advance` (fused numba loop used by the scene; bit-compatible with ``step`` + :func:`model_forces`).
A step above the Gershgorin bound is refused with ``ValueError`` naming ``dt`` and the limit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit

from ..runtime import InstabilityError          # shared with the disk engine
from .element import element_stiffness
from .interface import Strength, Traction, mc_update, spring_stiffness_rule
from .lattice import make_lattice

__all__ = ["Model", "Cells", "Walls", "Interfaces", "Fault", "Contact", "Kinematics", "step", "advance",
           "model_forces", "assemble_stiffness", "gershgorin_dt",
           "power_dt", "energies", "cell_stress", "ramp_value", "RAMP_CODES", "forces_frozen",
           "free_cells_model", "stored_energy_abs"]

RAMP_CODES = {"instant": 0, "linear": 1, "nonlinear": 2, "none": 3}
# energy/contact accounts in Model.acc: W_E, W_gas, D_break, D_fric, D_damp, D_dash (accumulated);
# V_contact (current contact energy), n_contacts (current), max overlap / d (so far)
# and the parts of D_break, D_fric spent on the planar fault's segments (D_break_fault, D_fric_fault)
ACC = {"W_E": 0, "W_gas": 1, "D_break": 2, "D_fric": 3, "D_damp": 4, "D_dash": 5, "V_contact": 6,
       "n_contacts": 7, "max_overlap": 8, "D_break_fault": 9, "D_fric_fault": 10}
N_ACC = len(ACC)


# Named bundles handed to the numba kernels (numba NamedTuples: fields are read by name, so a new field
# or a reordering cannot swap two arrays silently). Built fresh from the Model at each call.
class Cells(NamedTuple):
    """Per-cell data of the kernels: element stiffness per material ``Kmat`` (nmat,12,12) [N/m per m],
    material index ``mat`` (N,), prestress ``f0`` and dead loads ``fext`` (N,12) [N/m], ground spring
    ``kspr`` [N/m per m] about ``uref`` [m], boundary dashpot ``cvis`` [N s/m per m] (N,12), node mass
    ``mnode`` (N,) [kg/m], inverse node mass ``minv`` (N,12) [1/kg per m] (0 on supports), mass
    damping ``alpha`` [1/s]."""
    Kmat: np.ndarray
    mat: np.ndarray
    f0: np.ndarray
    fext: np.ndarray
    kspr: np.ndarray
    uref: np.ndarray
    cvis: np.ndarray
    mnode: np.ndarray
    minv: np.ndarray
    alpha: float


class Walls(NamedTuple):
    """Eshelby wall loads: cell ``wc`` and node ``wk`` (nw,), force ``FE0`` (nw,2) [N/m] at g = 1, the
    release ramp ``ramp_kind`` (a value of ``RAMP_CODES``) over ``ramp_time`` [s]."""
    wc: np.ndarray
    wk: np.ndarray
    FE0: np.ndarray
    ramp_kind: int
    ramp_time: float


class Interfaces(NamedTuple):
    """The interfaces (constants, then the state arrays the kernels update in place); see
    :class:`Model` for each field. ``cdash`` [N s/m per m] is the dashpot of cracked closed ones."""
    ci: np.ndarray
    ca: np.ndarray
    cj: np.ndarray
    cb: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    L: float
    kn: np.ndarray
    kt: np.ndarray
    ft: np.ndarray
    coh: np.ndarray
    tanphi: np.ndarray
    tanphi_r: np.ndarray
    vent: np.ndarray
    sn0: np.ndarray
    sn: np.ndarray
    tau: np.ndarray
    jtp: np.ndarray
    jnp: np.ndarray
    broken: np.ndarray
    pg: np.ndarray
    cdash: float


class Fault(NamedTuple):
    """The planar fault's segments: per interface its segment ``fseg`` (-1: not a fault edge), the
    segments as CSR ``sidx[sp[s]:sp[s+1]]`` (edges in the order along the line), the edge weights ``sw``
    and each segment's weighted projected length over L, ``slam`` (:meth:`Model.fault_bundle`)."""
    fseg: np.ndarray
    sp: np.ndarray
    sidx: np.ndarray
    slam: np.ndarray
    sw: np.ndarray


class Contact(NamedTuple):
    """The new-neighbour contact: switched ``on``, reference ``centres`` (N,2) [m], lattice neighbours
    ``nbc`` (N,6), interface count ``nif`` (N,), contact distance ``cut`` [m], penalty ``kc`` [N/m per
    m], dashpot ``cc`` [N s/m per m], binning ``grid`` (5,), scratch arrays ``head``, ``nxt``, ``cand``,
    ``pos``, ``vel`` (not part of the state)."""
    on: bool
    centres: np.ndarray
    nbc: np.ndarray
    nif: np.ndarray
    cut: float
    kc: float
    cc: float
    grid: np.ndarray
    head: np.ndarray
    nxt: np.ndarray
    cand: np.ndarray
    pos: np.ndarray
    vel: np.ndarray


class Kinematics(NamedTuple):
    """The kinematic state the kernels advance in place: displacements ``u``, half-step velocities
    ``vh`` and ``vh_prev``, forces ``f`` (N,12) and the energy/contact accounts ``acc`` (``ACC``)."""
    u: np.ndarray
    vh: np.ndarray
    vh_prev: np.ndarray
    f: np.ndarray
    acc: np.ndarray


@dataclass
class Model:
    """Plain arrays of one hexagon assembly (the state the integrator needs, nothing more).

    SI per m of thickness. ``N`` cells, ``nif`` interfaces (pairs of facing edges), ``nw`` Eshelby
    wall loads. A cell has 6 nodes, 12 dofs ordered (x0, y0, x1, y1, ...); arrays of shape (N, 12)
    are per-dof.

    Attributes
    ----------
    centres : ndarray, shape (N, 2)
        Reference cell centres [m].
    mat : ndarray of int, shape (N,)
        Material index of each cell (row of ``Kmat``).
    is_coal : ndarray of bool, shape (N,)
        True for cells of the coal seam.
    Kmat : ndarray, shape (nmat, 12, 12)
        Element stiffness per material [N/m per m].
    f0 : ndarray, shape (N, 12)
        Prestress edge forces sigma0 n L [N/m].
    fext : ndarray, shape (N, 12)
        Dead external loads (boundary tractions, gravity) [N/m].
    mnode : ndarray, shape (N,)
        Node mass m_cell / 6 [kg/m].
    minv : ndarray, shape (N, 12)
        Inverse node mass [m/kg], 0 on constrained dofs.
    geo : dict
        Hexagon geometry of :func:`dem.hexagons.lattice.make_lattice` (node offsets ``x`` [m],
        area ``A`` [m^2], ...).
    ci, ca, cj, cb : ndarray of int, shape (nif,)
        Interface e joins edge ``ca[e]`` (0..5) of cell ``ci[e]`` to edge ``cb[e]`` of cell ``cj[e]``.
    nx, ny : ndarray, shape (nif,)
        Unit normal of the interface, pointing from cell i to cell j [-].
    L : float
        Edge length [m].
    kn, kt : ndarray, shape (nif,)
        Normal and shear penalty stiffness [Pa/m].
    ft : ndarray, shape (nif,)
        Tensile strength [Pa].
    coh : ndarray, shape (nif,)
        Cohesion [Pa].
    tanphi, tanphi_r : ndarray, shape (nif,)
        Tangent of the peak and of the residual friction angle [-].
    vent : ndarray, shape (nif,)
        Opening beyond which the gas of a cracked interface escapes [m].
    sn0 : ndarray, shape (nif,)
        Virgin normal traction of the interface [Pa], tension positive.
    is_disl : ndarray of bool, shape (nif,)
        True on dislocation (fault) interfaces.
    sn, tau : ndarray, shape (nif,)
        Current normal and shear traction [Pa] (interface state).
    jtp, jnp : ndarray, shape (nif,)
        Tangential and normal displacement jump at the previous step [m].
    broken : ndarray of int, shape (nif,)
        0 intact, 1 broke in tension, 2 broke in shear.
    pg : ndarray, shape (nif,)
        Gas pressure on the interface faces [Pa] (0 once vented).
    wc, wk : ndarray of int, shape (nw,)
        Cell and node (0..5) of each Eshelby wall load.
    FE0 : ndarray, shape (nw, 2)
        Eshelby wall force at t = 0 [N/m], scaled by ``ramp_value``.
    ramp_kind : int
        Code of the release ramp (values of ``RAMP_CODES``).
    ramp_time : float
        Duration of the release ramp [s].
    alpha : float
        Mass-proportional damping [1/s].
    cdash : float
        Dashpot on cracked, closed interfaces [N s/m per m].
    v_abort : float
        Runaway guard: a speed above it raises ``InstabilityError`` [m/s].
    dt_last : float
        Last time step used [s].
    u : ndarray, shape (N, 12)
        Node displacements [m].
    vh : ndarray, shape (N, 12)
        Half-step velocity v^{n-1/2} (after a step v^{n+1/2}) [m/s].
    vh_prev : ndarray, shape (N, 12)
        Half-step velocity of the step before [m/s].
    f : ndarray, shape (N, 12)
        Node forces at the current step [N/m].
    t : float
        Time [s].
    nstep : int
        Number of steps taken.
    acc : ndarray, shape (9,)
        Energy and contact accounts: W_E, W_gas, D_break, D_fric, D_damp, D_dash (accumulated)
        [J/m], V_contact (current) [J/m], n_contacts (current), max overlap / d (so far) [-].
    contact : bool
        Proximity (new-neighbour) contact switched on (:meth:`enable_contact`).
    nbc : ndarray of int, shape (N, 6)
        Lattice neighbour across each edge in this model, -1 if none.
    nif : ndarray of int, shape (N,)
        Number of interfaces of each cell.
    kc : float
        Contact penalty stiffness [N/m per m].
    cc : float
        Contact dashpot [N s/m per m].
    c_cut : float
        Contact distance, the inscribed diameter d = 2 r_in [m].
    grid : ndarray, shape (5,)
        (x0 [m], y0 [m], h [m], nbx, nby) of the fixed binning grid of the contact search.
    u0 : ndarray, shape (N, 12)
        Displacements at the start of the run [m].
    U0 : float
        Stored energy at the start of the run [J/m] (:func:`dem.hexagons.dynamics.stored_energy_abs`).
    cvis : ndarray, shape (N, 12)
        Per-dof boundary dashpot [N s/m per m] (None: zeros).
    kspr : ndarray, shape (N, 12)
        Per-dof ground spring [N/m per m] (None: zeros).
    uref : ndarray, shape (N, 12)
        Reference displacement of the ground springs [m] (None: zeros).
    fseg : ndarray of int, shape (nif,)
        Segment of the planar fault each interface belongs to, -1 if none (None: no planar fault;
        :mod:`dem.hexagons.fault`).
    flam : ndarray, shape (nif,)
        n_e . n_f of each fault interface: its edge's projected length on the fault over L [-].
    """
    centres: np.ndarray           # (N,2) m
    mat: np.ndarray               # (N,) int material index
    is_coal: np.ndarray           # (N,) bool
    Kmat: np.ndarray              # (nmat,12,12) N/m per m
    f0: np.ndarray                # (N,12) prestress edge forces sigma0.n L  [N/m]
    fext: np.ndarray              # (N,12) dead external loads (boundary tractions, gravity) [N/m]
    mnode: np.ndarray             # (N,) node mass m_cell/6 [kg/m]
    minv: np.ndarray              # (N,12) inverse node mass, 0 on constrained dofs
    geo: dict                     # hexagon geometry
    # interfaces
    ci: np.ndarray
    ca: np.ndarray
    cj: np.ndarray
    cb: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    L: float
    kn: np.ndarray
    kt: np.ndarray
    ft: np.ndarray
    coh: np.ndarray
    tanphi: np.ndarray
    tanphi_r: np.ndarray
    vent: np.ndarray
    sn0: np.ndarray
    is_disl: np.ndarray
    # interface state
    sn: np.ndarray
    tau: np.ndarray
    jtp: np.ndarray
    jnp: np.ndarray
    broken: np.ndarray
    pg: np.ndarray
    # Eshelby wall loads
    wc: np.ndarray
    wk: np.ndarray
    FE0: np.ndarray               # (nw,2) N/m
    ramp_kind: int = 3
    ramp_time: float = 0.0
    alpha: float = 0.0            # mass-proportional damping [1/s]
    cdash: float = 0.0            # dashpot on cracked closed interfaces [N s/m per m]
    v_abort: float = 1e3          # runaway guard [m/s]
    dt_last: float = 0.0
    # kinematic state
    u: np.ndarray = None
    vh: np.ndarray = None         # v^{n-1/2} after a step: v^{n+1/2}
    vh_prev: np.ndarray = None
    f: np.ndarray = None
    t: float = 0.0
    nstep: int = 0
    # energy accounts [J/m]
    acc: np.ndarray = field(default_factory=lambda: np.zeros(N_ACC))
    # new-neighbour (proximity) contact: off unless switched on by the scene (see enable_contact)
    contact: bool = False
    nbc: np.ndarray = None        # (N,6) lattice neighbour across each edge in this model, -1 if none
    nif: np.ndarray = None        # (N,) number of interfaces of each cell
    kc: float = 0.0               # contact penalty stiffness [N/m per m]
    cc: float = 0.0               # contact dashpot [N s/m per m] (same ratio as cdash)
    c_cut: float = 0.0            # contact distance = inscribed diameter d = 2 r_in [m]
    grid: np.ndarray = None       # (x0, y0, h, nbx, nby) of the fixed binning grid
    u0: np.ndarray = None
    U0: float = 0.0
    # boundary devices (zeros unless a scene sets them): per-dof dashpot [N s/m per m], ground
    # spring [N/m per m] about the reference displacement uref [m]
    cvis: np.ndarray = None
    kspr: np.ndarray = None
    uref: np.ndarray = None
    # the planar fault (None: no fault law; every interface follows its own edge's law)
    fseg: np.ndarray = None
    flam: np.ndarray = None

    def fault_bundle(self):
        """The :class:`~dem.hexagons.dynamics.Fault` bundle: per interface its segment (-1: not a fault
        edge), the segments as CSR (``sidx[sp[s]:sp[s+1]]``, edges in the order along the line), the
        edge weights ``sw`` (1; 1/2, 1, 1/2 in a triple) and each segment's weighted projected length
        over L, ``slam[s] = sum_e sw flam[e]`` (computed once, not part of the state)."""
        if getattr(self, "_fargs", None) is not None and self._fkey is self.fseg \
                and len(self._fargs.fseg) == len(self.ci):
            return self._fargs
        nifc = len(self.ci)
        if self.fseg is None or not np.any(self.fseg >= 0):
            fseg = -np.ones(nifc, np.int64)
            args = Fault(fseg, np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        else:
            fseg = np.asarray(self.fseg, np.int64)
            nseg = int(fseg.max()) + 1
            e = np.nonzero(fseg >= 0)[0]
            order = e[np.argsort(fseg[e], kind="stable")]
            cnt = np.bincount(fseg[e], minlength=nseg)
            sp_ = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
            w = np.ones(len(order))
            for s_ in np.nonzero(cnt == 3)[0]:          # a triple a, b, a: weights 1/2, 1, 1/2
                q = np.arange(sp_[s_], sp_[s_] + 3)
                fam = self.ca[order[q]]                    # the edge family (edge number of cell i)
                for k in range(3):
                    w[q[k]] = 1.0 if np.sum(fam == fam[k]) == 1 else 0.5
            slam = np.bincount(fseg[order], weights=w * self.flam[order], minlength=nseg).astype(float)
            args = Fault(fseg=fseg, sp=sp_, sidx=order.astype(np.int64), slam=slam, sw=w)
        self._fkey = self.fseg
        self._fargs = args
        return args

    def devices(self):
        """(cvis, kspr, uref) arrays of shape (N,12), zeros when the scene has none."""
        N = self.n_cells
        if self.cvis is None:
            self.cvis = np.zeros((N, 12))
        if self.kspr is None:
            self.kspr = np.zeros((N, 12))
        if self.uref is None:
            self.uref = np.zeros((N, 12))
        return self.cvis, self.kspr, self.uref

    @property
    def n_cells(self):
        """Number of cells N."""
        return len(self.centres)

    @property
    def n_ifc(self):
        """Number of interfaces."""
        return len(self.ci)

    def enable_contact(self, kc: float, cc: float = 0.0, margin: float | None = None):
        """Switch on the proximity contact between cells that were not lattice neighbours, for
        cells with a broken interface (or no interface at all). ``kc`` [N/m per m] penalty along
        the centre line when the centre distance is below the inscribed diameter d = 2 r_in."""
        N = self.n_cells
        self.nbc = -np.ones((N, 6), np.int64)
        self.nbc[self.ci, self.ca] = self.cj
        self.nbc[self.cj, self.cb] = self.ci
        self.nif = (np.bincount(self.ci, minlength=N) + np.bincount(self.cj, minlength=N)).astype(np.int64)
        d = 2.0 * float(np.linalg.norm(self.geo["x"][0]))       # 2 r_in (edge midpoints lie at r_in)
        self.c_cut = d
        self.kc = float(kc)
        self.cc = float(cc)
        h = 1.0001 * d
        margin = 2 * d if margin is None else margin
        lo = self.centres.min(axis=0) - margin
        hi = self.centres.max(axis=0) + margin
        nb = np.ceil((hi - lo) / h).astype(int) + 1
        self.grid = np.array([lo[0], lo[1], h, nb[0], nb[1]], float)
        self._cscratch = None
        self.contact = True
        return self

    def contact_bundle(self):
        """The :class:`~dem.hexagons.dynamics.Contact` bundle (scratch arrays allocated once, not part of
        the state); tiny dummies with ``on=False`` when the contact is off."""
        if not self.contact:
            i1 = np.zeros(1, np.int64)
            return Contact(False, np.zeros((1, 2)), -np.ones((1, 6), np.int64), i1, 0.0, 0.0, 0.0, np.zeros(5),
                           i1.copy(), i1.copy(), i1.copy(), np.zeros((1, 2)), np.zeros((1, 2)))
        N = self.n_cells
        if getattr(self, "_cscratch", None) is None:
            nbins = int(self.grid[3]) * int(self.grid[4])
            self._cscratch = (np.empty(nbins, np.int64), np.empty(N, np.int64), np.empty(N, np.int64),
                              np.empty((N, 2)), np.empty((N, 2)))
        head, nxt, cand, pos, vel = self._cscratch
        return Contact(on=True, centres=self.centres, nbc=self.nbc, nif=self.nif, cut=float(self.c_cut),
                       kc=float(self.kc), cc=float(self.cc), grid=self.grid, head=head, nxt=nxt, cand=cand,
                       pos=pos, vel=vel)

    def interfaces_bundle(self):
        """The :class:`~dem.hexagons.dynamics.Interfaces` bundle (the model's own arrays: the kernels
        update the state)."""
        return Interfaces(ci=self.ci, ca=self.ca, cj=self.cj, cb=self.cb, nx=self.nx, ny=self.ny, L=float(self.L),
                          kn=self.kn, kt=self.kt, ft=self.ft, coh=self.coh, tanphi=self.tanphi,
                          tanphi_r=self.tanphi_r, vent=self.vent, sn0=self.sn0, sn=self.sn, tau=self.tau,
                          jtp=self.jtp, jnp=self.jnp, broken=self.broken, pg=self.pg, cdash=float(self.cdash))

    def cells_bundle(self):
        """The :class:`~dem.hexagons.dynamics.Cells` bundle."""
        cvis, kspr, uref = self.devices()
        return Cells(Kmat=self.Kmat, mat=self.mat, f0=self.f0, fext=self.fext, kspr=kspr, uref=uref, cvis=cvis,
                     mnode=self.mnode, minv=self.minv, alpha=float(self.alpha))

    def walls_bundle(self):
        """The :class:`~dem.hexagons.dynamics.Walls` bundle."""
        return Walls(wc=self.wc, wk=self.wk, FE0=self.FE0, ramp_kind=int(self.ramp_kind),
                     ramp_time=float(self.ramp_time))


@njit(cache=True)
def ramp_value(kind, Tr, t):
    """g(t): Eshelby-force factor, 1 at t=0, 0 at t >= Tr. kind 0 instant, 1 linear,
    2 nonlinear 3DEC-style 0.95**(100 t/Tr) (set to 0 at Tr), 3 none (g = 1 always)."""
    if kind == 3:
        return 1.0
    if kind == 0 or Tr <= 0.0:
        return 1.0 if t <= 0.0 else 0.0
    if t >= Tr:
        return 0.0
    if kind == 1:
        return 1.0 - t / Tr
    return 0.95 ** (100.0 * t / Tr)


@njit(cache=True)
def _forces(u, f, vh, acc, g, dt, cells, walls, ifc, fault):
    """Node forces f (N,12) [N/m] of the displacements u at the Eshelby factor g; updates the interface
    state (``ifc``) and the accounts ``acc`` (``vh``: the lagged velocity of the dashpots, ``dt`` [s])."""
    Kmat, mat, f0, fext, kspr, uref = cells.Kmat, cells.mat, cells.f0, cells.fext, cells.kspr, cells.uref
    wc, wk, FE0 = walls.wc, walls.wk, walls.FE0
    ci, ca, cj, cb, nx, ny, L = ifc.ci, ifc.ca, ifc.cj, ifc.cb, ifc.nx, ifc.ny, ifc.L
    kn, kt, ft, coh, tanphi, tanphi_r, vent, sn0 = (ifc.kn, ifc.kt, ifc.ft, ifc.coh, ifc.tanphi, ifc.tanphi_r,
                                                    ifc.vent, ifc.sn0)
    sn, tau, jtp, jnp, broken, pg, cdash = ifc.sn, ifc.tau, ifc.jtp, ifc.jnp, ifc.broken, ifc.pg, ifc.cdash
    fseg = fault.fseg
    N = u.shape[0]
    for c in range(N):
        K = Kmat[mat[c]]
        for r in range(12):
            s = f0[c, r]
            for q in range(12):
                s += K[r, q] * u[c, q]
            f[c, r] = fext[c, r] - s - kspr[c, r] * (u[c, r] - uref[c, r])
    for w in range(wc.shape[0]):
        c = wc[w]
        k = wk[w]
        f[c, 2 * k] += g * FE0[w, 0]
        f[c, 2 * k + 1] += g * FE0[w, 1]
    d_break = 0.0
    d_fric = 0.0
    w_gas = 0.0
    d_dash = 0.0
    for e in range(ci.shape[0]):
        if fseg[e] >= 0:
            continue                      # an edge of the planar fault: segment law below
        i = ci[e]
        a = ca[e]
        j = cj[e]
        b = cb[e]
        dux = u[j, 2 * b] - u[i, 2 * a]
        duy = u[j, 2 * b + 1] - u[i, 2 * a + 1]
        n_x = nx[e]
        n_y = ny[e]
        jn = dux * n_x + duy * n_y
        jt = -dux * n_y + duy * n_x
        pg_old = pg[e]
        state = Traction(sn0[e], tau[e], broken[e], pg_old)
        law = Strength(kn[e], kt[e], ft[e], coh[e], tanphi[e], tanphi_r[e], vent[e])
        s_n, ta, br, pgn, db, df, is_open = mc_update(jn, jt - jtp[e], state, law)
        if is_open and pg_old > 0.0:
            w_gas += L * pg_old * (jn - jnp[e])
        jtp[e] = jt
        jnp[e] = jn
        sn[e] = s_n
        tau[e] = ta
        broken[e] = br
        pg[e] = pgn
        d_break += L * db
        d_fric += L * df
        Fx = L * (s_n * n_x - ta * n_y)
        Fy = L * (s_n * n_y + ta * n_x)
        if br > 0 and cdash > 0.0 and (s_n + pgn) < 0.0:
            # contact dashpot on a cracked, closed interface (restitution), lagged velocity v^{n+1/2}
            dvx = vh[j, 2 * b] - vh[i, 2 * a]
            dvy = vh[j, 2 * b + 1] - vh[i, 2 * a + 1]
            Fx += cdash * dvx
            Fy += cdash * dvy
            d_dash += cdash * (dvx * dvx + dvy * dvy) * dt
        f[i, 2 * a] += Fx
        f[i, 2 * a + 1] += Fy
        f[j, 2 * b] -= Fx
        f[j, 2 * b + 1] -= Fy
    if fault.sp.shape[0] > 1:
        fb, ff, fg, fd = _fault_segments(u, f, vh, dt, ifc, fault)
        d_break += fb
        d_fric += ff
        w_gas += fg
        d_dash += fd
        acc[9] += fb
        acc[10] += ff
    acc[1] += w_gas
    acc[2] += d_break
    acc[3] += d_fric
    acc[5] += d_dash


# The three passes per segment (trial tractions; strength check and one shared plastic slip; edge forces)
# share the segment's sums and break state, so the kernel keeps them together.
# long: a numba loop over the fault's segments, whose three passes share each segment's sums
@njit(cache=True)
def _fault_segments(u, f, vh, dt, ifc, fault):
    """The planar fault: Mohr-Coulomb on the true plane, per segment of the zigzag of lattice edges.

    Segment ``s`` owns the interfaces ``sidx[sp[s]:sp[s+1]]`` with weights ``sw`` (1 and 1 for a pair,
    1/2, 1, 1/2 for the triple that closes a line crossing an odd number of edges) and has
    ``lam = slam[s] = sum_e w_e n_e . n_f`` (consecutive edges along the fault line,
    one of each of the two edge orientations). Their frame (``nx``, ``ny``) is the fault's normal
    n_f, their preload ``sn0``, ``tau0`` is the virgin traction vector sigma0 n_e of the edge in that
    frame, and the gas pressure ``pg`` is p_g (n_e . n_f), so that for a uniform stress sigma the
    sums over a segment are exact:

        sum_e w_e sn_e = lam sigma_nf,  sum_e w_e tau_e = lam tau_f,  sum_e w_e pg_e = lam p_g,
        lam = sum_e w_e n_e . n_f      (sum_e w_e n_e = lam n_f: the two families weigh the same)

    The strength check uses the fault tractions sigma_f = sum w sn / lam, tau_f = sum w tau / lam (tension
    if sigma_f + p_g >= ft, shear if |tau_f| >= c - (sigma_f + p_g) tan phi); once broken, every edge
    keeps the no-tension cut-off of the broken law (gas on the faces, vented per edge) and the
    segment's weighted shear sum is returned onto |sum w tau| <= -sum w (sn + pg) tan phi_r by one
    plastic slip shared by its edges (equal shear decrements: the edges have the same kt). Energies as
    in :func:`dem.hexagons.interface.mc_update`: the drop at a break in d_break, the plastic work (the
    edges' shear forces times the slip) in d_fric. Returns (d_break, d_fric, w_gas, d_dash) [J/m]."""
    ci, ca, cj, cb, nx, ny, L = ifc.ci, ifc.ca, ifc.cj, ifc.cb, ifc.nx, ifc.ny, ifc.L
    kn, kt, ft, coh, tanphi, tanphi_r, vent, sn0 = (ifc.kn, ifc.kt, ifc.ft, ifc.coh, ifc.tanphi, ifc.tanphi_r,
                                                    ifc.vent, ifc.sn0)
    sn, tau, jtp, jnp, broken, pg, cdash = ifc.sn, ifc.tau, ifc.jtp, ifc.jnp, ifc.broken, ifc.pg, ifc.cdash
    sp, sidx, slam, sw = fault.sp, fault.sidx, fault.slam, fault.sw
    d_break = 0.0
    d_fric = 0.0
    w_gas = 0.0
    d_dash = 0.0
    nseg = sp.shape[0] - 1
    for s in range(nseg):
        lo = sp[s]
        hi = sp[s + 1]
        m = hi - lo
        if m == 0:
            continue
        e0 = sidx[lo]
        lam = slam[s]
        n_tr = 0.0
        t_tr = 0.0
        p_sum = 0.0
        e_before = 0.0
        for q in range(lo, hi):
            e = sidx[q]
            i = ci[e]
            a = ca[e]
            j = cj[e]
            b = cb[e]
            dux = u[j, 2 * b] - u[i, 2 * a]
            duy = u[j, 2 * b + 1] - u[i, 2 * a + 1]
            jn = dux * nx[e] + duy * ny[e]
            jt = -dux * ny[e] + duy * nx[e]
            s_tr = sn0[e] + kn[e] * jn
            t_e = tau[e] + kt[e] * (jt - jtp[e])
            # keep the trial values in the state arrays (overwritten below); jumps in jnp/jtp after use
            sn[e] = s_tr
            tau[e] = t_e
            w = sw[q]
            n_tr += w * s_tr
            t_tr += w * t_e
            p_sum += w * pg[e]
            e_before += 0.5 * s_tr * s_tr / kn[e] + 0.5 * t_e * t_e / kt[e]
        br = broken[e0]
        newly = False
        if br == 0:
            spf = (n_tr + p_sum) / lam
            lim = coh[e0] - spf * tanphi[e0]
            if spf >= ft[e0]:
                br = 1
                newly = True
            elif abs(t_tr) / lam >= lim:
                br = 2
                newly = True
        d_vent = 0.0
        if br > 0:
            n_eff = 0.0
            for q in range(lo, hi):
                e = sidx[q]
                pge = pg[e]
                spb = sn[e] + pge
                if spb > 0.0 and pge > 0.0:
                    # gas work on the open faces (pressure before venting), as in the edge law
                    dux = u[cj[e], 2 * cb[e]] - u[ci[e], 2 * ca[e]]
                    duy = u[cj[e], 2 * cb[e] + 1] - u[ci[e], 2 * ca[e] + 1]
                    w_gas += L * pge * (dux * nx[e] + duy * ny[e] - jnp[e])
                if spb > 0.0:
                    if pge > 0.0 and spb / kn[e] > vent[e]:
                        d_vent += 0.5 * pge * pge / kn[e]
                        pge = 0.0
                        pg[e] = 0.0
                    spb = 0.0
                sn[e] = spb - pge
                n_eff += sw[q] * spb
            limr = -n_eff * tanphi_r[e0]
            t_new = t_tr
            if t_tr > limr:
                t_new = limr
            elif t_tr < -limr:
                t_new = -limr
            wsum = 0.0
            for q in range(lo, hi):
                wsum += sw[q]
            dl = (t_tr - t_new) / wsum          # the shear decrement of every edge: one shared slip
            t_all = 0.0
            if dl != 0.0:
                for q in range(lo, hi):
                    tau[sidx[q]] -= dl
                    t_all += tau[sidx[q]]
            if newly:
                e_after = 0.0
                for q in range(lo, hi):
                    e = sidx[q]
                    e_after += 0.5 * sn[e] * sn[e] / kn[e] + 0.5 * tau[e] * tau[e] / kt[e]
                d_break += L * (e_before - e_after)
            else:
                d_fric += L * t_all * dl / kt[e0]       # sum of the edge forces times the slip dl/kt
                d_break += L * d_vent
        for q in range(lo, hi):
            e = sidx[q]
            i = ci[e]
            a = ca[e]
            j = cj[e]
            b = cb[e]
            n_x = nx[e]
            n_y = ny[e]
            dux = u[j, 2 * b] - u[i, 2 * a]
            duy = u[j, 2 * b + 1] - u[i, 2 * a + 1]
            jn = dux * n_x + duy * n_y
            jt = -dux * n_y + duy * n_x
            pge = pg[e]
            jtp[e] = jt
            jnp[e] = jn
            broken[e] = br
            s_n = sn[e]
            ta = tau[e]
            Fx = L * (s_n * n_x - ta * n_y)
            Fy = L * (s_n * n_y + ta * n_x)
            if br > 0 and cdash > 0.0 and (s_n + pge) < 0.0:
                dvx = vh[j, 2 * b] - vh[i, 2 * a]
                dvy = vh[j, 2 * b + 1] - vh[i, 2 * a + 1]
                Fx += cdash * dvx
                Fy += cdash * dvy
                d_dash += cdash * (dvx * dvx + dvy * dvy) * dt
            f[i, 2 * a] += Fx
            f[i, 2 * a + 1] += Fy
            f[j, 2 * b] -= Fx
            f[j, 2 * b + 1] -= Fy
    return d_break, d_fric, w_gas, d_dash


@njit(cache=True)
def _contacts(u, vh, f, acc, dt, ifc, con):
    """Proximity contact between cells that were not lattice neighbours (new-neighbour contact).

    Candidates: cells with a broken interface or without any interface. A pair (i, j) with at least
    one candidate, not neighbours in the lattice, whose current centres (mean of the 6 node
    displacements) are closer than ``cut`` = 2 r_in gets a penalty force kc (cut - dist) along the
    centre line (the hexagons' inscribed disks overlap), plus an optional dashpot cc on the normal
    relative velocity (lagged v^{n+1/2}). The force is spread as F/6 on the 6 nodes (exactly the
    gradient of the potential 1/2 kc overlap^2 of the mean-node centres: it loads rigid translation
    only). Binning on a fixed grid of spacing >= cut (positions clamped into it, which keeps
    neighbouring bins neighbouring). Writes V_contact, n_contacts, max overlap/cut into acc[6:9];
    returns the dashpot work of the step [J/m]."""
    ci, cj, broken = ifc.ci, ifc.cj, ifc.broken
    centres, nbc, nif, cut, kc, cc, grid = con.centres, con.nbc, con.nif, con.cut, con.kc, con.cc, con.grid
    head, nxt, cand, pos, vel = con.head, con.nxt, con.cand, con.pos, con.vel
    N = u.shape[0]
    nc = 0
    for c in range(N):
        cand[c] = 1 if nif[c] == 0 else 0
        nc += cand[c]
    for e in range(ci.shape[0]):
        if broken[e] > 0:
            if cand[ci[e]] == 0:
                cand[ci[e]] = 1
                nc += 1
            if cand[cj[e]] == 0:
                cand[cj[e]] = 1
                nc += 1
    acc[6] = 0.0
    acc[7] = 0.0
    if nc == 0:
        return 0.0
    x0 = grid[0]
    y0 = grid[1]
    h = grid[2]
    nbx = int(grid[3])
    nby = int(grid[4])
    for b in range(head.shape[0]):
        head[b] = -1
    for c in range(N):
        sx = 0.0
        sy = 0.0
        wx = 0.0
        wy = 0.0
        for k in range(6):
            sx += u[c, 2 * k]
            sy += u[c, 2 * k + 1]
            wx += vh[c, 2 * k]
            wy += vh[c, 2 * k + 1]
        pos[c, 0] = centres[c, 0] + sx / 6.0
        pos[c, 1] = centres[c, 1] + sy / 6.0
        vel[c, 0] = wx / 6.0
        vel[c, 1] = wy / 6.0
        bx = int(np.floor((pos[c, 0] - x0) / h))
        by = int(np.floor((pos[c, 1] - y0) / h))
        bx = min(max(bx, 0), nbx - 1)
        by = min(max(by, 0), nby - 1)
        b = by * nbx + bx
        nxt[c] = head[b]
        head[b] = c
    V = 0.0
    n_ct = 0
    ovmax = 0.0
    d_dash = 0.0
    cut2 = cut * cut
    for i in range(N):
        if cand[i] == 0:
            continue
        bxi = min(max(int(np.floor((pos[i, 0] - x0) / h)), 0), nbx - 1)
        byi = min(max(int(np.floor((pos[i, 1] - y0) / h)), 0), nby - 1)
        for oy in range(-1, 2):
            by = byi + oy
            if by < 0 or by >= nby:
                continue
            for ox in range(-1, 2):
                bx = bxi + ox
                if bx < 0 or bx >= nbx:
                    continue
                j = head[by * nbx + bx]
                while j >= 0:
                    if j != i and (cand[j] == 0 or j > i):
                        dx = pos[j, 0] - pos[i, 0]
                        dy = pos[j, 1] - pos[i, 1]
                        r2 = dx * dx + dy * dy
                        if r2 < cut2 and r2 > 0.0:
                            isnb = False
                            for k in range(6):
                                if nbc[i, k] == j:
                                    isnb = True
                            if not isnb:
                                r = np.sqrt(r2)
                                ov = cut - r
                                ex = dx / r
                                ey = dy / r
                                F = kc * ov                      # repulsion, on j along +e
                                V += 0.5 * kc * ov * ov
                                if cc > 0.0:
                                    vn = (vel[j, 0] - vel[i, 0]) * ex + (vel[j, 1] - vel[i, 1]) * ey
                                    F -= cc * vn
                                    d_dash += cc * vn * vn * dt
                                fx = F * ex / 6.0
                                fy = F * ey / 6.0
                                for k in range(6):
                                    f[j, 2 * k] += fx
                                    f[j, 2 * k + 1] += fy
                                    f[i, 2 * k] -= fx
                                    f[i, 2 * k + 1] -= fy
                                n_ct += 1
                                if ov > ovmax:
                                    ovmax = ov
                    j = nxt[j]
    acc[6] = V
    acc[7] = n_ct
    if ovmax / cut > acc[8]:
        acc[8] = ovmax / cut
    return d_dash


@njit(cache=True)
def _advance(nsteps, dt, t0, vabort, kin, cells, walls, ifc, fault, con):
    """``nsteps`` central-difference steps of ``dt`` [s] from the time ``t0`` [s] (the state ``kin`` and
    the interface state in ``ifc`` advanced in place). Returns the end time, or -(steps done) when a
    node speed exceeded ``vabort`` [m/s] or became NaN."""
    u, vh, vh_prev, f, acc = kin.u, kin.vh, kin.vh_prev, kin.f, kin.acc
    minv, alpha, cvis, mnode = cells.minv, cells.alpha, cells.cvis, cells.mnode
    wc, wk, FE0, ramp_kind, Tr = walls.wc, walls.wk, walls.FE0, walls.ramp_kind, walls.ramp_time
    N = u.shape[0]
    t = t0
    for s in range(nsteps):
        g_old = ramp_value(ramp_kind, Tr, t)
        g_new = ramp_value(ramp_kind, Tr, t + dt)
        d_damp = 0.0
        for c in range(N):
            m = mnode[c]
            for r in range(12):
                vp = vh[c, r]
                vh_prev[c, r] = vp
                if minv[c, r] > 0.0:
                    cv = cvis[c, r]
                    vn = vp + dt * (minv[c, r] * (f[c, r] - cv * vp) - alpha * vp)
                    d_damp += (alpha * m + cv) * vp * 0.5 * (vp + vn) * dt
                else:
                    vn = 0.0
                vh[c, r] = vn
        w_e = 0.0
        for w in range(wc.shape[0]):
            c = wc[w]
            k = wk[w]
            w_e += 0.5 * (g_old + g_new) * (FE0[w, 0] * vh[c, 2 * k] + FE0[w, 1] * vh[c, 2 * k + 1]) * dt
        for c in range(N):
            for r in range(12):
                u[c, r] += dt * vh[c, r]
        acc[0] += w_e
        acc[4] += d_damp
        t = t0 + (s + 1) * dt
        _forces(u, f, vh, acc, g_new, dt, cells, walls, ifc, fault)
        if con.on:
            acc[5] += _contacts(u, vh, f, acc, dt, ifc, con)
        vm = 0.0
        for c in range(N):
            for r in range(12):
                if abs(vh[c, r]) > vm:
                    vm = abs(vh[c, r])
        if not (vm < vabort):
            return -(s + 1.0)
    return t


def model_forces(model: Model, u: np.ndarray, t: float) -> np.ndarray:
    """F(u, t) of the model (updates the interface states: call once per step)."""
    f = np.empty_like(u)
    g = ramp_value(model.ramp_kind, model.ramp_time, t)
    vh = model.vh if model.vh is not None else np.zeros_like(u)
    ifc = model.interfaces_bundle()
    _forces(u, f, vh, model.acc, g, float(model.dt_last), model.cells_bundle(), model.walls_bundle(), ifc,
            model.fault_bundle())
    if model.contact:
        model.acc[5] += _contacts(u, vh, f, model.acc, float(model.dt_last), ifc, model.contact_bundle())
    return f


def step(state, dt: float, forces_fn, minv, alpha: float = 0.0):
    """One central-difference step of a generic state (dict with 'u', 'vh', 'f', 't').

    ``forces_fn(u, t) -> f``. The narrow interface that a shared DEM integrator can replace.
    Returns the state (updated in place).
    """
    free = minv > 0
    vh = state["vh"]
    vn = np.where(free, vh + dt * (minv * state["f"] - alpha * vh), 0.0)
    state["vh_prev"] = vh
    state["vh"] = vn
    state["u"] = state["u"] + dt * vn
    state["t"] = state["t"] + dt
    state["f"] = forces_fn(state["u"], state["t"])
    return state


def advance(model: Model, nsteps: int, dt: float, dt_limit: float | None = None):
    """Advance the model ``nsteps`` steps of ``dt`` [s] with the fused numba loop.

    ``dt_limit``: the safe bound (Gershgorin); ``dt > dt_limit`` raises ValueError. Pass
    ``dt_limit=np.inf`` only in tests that probe instability on purpose. A runaway (node speed above
    ``v_abort`` or NaN) raises :class:`dem.runtime.InstabilityError` (a RuntimeError) naming the
    step; the model is left at that step (the runner attaches its last good snapshot).
    """
    if dt_limit is None:
        raise ValueError("advance needs dt_limit (use gershgorin_dt(model))")
    if not (dt > 0):
        raise ValueError(f"dt must be > 0, got {dt}")
    if dt > dt_limit:
        raise ValueError(f"time step dt={dt:.4e} s exceeds the stability limit {dt_limit:.4e} s "
                         "(Gershgorin bound 2/sqrt(max_i sum_j |K_ij|/m_i))")
    if model.f is None:
        model.f = model_forces(model, model.u, model.t)
    kin = Kinematics(u=model.u, vh=model.vh, vh_prev=model.vh_prev, f=model.f, acc=model.acc)
    t = _advance(int(nsteps), float(dt), float(model.t), float(model.v_abort), kin, model.cells_bundle(),
                 model.walls_bundle(), model.interfaces_bundle(), model.fault_bundle(), model.contact_bundle())
    model.dt_last = float(dt)
    if t < 0:
        done = int(-t)
        model.t = model.t + done * dt
        model.nstep += done
        raise InstabilityError(f"a node velocity exceeded v_abort={model.v_abort:g} m/s or became NaN at "
                               f"t={model.t:.6g} s (runaway/instability)", None, model.nstep)
    model.t = t
    model.nstep += int(nsteps)
    return model


# ----------------------------------------------------------------------------- linear algebra
def assemble_stiffness(model: Model, intact_only: bool = False):
    """Sparse tangent stiffness (elements + interface springs with kn, kt) over all 12N dofs.

    Broken interfaces are included with their contact stiffness unless ``intact_only``.
    """
    N = model.n_cells
    rows, cols, vals = [], [], []
    base = 12 * np.arange(N)
    r12 = np.arange(12)
    for c in range(N):
        K = model.Kmat[model.mat[c]]
        rr = base[c] + r12
        rows.append(np.repeat(rr, 12))
        cols.append(np.tile(rr, 12))
        vals.append(K.ravel())
    # springs: energy 1/2 L jump^T S jump, jump = u_j,b - u_i,a
    m = np.ones(model.n_ifc, bool) if not intact_only else (model.broken == 0)
    ia = 12 * model.ci[m] + 2 * model.ca[m]
    jb = 12 * model.cj[m] + 2 * model.cb[m]
    nx, ny = model.nx[m], model.ny[m]
    kn, kt, L = model.kn[m], model.kt[m], model.L
    S = np.empty((m.sum(), 2, 2))
    S[:, 0, 0] = L * (kn * nx * nx + kt * ny * ny)
    S[:, 1, 1] = L * (kn * ny * ny + kt * nx * nx)
    S[:, 0, 1] = S[:, 1, 0] = L * (kn - kt) * nx * ny
    for p in range(2):
        for q in range(2):
            for (A, Bn, sgn) in ((ia, ia, 1), (jb, jb, 1), (ia, jb, -1), (jb, ia, -1)):
                rows.append(A + p)
                cols.append(Bn + q)
                vals.append(sgn * S[:, p, q])
    if model.kspr is not None and np.any(model.kspr):
        rows.append(np.arange(12 * N))
        cols.append(np.arange(12 * N))
        vals.append(model.kspr.ravel())
    K = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(12 * N, 12 * N))
    return K


def gershgorin_dt(model: Model, K=None, contact: bool = True) -> float:
    """Safe critical step [s]: 2/sqrt(omega^2) with ``omega^2 = max_i sum_j |K_ij| / m_i`` over the free
    dofs of the assembled lattice (elements + all interface springs), plus, when the proximity
    contact is on (and ``contact``), the bound 2 kc / m_node of the contact springs. They act on the
    cells' mean translation only: a cell of mass 6 m_node pressed by at most 6 others has
    omega_c^2 <= 2 * 6 kc / (6 m_node) (Gershgorin on the cell graph), and the eigenvalues of a sum
    of symmetric matrices add at most (Weyl), so the sum is a safe bound."""
    if K is None:
        K = assemble_stiffness(model)
    free = model.minv.ravel() > 0
    Kf = K[free][:, free]
    rs = np.asarray(abs(Kf).sum(axis=1)).ravel() * model.minv.ravel()[free]
    w2 = rs.max() if rs.size else 0.0
    if contact and model.contact and model.kc > 0:
        w2 += 2.0 * model.kc * model.minv.max()
    w = np.sqrt(w2)
    xi = 0.0
    if model.cvis is not None and np.any(model.cvis):
        # boundary dashpots lagged by half a step: dt <= (2/w)(sqrt(1+xi^2) - xi) (Belytschko et al.)
        xi = float((model.cvis * model.minv).max()) / (2.0 * w)
    return 2.0 / w * (np.sqrt(1.0 + xi * xi) - xi)


def power_dt(model: Model, K=None, iters: int = 3000, seed: int = 0, tol: float = 1e-10) -> float:
    """Critical step 2/omega_max with omega_max^2 the largest eigenvalue of M^-1 K (free dofs),
    by the symmetric Lanczos solver (eigsh) on M^-1/2 K M^-1/2."""
    if K is None:
        K = assemble_stiffness(model)
    free = model.minv.ravel() > 0
    Kf = K[free][:, free]
    s = np.sqrt(model.minv.ravel()[free])
    A = sp.diags(s) @ Kf @ sp.diags(s)
    lam = spla.eigsh(A, k=1, which="LA", tol=tol, maxiter=iters,
                     v0=np.random.default_rng(seed).standard_normal(A.shape[0]))[0][0]
    return 2.0 / np.sqrt(lam)


@njit(cache=True)
def _energy_cells(u, Kmat, mat, f0):
    U = 0.0
    for c in range(u.shape[0]):
        K = Kmat[mat[c]]
        for r in range(12):
            s = 0.0
            for q in range(12):
                s += K[r, q] * u[c, q]
            U += u[c, r] * (0.5 * s + f0[c, r])
    return U


def energies(model: Model) -> dict:
    """Energy accounts [J/m]: U (stored, relative to the start), Ek (synchronous), Ek_shadow
    (1/2 v^{n-1/2} M v^{n+1/2}, the quantity central differences conserve), W_dead, W_E, W_gas,
    D_break, D_fric, D_damp, W_ext, balance residual = W_ext - (dU + Ek_shadow + D)."""
    Uc = _energy_cells(model.u, model.Kmat, model.mat, model.f0)
    Ui = model.L * np.sum(0.5 * model.sn ** 2 / model.kn + 0.5 * model.tau ** 2 / model.kt)
    U = Uc + Ui + _spring_energy(model) - model.U0
    m = model.mnode[:, None]
    vs = 0.5 * (model.vh + model.vh_prev)
    Ek = 0.5 * np.sum(m * vs * vs)
    Eks = 0.5 * np.sum(m * model.vh * model.vh_prev)
    Wd = float(np.sum(model.fext * (model.u - model.u0)))
    W_E, W_gas, D_break, D_fric, D_damp, D_dash, V_c = model.acc[:7]
    U = U + V_c                                     # proximity-contact springs (0 when off)
    W = Wd + W_E + W_gas
    D = D_break + D_fric + D_damp + D_dash
    return {"U": U, "Ek": Ek, "Ek_shadow": Eks, "W_dead": Wd, "W_E": W_E, "W_gas": W_gas,
            "D_break": D_break, "D_fric": D_fric, "D_damp": D_damp, "D_dash": D_dash, "V_contact": V_c, "W_ext": W,
            "residual": W - (U + Eks + D)}


def _spring_energy(model: Model) -> float:
    if model.kspr is None:
        return 0.0
    return float(0.5 * np.sum(model.kspr * (model.u - model.uref) ** 2))


def stored_energy_abs(model: Model) -> float:
    """Absolute stored energy [J/m]: cell strain energy with the prestress, interface springs
    L (sn^2/(2 kn) + tau^2/(2 kt)) and ground springs 1/2 kspr (u - uref)^2."""
    Uc = _energy_cells(model.u, model.Kmat, model.mat, model.f0)
    Ui = model.L * np.sum(0.5 * model.sn ** 2 / model.kn + 0.5 * model.tau ** 2 / model.kt)
    return Uc + Ui + _spring_energy(model)


def cell_stress(model: Model, u=None) -> np.ndarray:
    """Mean Cauchy stress per cell (N,3) [sxx, syy, sxy] Pa: (1/A) sum_k sym(F_k (x) x_k) with
    F = K u + f0 the edge forces the surroundings apply (exact for the hybrid element)."""
    if u is None:
        u = model.u
    F = np.einsum("cij,cj->ci", model.Kmat[model.mat], u) + model.f0
    F = F.reshape(-1, 6, 2)
    x = model.geo["x"]
    A = model.geo["A"]
    sxx = np.sum(F[:, :, 0] * x[None, :, 0], axis=1) / A
    syy = np.sum(F[:, :, 1] * x[None, :, 1], axis=1) / A
    sxy = 0.5 * np.sum(F[:, :, 0] * x[None, :, 1] + F[:, :, 1] * x[None, :, 0], axis=1) / A
    return np.stack([sxx, syy, sxy], axis=1)


def forces_frozen(model: Model, u):
    """F(u, t=0) without changing the model's interface states or energy accounts."""
    saved = [a.copy() for a in (model.sn, model.tau, model.jtp, model.jnp, model.broken, model.pg, model.acc)]
    f = model_forces(model, u, 0.0)
    model.sn, model.tau, model.jtp, model.jnp, model.broken, model.pg, model.acc = saved
    return f


def free_cells_model(centres, velocities, E=50e9, nu=0.25, r_in=0.25, rho=25e3 / 9.81,
                     contact_factor=1.0, contact_damping=0.0, theta0=0.0) -> Model:
    """Unbonded hexagons (no interfaces, no supports) with the new-neighbour contact switched on:
    the smallest model to check the proximity contact (tests). ``centres`` (n,2) m, ``velocities``
    (n,2) m/s (rigid translation of each cell). Contact stiffness and dashpot as in the scene:
    kc = contact_factor * kn L with kn from the Itasca rule."""
    C = np.asarray(centres, float).reshape(-1, 2)
    N = len(C)
    geo = make_lattice(1.0, 1.0, r_in, theta0).geo
    L = geo["L"]
    kn = spring_stiffness_rule([(E, nu)], r_in)
    mnode = np.full(N, rho * geo["A"] / 6.0)
    e64 = np.zeros(0, np.int64)
    z = np.zeros(0)
    m = Model(centres=C, mat=np.zeros(N, np.int64), is_coal=np.zeros(N, bool),
              Kmat=element_stiffness(E, nu, r_in, theta0)[None], f0=np.zeros((N, 12)), fext=np.zeros((N, 12)),
              mnode=mnode, minv=np.full((N, 12), 1.0 / mnode[0]), geo=geo, ci=e64, ca=e64, cj=e64, cb=e64,
              nx=z, ny=z, L=L, kn=z, kt=z, ft=z, coh=z, tanphi=z, tanphi_r=z, vent=z, sn0=z,
              is_disl=np.zeros(0, bool), sn=z.copy(), tau=z.copy(), jtp=z.copy(), jnp=z.copy(), broken=e64.copy(),
              pg=z.copy(), wc=e64, wk=e64, FE0=np.zeros((0, 2)), ramp_kind=RAMP_CODES["none"])
    kc = contact_factor * kn * L
    m.enable_contact(kc, contact_damping * 2.0 * np.sqrt(kc * 6 * mnode[0] / 2.0), margin=10.0 * r_in)
    m.u = np.zeros((N, 12))
    m.u0 = m.u.copy()
    v = np.repeat(np.asarray(velocities, float).reshape(-1, 2), 6, axis=0).reshape(N, 12)
    m.vh = v.copy()
    m.vh_prev = v.copy()
    m.t = 0.0
    m.U0 = stored_energy_abs(m)
    m.f = None
    return m
