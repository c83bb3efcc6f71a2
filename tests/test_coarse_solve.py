"""The two-level statics' coarse solve without a factorisation (microhom.coarse_solve.amg_solver,
``microhom.dual_bound.COARSE_BACKEND = "amg"``; docs/theory.md section 12, "The coarse solve").

Checked against what it does not use: a dense least-squares solve of the coarse system (numpy's
``lstsq``) for the coarse forces ``K B R y`` (the null components of ``y`` are free), the
assembly's own ``B^T`` for the equilibrium of the statics' correction, the former factor solve for
the correction itself; the fallback to the factor on a matrix CG cannot take."""
import numpy as np
import pytest
import scipy.sparse as sps

import microhom.dual_bound as db
from microhom.coarse_solve import amg_solver, factor_solver
from microhom.kinematics import assemble
from studies.bench_spheres import fcc_network


@pytest.fixture(scope="module")
def case():
    """A 3D network with several clusters and alone spheres, its statics (the "amg" coarse solve),
    the coarse matrix and the coarse loads of random contact forces."""
    net = fcc_network(1000, keep=0.65, kt=0.5, seed=2)
    asm = assemble(net, prestress=False, pin=False)
    keep, db.COARSE_BACKEND = db.COARSE_BACKEND, "amg"
    try:
        eq = db.build_equilibrator(asm, clusters=60)
    finally:
        db.COARSE_BACKEND = keep
    T = eq._data["two"]
    assert T is not None and T["stats"]["n_alone"] > 0
    R = T["R"]
    Hc = (R.T @ (asm.H @ R)).tocsr()
    r = np.asarray(asm.Bs.T @ np.random.default_rng(4).normal(size=(asm.Bs.shape[0], 6)))
    return asm, eq, R, Hc, r


def test_amg_coarse_solve_reaches_round_off(case):
    """``Hc y = z`` to a relative residual of 1e-12 per column, and the coarse forces ``K B R y``
    those of numpy's dense least-squares solution."""
    asm, _, R, Hc, r = case
    z = np.asarray(R.T @ r)
    y = amg_solver(Hc, 6, 3)(z)
    assert np.all(np.linalg.norm(z - Hc @ y, axis=0) <= 1e-12 * np.linalg.norm(z, axis=0))
    ref = np.linalg.lstsq(Hc.toarray(), z, rcond=1e-13)[0]
    f, fref = (np.asarray(asm.Ks @ (asm.Bs @ np.asarray(R @ v))) for v in (y, ref))
    assert np.abs(f - fref).max() <= 1e-9 * np.abs(fref).max()


def test_statics_balanced_and_as_with_the_factor(case):
    """``eq.correct(r)`` balances ``r`` (the assembly's ``B^T``) to 1e-11 with the "amg" coarse
    solve, and is the former factor solve's correction to 1e-8."""
    asm, eq, R, Hc, r = case
    c = eq.correct(r)
    res = np.asarray(asm.Bs.T @ c.reshape(-1, r.shape[1])) - r
    assert np.abs(res).max() <= 1e-11 * np.abs(r).max()
    T = eq._data["two"]
    amg = T["solve"]
    try:
        T["solve"] = factor_solver(Hc, 3, "splu")
        c2 = eq.correct(r)
    finally:
        T["solve"] = amg
    assert np.abs(c - c2).max() <= 1e-8 * np.abs(c2).max()


def test_fallback_to_the_factor():
    """A matrix with negative diagonal blocks (no positive semi-definite coarse matrix): the
    solve falls back to the factor and still solves it; a block size that does not divide the
    unknowns is refused."""
    rng = np.random.default_rng(0)
    d = rng.uniform(1.0, 2.0, 24) * np.where(np.arange(24) % 5 == 0, -1.0, 1.0)
    A = sps.diags(d).tocsr() + sps.diags(0.01 * np.ones(23), 1) + sps.diags(0.01 * np.ones(23), -1)
    z = rng.normal(size=(24, 2))
    y = amg_solver(A.tocsr(), 6, 3, fallback="splu")(z)
    assert np.abs(A @ y - z).max() <= 1e-12 * np.abs(z).max()
    with pytest.raises(ValueError, match="b must divide"):
        amg_solver(A.tocsr(), 5, 3)
