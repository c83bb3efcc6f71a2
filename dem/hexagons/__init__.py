"""The free-hexagon method (Prochazka's discrete method, reconstructed): a second discrete method
next to the disk engine, with its own state, integrator, contact detection and time-step bound.

* :mod:`~dem.hexagons.element`: the hexagon element, 6 edge-midpoint nodes, 12x12 stiffness (the
  paper's BEM version and the consistent "hybrid" one), periodic homogenisation;
* :mod:`~dem.hexagons.interface`: the interface law (penalty springs, generalised Mohr-Coulomb with
  tension cut-off, gas as effective stress);
* :mod:`~dem.hexagons.lattice`: the regular hexagon lattice clipped to a rectangle;
* :mod:`~dem.hexagons.dynamics`: the model state, explicit central differences (numba), new-neighbour
  contact, energy accounts and the Gershgorin time-step bound;
* :mod:`~dem.hexagons.fault`: a straight fault whose Mohr-Coulomb law acts on the true plane (segments
  of the zigzag of crossed edges) and its one-plane benchmark;
* :mod:`~dem.hexagons.kirsch`: the static check against Kirsch's hole solution.

SI units, tension positive, plane strain, per m of thickness. The mine scene that uses it is
:mod:`dem.scenes.mine`. The disk engine does not import this package; both use ``dem.runtime``.
"""
from .dynamics import (Model, advance, assemble_stiffness, cell_stress, energies, gershgorin_dt, model_forces,
                       power_dt, step)
from .element import element_stiffness, hex_geometry, isotropic_from_C, periodic_moduli
from .interface import InterfaceLaw, Strength, Traction, mc_update, spring_stiffness_rule
from .lattice import make_lattice

__all__ = ["element_stiffness", "periodic_moduli", "isotropic_from_C", "hex_geometry", "InterfaceLaw",
           "Strength", "Traction", "mc_update", "spring_stiffness_rule", "make_lattice", "Model", "step", "advance", "model_forces",
           "gershgorin_dt", "power_dt", "energies", "cell_stress", "assemble_stiffness"]
