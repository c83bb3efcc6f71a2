"""The hierarchy's set-up order and its slim assembly (issue 26) change no number.

``relaxation_hierarchy`` builds the multilevel preconditioner right after the assembly when the CG
is certain to use it (``_amg_certain``), before the particle blocks and the dual bound's statics,
and holds the assembly without its dense per-contact ``B`` and ``K`` (``_slim``; the statics get
them recomputed, ``_full_matrices``). The former flow is still the code's own path where the
preconditioner is not certain: forcing it (``_amg_certain`` False, ``_slim`` the identity) must
give the same orders, bounds and interval bit for bit, in 2D and 3D, with and without the soft-mode
search (which reuses the early preconditioner).
"""
import warnings

import numpy as np
import pytest

import microhom.hierarchy as hi
from microhom.kinematics import assemble
from studies.bench_spheres import fcc_network
from studies.bench_stiffness import diluted_triangular

DUAL = dict(spectral_bound="none", dual_bound=True, soft_modes=0, tol=1e-4)
CASES = {
    "3D dual": (lambda: fcc_network(100, keep=0.65, kt=0.5, seed=2), DUAL),
    "3D dual sliding": (lambda: _sliding(fcc_network(100, keep=0.65, kt=0.5, seed=2)), DUAL),
    "2D dual": (lambda: diluted_triangular(300, z=4.6, kt=0.5, seed=1), DUAL),
    "2D amg soft modes": (lambda: diluted_triangular(300, z=4.6, kt=0.5, seed=1),
                          dict(preconditioner="amg", soft_modes=3, tol=1e-4)),
    "3D max_order": (lambda: fcc_network(100, keep=0.65, kt=0.5, seed=2), dict(max_order=40, tol=1e-4)),
}


def _sliding(net, frac=0.15, seed=3):
    return net.with_stiffness(sliding=np.random.default_rng(seed).random(net.n_contacts) < frac)


FIELDS = ("K_orders", "G_orders", "K_lower_orders", "G_lower_orders", "C_orders", "C_upper", "C_lower",
          "C_first_order", "order", "spectral_bound", "spectral_bound_source", "certified", "converged",
          "n_soft_modes", "reasons")


def _run(net, kw, monkeypatch, old):
    """The hierarchy with the calls of the three set-up stages recorded in order."""
    seq, seen = [], {}
    for name, label in (("amg_preconditioner", "amg"), ("block_preconditioner", "blocks"),
                        ("build_equilibrator", "statics")):
        real = getattr(hi, name)

        def rec(asm, *a, _real=real, _label=label, **k):
            seq.append(_label)
            seen.setdefault(_label, asm)
            return _real(asm, *a, **k)
        monkeypatch.setattr(hi, name, rec)
    monkeypatch.setattr(hi, "SHARE_H", False)     # H read from the multilevel copy: tests/test_shared_h.py
    if old:
        monkeypatch.setattr(hi, "_amg_certain", lambda run, o: False)
        monkeypatch.setattr(hi, "_slim", lambda asm: asm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = hi.relaxation_hierarchy(net, **kw)
    monkeypatch.undo()
    return h, seq, seen


@pytest.mark.parametrize("case", list(CASES))
def test_setup_order_changes_no_number(case, monkeypatch):
    make, kw = CASES[case]
    net = make()
    new, seq_new, seen = _run(net, kw, monkeypatch, old=False)
    old, seq_old, _ = _run(net, kw, monkeypatch, old=True)
    assert seq_new[0] == "amg" and seq_new.count("amg") == 1       # first, and built once
    assert seq_old[0] == "blocks" and seq_old.count("amg") == 1
    assert sorted(seq_new) == sorted(seq_old)
    if kw.get("dual_bound"):
        assert seq_new == ["amg", "blocks", "statics"] and seq_old == ["blocks", "statics", "amg"]
        # the statics read the recomputed per-contact matrices: the assembly's own, bit for bit
        ref = assemble(net, pin=False).matrices
        got = seen["statics"].matrices
        for f in ("B", "K", "D"):
            np.testing.assert_array_equal(getattr(got, f), getattr(ref, f))
        assert seen["amg"].matrices.B is None and seen["amg"].matrices.K is None     # held slim
        assert seen["amg"].ldof is None                                            # read by the exact solver only
    assert new.order >= 2 and new.certified
    for f in FIELDS:
        a, b = getattr(new, f), getattr(old, f)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=f)
        else:
            assert a == b, f


def test_not_certain_keeps_the_former_order(monkeypatch):
    """``preconditioner="auto"`` with the sparse certificate's factorisation possible (3D, 108
    spheres, 648 unknowns: above dense_max = 500, below CERTIFIED_MAX_DOF): the set-up order is the former one."""
    net = fcc_network(100, keep=0.65, kt=0.5, seed=2)
    h, seq, _ = _run(net, dict(tol=1e-4, dense_max=500), monkeypatch, old=False)
    assert seq[0] == "blocks" and "amg" not in seq[:1]
    assert h.spectral_bound_source.startswith("inertia")
