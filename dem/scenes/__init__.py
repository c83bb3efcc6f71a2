"""Scenes: one module per scene; a scene declares what it needs (spins, history, cell control).

* :mod:`dem.scenes.isotropic` — isotropic compression of a random disk packing to a target
  pressure in a periodic cell (wires state, cell servo, neighbour lists, contact law, integrator).
* :mod:`dem.scenes.mine` — the mine scene of the second paper, on the free-hexagon method
  (:mod:`dem.hexagons`), not on the disk engine.
"""

__all__: list[str] = []
