"""dem: discrete methods for 2D disk packings in a periodic deformable cell.

A numba disk DEM (:mod:`dem.integrate` with the contact laws of :mod:`dem.contact_laws`), the
preparation of dense packings (:mod:`dem.packing`), the exact linear stiffness of a contact network
(:mod:`dem.stiffness`), strain probes (:mod:`dem.probes`), micromechanical measurements
(:mod:`dem.measure`), readers and writers of other codes' files (:mod:`dem.io`), the LAMMPS
cross-checks (:mod:`dem.lammps`, :mod:`dem.lammps_trajectory`) and the free-hexagon mine scene.

Units are those of the inputs, used consistently (SI in the examples): lengths [m], time [s],
contact stiffnesses ``kn``, ``kt`` as force per unit overlap [N/m], 2D stresses and moduli (force per
unit length of the cell boundary) [N/m], masses from an areal density (:mod:`dem.state`). ``dem`` imports
``microhom`` (the contact network, periodic geometry, tensors), never ``studies``. The package
itself exports nothing: import the modules.
"""

__all__: list[str] = []
