"""The mine scene of Prochazka's "Influence of dislocations on bumps occurrence in deep mines", on the
free-hexagon method (:mod:`dem.hexagons`).

* :mod:`~dem.scenes.mine.params`: the scene file (``MineParams``, TOML) and the paper's readings;
* :mod:`~dem.scenes.mine.geometry`: the domain, the dislocation lines and the blocks between them;
* :mod:`~dem.scenes.mine.gas`: gas as interface pressure or as the paper's eigenstrain;
* :mod:`~dem.scenes.mine.excavation`: the exact virgin state and the Eshelby-force excavation;
* :mod:`~dem.scenes.mine.build`: the scene assembled (boundaries, overburden spring, absorbing
  dashpots);
* :mod:`~dem.scenes.mine.runner`: ramp + dynamics, series, checkpoints;
* :mod:`~dem.scenes.mine.indicators`: typed indicators (blocks, seam stress profiles);
* :mod:`~dem.scenes.mine.outputs`: pictures and VTK.

    from dem.scenes.mine import MineParams, run_scene
    res = run_scene(MineParams(disl_angle_deg=120, floor="no_slip"))
    res.indicators.block("wedge")

See docs/mine_scene.md. ``python -m dem.scenes.mine --help`` runs one scene from a file.
"""
from .build import Scene, build_scene
from .geometry import Geometry, block_labels, block_names, resolve
from .indicators import (BlockIndicators, FaultIndicators, MineIndicators, SeamProfile, block_indicators,
                         fault_indicators)
from .params import READINGS, MineParams, load_toml
from .runner import RunResult, run_scene

__all__ = ["MineParams", "READINGS", "load_toml", "Scene", "build_scene", "Geometry", "resolve", "block_labels",
           "block_names", "BlockIndicators", "FaultIndicators", "MineIndicators", "SeamProfile", "block_indicators",
           "fault_indicators", "RunResult", "run_scene"]
