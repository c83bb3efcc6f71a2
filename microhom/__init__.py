"""microhom: homogenisation theory of 2D frictional disk packings.

Closed-form and numeric predictions of the incremental (tangent) bulk and shear moduli of a
periodic packing of disks from its contact network, with the sympy derivations they rest on.
Everything is 2D: contact stiffnesses ``kn``, ``kt`` are forces per unit overlap [N/m], stresses
and moduli are 2D (force per unit length of the cell boundary) [N/m], lengths are in m; stress and
stiffness tensors are in Mandel form (shapes ``(3,)`` and ``(3, 3)``, see :mod:`microhom.tensors`).

Modules, in the order a reader meets them:

- :mod:`microhom.network`: the :class:`~microhom.network.ContactNetwork` every other module reads;
- :mod:`microhom.periodic`, :mod:`microhom.lattices`: cell geometry and perfect lattices (the
  exact cases);
- :mod:`microhom.laws`: normal contact laws (force and stiffness from the overlap);
- :mod:`microhom.kinematics`: per-contact kinematics and the assembled Hessian;
- :mod:`microhom.structural_sums`, :mod:`microhom.neighbourhood`: the statistics the theory needs;
- :mod:`microhom.rigidity`: floppy modes, redundant constraints and rigid clusters (pebble game);
- :mod:`microhom.moduli`: the predictions; :mod:`microhom.tensors`: tensor conversions;
- :mod:`microhom.symbolic`, :mod:`microhom.derivations`, :mod:`microhom.printed`: the derivations
  and the seed paper's printed figures they are checked against;
- :mod:`microhom.conventions`: conversions to and from the conventions of peer codes;
- :mod:`microhom.results`: the base every result type mixes in.

``microhom`` never imports ``dem`` or ``studies``. The package itself exports nothing: import the
modules.
"""

__all__: list[str] = []
