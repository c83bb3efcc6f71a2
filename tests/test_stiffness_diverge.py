"""A diverging refinement is caught and re-solved at the opposite shift (``dem.analysis.stiffness.relax``).

Iterated Tikhonov on ``M = H + s diag(d)`` multiplies the error of a pencil mode ``lam`` by
``-s/(lam + s)`` per step: above 1 in modulus for ``lam`` between 0 and ``-2s``. PARDISO factorises
at ``s = -eta`` (``eta = 1e-12``), so a rigid mode at ``1.26e-12`` made the refinement diverge
(factor -3.9 per step) on the corpus row ``pack_study_n1000_s1_8e5129a20b`` at kt = 0: residual 6e19
and K = 1.7e51 before the fix. ``tests/data/diverge_row.npz`` holds that network (1000 disks,
kn = 1, analysed at kt = 0; ``docs/stiffness.md``, "Solve").
"""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import dem.analysis.stiffness as stf
from dem.analysis.stiffness import Reduced, relax, stiffness
from microhom.factor import ETA, available_backends, factor
from microhom.network import ContactNetwork

DATA = Path(__file__).parent / "data" / "diverge_row.npz"


def _diagonal_system(h):
    """``H = diag(h)``, ``d = 1``: the pencil's eigenvalues are ``h`` exactly; a unit load on every
    mode of nonzero ``h`` (the three columns scaled -1, 2, -0.5) and its solution ``x = -F / h``
    (zero on ``h = 0``) in closed form."""
    h = np.asarray(h, dtype=float)
    n = h.size
    F = np.where(h != 0, 1.0, 0.0)[:, None] * np.array([[-1.0, 2.0, -0.5]])
    x = np.divide(-F, h[:, None], out=np.zeros_like(F), where=h[:, None] != 0)
    red = Reduced(H=sp.diags(h).tocsc(), F=F, d=np.ones(n), idx=np.arange(n),
                  n_zero=int((h == 0).sum()), particle=np.arange(n))
    return red, x


def test_a_rigid_mode_beside_the_negative_shift_is_solved_at_the_positive_one():
    """Pencil eigenvalue 1.26 eta with s = -eta: the refinement diverges (factor -1/0.26 per step);
    relax keeps its best iterate, re-solves at +eta and reaches the closed form."""
    red, x = _diagonal_system([1.0, 0.3, 1.26 * ETA, 0.0, 2.0, 5e-3, 3 * ETA])
    f = factor(red.H, backend="splu", shift=-ETA, scale=red.d)
    X, resid, n_ref, path = relax(f, red, 1.0, details=True)
    assert "diverged" in path and "+1e-12" in path and "diverged too" not in path, path
    assert resid <= 1e-13 and n_ref <= 50
    assert np.allclose(X, x, rtol=1e-9, atol=0), np.abs(X / np.where(x != 0, x, 1) - 1).max()
    # the same system at +eta converges without a detour (slowly along 1.26 eta: 0.44 per step)
    X2, resid2, _, path2 = relax(factor(red.H, backend="splu", shift=ETA, scale=red.d), red, 1.0, details=True)
    assert "diverged" not in path2 and resid2 <= 1e-13
    assert np.allclose(X2, x, rtol=1e-9, atol=0)


def test_modes_on_both_sides_keep_the_best_iterate_and_stop():
    """Pencil eigenvalues +-1.26 eta: each shift diverges on one of them; relax stops within
    max_refine solves with the best residual seen (never above the first solve's), which
    :func:`stiffness` would flag "inaccurate" with NaN moduli."""
    red, _ = _diagonal_system([1.0, 1.26 * ETA, -1.26 * ETA, 0.5])
    f = factor(red.H, backend="splu", shift=-ETA, scale=red.d)
    r0 = float((np.linalg.norm(-red.F - red.H @ f.solve(-red.F), axis=0)).max())
    X, resid, n_ref, path = relax(f, red, 1.0, max_refine=30, details=True)
    assert "diverged too" in path, path
    assert np.isfinite(X).all() and resid <= r0 and n_ref <= 30
    assert resid > stf.INACCURATE
    # psd=True (no pre-stress): a growth at s = +eta can only be rounding, so no second factor
    f = factor(red.H, backend="splu", shift=ETA, scale=red.d)
    X, resid, n_ref, path = relax(f, red, 1.0, max_refine=30, details=True, psd=True)
    assert path.endswith("kept the best iterate") and n_ref < 30 and np.isfinite(X).all(), path


def _row():
    z = np.load(DATA)
    assert json.loads(str(z["meta"]))["corpus_key"] == "pack_study_n1000_s1_8e5129a20b"
    c = z["pairs"].shape[0]
    return ContactNetwork(positions=z["positions"], radii=z["radii"], cell=z["cell"],
                          pairs=z["pairs"].astype(np.int64), branch=z["branch"],
                          kn=np.ones(c), kt=np.zeros(c), sliding=np.zeros(c, bool))


def _quiet(net, solver):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return stiffness(net, solver=solver)


@pytest.mark.parametrize("solver", [s for s in ("pardiso", "cholmod") if s in available_backends()])
def test_the_corpus_row_gives_the_superlu_tensor(solver):
    """The row is not jammed at kt = 0 (K, G ~ 1e-12 of the affine moduli): PARDISO (re-solved at
    +eta after its refinement diverged) and CHOLMOD give SuperLU's tensor to 1e-8 of the affine
    scale, with the same flags and no "inaccurate"."""
    net = _row()
    ref, r = _quiet(net, "splu"), _quiet(net, solver)
    kinds = lambda res: [f.split(":")[0] for f in res.flags]    # noqa: E731 - the numbers differ at 1e-11
    assert r.solver == solver and kinds(r) == kinds(ref) == ["not jammed"]
    assert r.residual <= 1e-11 and r.n_refine <= 50
    scale = np.abs(ref.C_affine_mandel).max()
    assert abs(r.K - ref.K) <= 1e-8 * ref.K_affine and abs(r.G - ref.G) <= 1e-8 * ref.G_affine
    assert np.abs(r.C_mandel - ref.C_mandel).max() <= 1e-8 * scale
    if solver == "pardiso":      # the path taken is reported
        assert "diverged" in r.relax_path and "pardiso reshifted to +1e-12" in r.relax_path
        assert "refinement: pardiso at -1e-12: diverged" in r.summary()


@pytest.mark.filterwarnings("ignore:not jammed")
def test_an_unconverged_solve_gives_nan_moduli_not_a_number(monkeypatch):
    """A residual above INACCURATE after every path: flagged, and the relaxed tensor and moduli are
    NaN (the affine ones kept), never a value off by an unknown amount."""
    true_relax = stf.relax

    def stalled(*args, **kw):
        X, _, n, path = true_relax(*args, **kw)
        return X, 1e-3, n, path + ": diverged too (test)"
    monkeypatch.setattr(stf, "relax", stalled)
    with pytest.warns(RuntimeWarning, match="inaccurate"):
        r = stiffness(_row(), solver="splu")
    assert np.isnan(r.K) and np.isnan(r.G) and np.isnan(r.C_mandel).all()
    assert np.isfinite(r.K_affine) and r.K_affine > 0 and r.residual == 1e-3
    assert any(f.startswith("inaccurate") and "diverged too (test)" in f for f in r.flags)
