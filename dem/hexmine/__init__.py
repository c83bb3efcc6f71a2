"""Free-hexagon mine scene (Prochazka's method, reconstructed): elastic hexagons with 12x12 boundary
stiffness, penalty interfaces with generalised Mohr-Coulomb, Eshelby-force excavation, explicit
central-difference dynamics. SI units, tension positive, plane strain, per m of thickness.

See docs/mine_scene.md. Main entry points::

    from dem.hexmine import MineParams, build_scene, run_scene
    res = run_scene(MineParams(disl_angle_deg=120, ramp_time=0.01))
    res.indicators
"""
from .element import element_stiffness, periodic_moduli, isotropic_from_C, hex_geometry
from .interface import InterfaceLaw, mc_update, spring_stiffness_rule
from .lattice import make_lattice
from .dynamics import (Model, step, advance, model_forces, gershgorin_dt, power_dt, energies,
                       cell_stress, assemble_stiffness)
from .scene import MineParams, Scene, build_scene, load_toml
from .runner import RunResult, run_scene, indicators, seam_profile

__all__ = ["element_stiffness", "periodic_moduli", "isotropic_from_C", "hex_geometry", "InterfaceLaw",
           "mc_update", "spring_stiffness_rule", "make_lattice", "Model", "step", "advance",
           "model_forces", "gershgorin_dt", "power_dt", "energies", "cell_stress", "assemble_stiffness",
           "MineParams", "Scene", "build_scene", "load_toml", "RunResult", "run_scene", "indicators",
           "seam_profile"]
