"""Scenes: one module per scene; a scene declares what it needs (spins, history, cell control).

* :mod:`dem.scenes.mine` — the mine scene of the second paper, on the free-hexagon method
  (:mod:`dem.hexagons`), not on the disk engine.
"""

__all__: list[str] = []
