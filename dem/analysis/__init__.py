"""Analysis of a contact network: what needs no simulator.

The exact incremental stiffness (:mod:`~dem.analysis.stiffness`), micromechanical measurements
(:mod:`~dem.analysis.measure`), peers' conventions (:mod:`~dem.analysis.peers`), the analysis of a
packing file against the theory (:mod:`~dem.analysis.analyse`, its command line in
:mod:`~dem.analysis.analyse_cli`) and pictures of networks (:mod:`~dem.analysis.plot`).

Nothing here imports :mod:`dem.engine` (the simulator), :mod:`dem.hexagons` or :mod:`dem.scenes`:
a packing from any code is analysed without compiling the DEM (tests/test_imports.py holds it).
"""

__all__: list[str] = []
