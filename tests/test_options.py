"""The options bundles (issue 23): ``microhom.options.Options`` and its subclasses
``HierarchyOptions`` (:func:`microhom.hierarchy.relaxation_hierarchy`), ``CertificateOptions``
(:func:`microhom.spectral.certified_bound`) and the disk engine's ``Guard`` and ``Loop``
(``dem.engine.integrate.Simulation``): validated once when made, errors naming the field and its
range, keywords as overrides giving the very same run as the bundle."""
import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from dem.engine.contact_laws import LinearFriction
from dem.engine.integrate import Guard, Loop, Simulation
from microhom import lattices
from microhom.hierarchy import HierarchyOptions, relaxation_hierarchy
from microhom.options import OptionError
from microhom.spectral import CertificateOptions, certified_bound


def _ring(n):
    L = sp.diags([2 * np.ones(n), -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1]).tolil()
    L[0, n - 1] = L[n - 1, 0] = -1
    return L.tocsr()


@pytest.mark.parametrize("cls, name, bad", [
    (HierarchyOptions, "tol", 1.0), (HierarchyOptions, "max_order", 0), (HierarchyOptions, "max_order", "many"),
    (HierarchyOptions, "spectral_bound", -1.0), (HierarchyOptions, "dense_max", -1),
    (HierarchyOptions, "min_contacts", -1), (HierarchyOptions, "reorthogonalize", "maybe"),
    (HierarchyOptions, "preconditioner", "ilu"), (HierarchyOptions, "soft_modes", 51),
    (HierarchyOptions, "max_memory", 0), (HierarchyOptions, "certify_max_order", 0),
    (HierarchyOptions, "factor_steps", 101), (HierarchyOptions, "spectral_guess", float("nan")),
    (HierarchyOptions, "spin_arm", "arm"), (HierarchyOptions, "dual_bound", 1), (HierarchyOptions, "prestress", None),
    (CertificateOptions, "eps", 0.1), (CertificateOptions, "rel_gap", 0.0), (CertificateOptions, "backend", "cholmod"),
    (CertificateOptions, "tol", -1.0), (CertificateOptions, "ncv", 1), (CertificateOptions, "max_tries", 0),
    (CertificateOptions, "max_memory", -5), (CertificateOptions, "psd", "yes"),
    (Guard, "check_every", -1), (Guard, "ke_limit", 0.0), (Guard, "unsafe_dt", 1), (Guard, "failure_path", 3),
    (Loop, "skin", 0.0), (Loop, "sort_every", 2.5), (Loop, "fuse", None), (Loop, "threads", 0),
    (Loop, "threads", True),
])
def test_a_value_outside_its_range_names_the_field(cls, name, bad):
    with pytest.raises(OptionError, match=f"^{name} must be .*, got") as e:
        cls(**{name: bad})
    assert e.value.name == name and isinstance(e.value, ValueError)


@pytest.mark.parametrize("cls", [HierarchyOptions, CertificateOptions, Guard, Loop])
def test_bundles_are_frozen_and_replace_validates(cls):
    o = cls()
    assert cls.__dataclass_params__.frozen
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(o, cls.names()[0], None)
    with pytest.raises(TypeError, match="unknown"):
        o.replace(no_such_field=1)
    assert o.replace() == o and set(o.as_dict()) == set(cls.names())


def test_hierarchy_keywords_are_overrides_of_the_bundle():
    """``relaxation_hierarchy(net, tol=..., ...)``, the bundle, and the bundle with a keyword
    replacing one of its values give the same result, bit for bit."""
    net = lattices.honeycomb(4, 3, kt=0.3, angle=0.2)
    kw = dict(tol=1e-9, preconditioner="block", soft_modes=0)
    a = relaxation_hierarchy(net, **kw)
    b = relaxation_hierarchy(net, HierarchyOptions(**kw))
    c = relaxation_hierarchy(net, HierarchyOptions(tol=0.5, preconditioner="block", soft_modes=0), tol=1e-9)
    for h in (b, c):
        assert np.array_equal(h.C_upper, a.C_upper) and np.array_equal(h.G_orders, a.G_orders)
        assert h.order == a.order and h.tol == 1e-9
    with pytest.raises(TypeError, match="HierarchyOptions or None"):
        relaxation_hierarchy(net, {"tol": 1e-3})
    with pytest.raises(TypeError, match="unknown HierarchyOptions field 'tolerance'"):
        relaxation_hierarchy(net, tolerance=1e-3)


def test_certificate_keywords_are_overrides_of_the_bundle():
    """The ring Laplacian (eigenvalues 2 - 2 cos(2 pi k / n) of H, halved by M = 2 I): the same
    certified bound through keywords and through the bundle, below the closed form."""
    n = 200
    H, M = _ring(n), 2 * sp.identity(n, format="csr")
    a = certified_bound(H, M, psd=True, backend="splu")
    b = certified_bound(H, M, CertificateOptions(psd=True, backend="splu"))
    lam1 = (2 - 2 * np.cos(2 * np.pi / n)) / 2
    assert a.certified and b.certified and a.n_zero == b.n_zero == 1
    assert a.lower <= lam1 and b.lower <= lam1 and b.lower >= 0.99 * lam1
    with pytest.raises(TypeError, match="CertificateOptions or None"):
        certified_bound(H, M, "splu")


def _disks():
    from dem.engine.state import State
    x = np.array([[0.0, 0.0], [0.99, 0.0], [0.0, 1.5], [1.4, 1.6]]) + 0.5
    return State.from_disks(x, np.full(4, 0.5), np.diag([4.0, 4.0]), rho=1.0, spins=True)


def test_simulation_takes_the_bundles_and_refuses_the_flat_keywords(tmp_path):
    law = LinearFriction(kn=1e3, kt=1e3, mu=0.5)
    sim = Simulation(_disks(), law, damping=0.0, guard=Guard(check_every=7, ke_limit=3.0),
                     loop=Loop(skin=0.05, sort_every=4, threads=1))
    assert (sim.check_every, sim.ke_limit, sim.skin, sim.sort_every, sim.fuse) == (7, 3.0, 0.05, 4, False)
    with pytest.raises(TypeError):
        Simulation(_disks(), law, skin=0.05)                  # a clean cut: no flat keyword
    with pytest.raises(TypeError, match="loop must be a dem.engine.integrate.Loop"):
        Simulation(_disks(), law, loop=Guard())
    sim.run(10)
    sim.save(tmp_path / "ck.npz")
    back = Simulation.load(tmp_path / "ck.npz", threads=1, check_every=3)
    assert (back.skin, back.sort_every, back.check_every, back.ke_limit) == (0.05, 4, 3, 3.0)
    with pytest.raises(TypeError, match="unknown setting 'skn'"):
        Simulation.load(tmp_path / "ck.npz", skn=0.1)
