"""The disk simulator: what runs time steps.

Particle state (:mod:`~dem.engine.state`), the periodic deformable cell (:mod:`~dem.engine.cell`),
neighbour lists (:mod:`~dem.engine.neighbors`), contact laws composed of sub-models
(:mod:`~dem.engine.contact_laws`, their pair loops in :mod:`~dem.engine.contact_models`), the
integrator (:mod:`~dem.engine.integrate`), FIRE minimisation (:mod:`~dem.engine.fire`), packing
protocols (:mod:`~dem.engine.packing`), strain probes (:mod:`~dem.engine.probes`) and LAMMPS as a
peer simulator (:mod:`~dem.engine.lammps`, :mod:`~dem.engine.lammps_trajectory`).

The engine may use :mod:`dem.analysis` (a packing reports its stress and fabric) and :mod:`dem.io`;
it never imports :mod:`dem.hexagons` or :mod:`dem.scenes`.
"""

__all__: list[str] = []
