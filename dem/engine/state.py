"""Particle state of a 2D disk assembly as a structure of arrays, with atomic npz checkpoints.

Units: any consistent set (SI or scaled). 2D: quantities are per unit thickness, so ``rho`` is an
areal density [kg/m^2] with disk mass ``m = rho * pi * r^2`` [kg/m] and moment of inertia
``I = m r^2 / 2`` (disks are disks, not spheres).

The state is everything a bit-exact restart needs: particle arrays, the periodic cell (shape matrix
``h``, columns = cell vectors, and velocity gradient ``L``), the Verlet list with its tangential
contact history and the reference configuration of the last neighbour build, step counter and time,
plus a small ``meta`` dict of scalars (servo state, counters) kept as JSON.

Velocities ``v`` are *fluctuations* about the affine field of the cell: the total velocity of a
particle at ``x`` is ``v + L x`` (Yade ``homoDeform`` style).

A scene that needs no spins carries no spin arrays: ``omega`` (angular velocity [rad/s]) and
``theta`` (accumulated rotation [rad]) are ``None`` then; ``nl_ft`` (tangential history) is ``None``
for laws without history.
"""
from __future__ import annotations

import json
import os
import zipfile
import zlib
from dataclasses import dataclass, field, fields

import numpy as np

from ..runtime import atomic_write

__all__ = ["State", "disk_mass"]


def disk_mass(radius, rho):
    """Mass per unit thickness of disks of the given radius [m] and areal density rho [kg/m^2]."""
    return rho * np.pi * np.asarray(radius, dtype=np.float64) ** 2


_ARRAYS = ("x", "v", "radius", "mass", "inertia", "omega", "theta", "ids", "h", "L",
           "nl_i", "nl_j", "nl_shift", "nl_ft", "x_ref", "h_ref")



@dataclass(eq=False)
class State:
    """Structure-of-arrays state of N disks in a periodic deformable cell.

    x : (N, 2) positions [m];  v : (N, 2) fluctuation velocities [m/s] (total = v + L x);
    radius, mass, inertia : (N,) [m], [kg/m], [kg m] (per unit thickness), inertia = m r^2 / 2;
    omega, theta : (N,) angular velocity and rotation, or None (no spins);
    ids : (N,) int64 original labels (particles are re-ordered by spatial sorting);
    h : (2, 2) cell shape matrix (columns = cell vectors) [m];  L : (2, 2) velocity gradient [1/s];
    rho : areal density [kg/m^2] used to build masses (informative);
    nl_i, nl_j, nl_shift, nl_ft : Verlet list (P pairs, i < j, image shift s with branch
    x_j + h s - x_i) and tangential contact force history [N/m] (or None);
    x_ref, h_ref : configuration of the last neighbour build (rebuild criterion);
    step, time : counters;  meta : JSON-serialisable dict of scalars.
    """

    x: np.ndarray
    v: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    h: np.ndarray
    L: np.ndarray
    ids: np.ndarray
    omega: np.ndarray | None = None
    theta: np.ndarray | None = None
    rho: float = 1.0
    nl_i: np.ndarray | None = None
    nl_j: np.ndarray | None = None
    nl_shift: np.ndarray | None = None
    nl_ft: np.ndarray | None = None
    x_ref: np.ndarray | None = None
    h_ref: np.ndarray | None = None
    step: int = 0
    time: float = 0.0
    meta: dict = field(default_factory=dict)

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def from_disks(cls, x, radius, h, *, rho=1.0, spins=False, v=None, omega=None, ids=None):
        """New state of disks at positions x (N, 2) [m] with radii (N,) or scalar [m] in the periodic
        cell h (2, 2) [m]; masses from the areal density ``rho`` [kg/m^2]; ``spins=True`` adds
        angular velocity and rotation arrays (zero unless ``omega`` is given)."""
        x = np.array(x, dtype=np.float64, order="C").reshape(-1, 2)
        n = x.shape[0]
        radius = np.array(np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,)))
        if np.any(~np.isfinite(radius)) or np.any(radius <= 0):
            raise ValueError("radius must be finite and > 0 for every disk")
        if not (np.isfinite(rho) and rho > 0):
            raise ValueError(f"rho (areal density) must be > 0, got {rho}")
        h = np.array(h, dtype=np.float64).reshape(2, 2)
        if np.linalg.det(h) <= 0:
            raise ValueError("cell shape matrix h must have a positive determinant (right-handed cell)")
        mass = disk_mass(radius, rho)
        st = cls(x=x, v=np.zeros((n, 2)) if v is None else np.array(v, dtype=np.float64).reshape(n, 2),
                 radius=radius, mass=mass, inertia=0.5 * mass * radius ** 2, h=h, L=np.zeros((2, 2)),
                 ids=np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64),
                 rho=float(rho))
        if spins or omega is not None:
            st.omega = np.zeros(n) if omega is None else np.array(np.broadcast_to(omega, (n,)), dtype=np.float64)
            st.theta = np.zeros(n)
        return st

    # ---- sizes ---------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def area(self) -> float:
        """Cell area det(h) [m^2]."""
        return float(np.linalg.det(self.h))

    @property
    def has_spins(self) -> bool:
        return self.omega is not None

    @property
    def solid_fraction(self) -> float:
        return float(np.pi * np.sum(self.radius ** 2) / self.area)

    def copy(self) -> "State":
        kw = {}
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, np.ndarray):
                val = val.copy()
            elif isinstance(val, dict):
                val = json.loads(json.dumps(val))
            kw[f.name] = val
        return State(**kw)

    def kinetic_energy(self) -> float:
        """Kinetic energy of the fluctuation velocities (translation + rotation) [J/m]."""
        ke = 0.5 * float(np.sum(self.mass[:, None] * self.v ** 2))
        if self.omega is not None:
            ke += 0.5 * float(np.sum(self.inertia * self.omega ** 2))
        return ke

    # ---- persistence ---------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write an npz checkpoint atomically (:func:`dem.runtime.atomic_write`)."""
        path = os.fspath(path)
        if not path.endswith(".npz"):
            path += ".npz"
        arrays = self.arrays()
        atomic_write(path, lambda fh: np.savez(fh, **arrays))

    def arrays(self) -> dict:
        """The arrays of a checkpoint (what :meth:`save` writes, scalars and meta as JSON in
        ``_scalars``)."""
        arrays = {k: getattr(self, k) for k in _ARRAYS if getattr(self, k) is not None}
        scal = {"rho": self.rho, "step": int(self.step), "time": float(self.time), "meta": self.meta}
        arrays["_scalars"] = np.array(json.dumps(scal))
        return arrays

    @classmethod
    def load(cls, path) -> "State":
        path = os.fspath(path)
        if not path.endswith(".npz") and not os.path.exists(path):
            path += ".npz"
        from ..io import FormatError, check_regular_file

        check_regular_file(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                kw = {k: np.array(z[k]) for k in _ARRAYS if k in z.files}
                scal = json.loads(str(z["_scalars"]))
            return cls(**kw, rho=scal["rho"], step=scal["step"], time=scal["time"],
                       meta=scal["meta"])
        except PermissionError:
            raise
        except (ValueError, KeyError, TypeError, OSError, EOFError, zipfile.BadZipFile,
                zlib.error):
            # numpy's "allow_pickle=False" text, a missing key, a truncated zip: one cause
            raise FormatError(path, None, None, "not a readable dem checkpoint (an npz "
                              "written by State.save, with its '_scalars' record): truncated, "
                              "corrupt or another kind of file") from None
