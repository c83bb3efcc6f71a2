"""dem: discrete methods for 2D disk packings in a periodic deformable cell.

A numba disk DEM (:mod:`dem.engine.integrate` with the contact laws of :mod:`dem.engine.contact_laws`), the
preparation of dense packings (:mod:`dem.engine.packing`), the exact linear stiffness of a contact network
(:mod:`dem.analysis.stiffness`), strain probes (:mod:`dem.engine.probes`), micromechanical measurements
(:mod:`dem.analysis.measure`), readers and writers of other codes' files (:mod:`dem.io`), the LAMMPS
cross-checks (:mod:`dem.engine.lammps`, :mod:`dem.engine.lammps_trajectory`) and the free-hexagon mine scene.

Units are those of the inputs, used consistently (SI in the examples): lengths [m], time [s],
contact stiffnesses ``kn``, ``kt`` as force per unit overlap [N/m], 2D stresses and moduli (force per
unit length of the cell boundary) [N/m], masses from an areal density (:mod:`dem.engine.state`). ``dem`` imports
``microhom`` (the contact network, periodic geometry, tensors), never ``studies``. The package
itself exports nothing: import the modules.
"""

__all__: list[str] = []
