"""Isotropic compression scene: a periodic cell of disks servo-compressed to a target pressure.

What it needs: periodic deformable cell with :class:`dem.cell.PressureServo`, a contact law
(frictionless: no spins and no history; frictional: spins and tangential history), Cundall local
damping. Units consistent; 2D per unit thickness; pressure = -tr(sigma)/2 [N/m], compression
positive.

* :func:`run` — the full protocol of :func:`dem.packing.pack` (random gas, fast compression,
  equilibrium on pressure, unbalanced force and kinetic energy, preparation then test friction).
* :func:`simulation` — the wired :class:`dem.integrate.Simulation` for an existing state, for
  callers that drive the steps themselves (e.g. a CLI with its own checkpoints).
"""
from __future__ import annotations

from ..cell import PressureServo
from ..contact_laws import Frictionless, LinearFriction
from ..integrate import Simulation
from ..packing import PackingProtocol, PackingResult, pack

__all__ = ["NEEDS", "run", "simulation"]

NEEDS = {"periodic_cell": True, "cell_control": "PressureServo", "spins": "if mu > 0",
         "tangential_history": "if mu > 0", "bonds": False, "gravity": False}


def run(protocol: PackingProtocol, **run_options) -> PackingResult:
    """Isotropic compression made by ``protocol`` (a :class:`dem.packing.PackingProtocol`) to its
    target pressure; ``run_options`` as :func:`dem.packing.pack`'s."""
    return pack(protocol, **run_options)


def simulation(state, *, p_target, kn, kt=None, mu=0.0, restitution=None, damping=0.7,
               max_strain_per_step=2e-4, alpha=0.5, dt=None) -> Simulation:
    """A Simulation of ``state`` under the isotropic pressure servo (target ``p_target`` [N/m])."""
    law = (Frictionless(kn=kn, restitution=restitution) if mu == 0 and not kt else
           LinearFriction(kn=kn, kt=kn if kt is None else kt, mu=mu, restitution=restitution))
    sim = Simulation(state, law, damping=damping, dt=dt)
    sim.control = PressureServo(p_target=p_target, max_rate=max_strain_per_step / sim.dt, alpha=alpha)
    return sim
