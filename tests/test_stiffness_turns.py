"""The exact solver deflates the turns of two-contact spheres (issue 26; docs/spheres.md, "The exact
solver on spheres").

A frictional sphere with exactly two contacts, at ``c_k = a_k n_k`` from its centre, has one free
motion: ``omega`` along the chord ``c_1 - c_2``, ``u = -omega x c_1``. The solver removes one rotation
unknown per such sphere before the factorisation and counts the turn as a floppy mode. Checked here
on the 300-sphere LAMMPS dump (``tests/data/sph3d_packing300.dump``, 4 two-contact spheres), against
references that do not come from the code under test: the closed-form turn from the raw positions
and radii, the dense SVD of the stiffness-weighted compatibility written here from ``K^1/2``, and the
solver without the deflation (tensor to 1e-10).
"""
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from dem.analysis.analyse import load_network
from dem.analysis.stiffness import (deflate_turns, factorise, have_pardiso, reduce_system, stiffness,
                                    two_contact_turns)
from microhom.kinematics import assemble
from microhom.lattices import fcc

DUMP = Path(__file__).resolve().parents[1] / "tests" / "data" / "sph3d_packing300.dump"


@pytest.fixture(scope="module")
def net():
    return load_network(DUMP, kn=1.0, kt=1.0)[0]


def _closed_form_turn(net, p, arm):
    """(6,) turn of sphere p (translations, rotations) from positions and radii: its contact points
    c_k = a_k n_k (n_k towards the neighbour under the minimum image; a_k = r_p for the radius arm,
    |x_k - x_p| r_p / (r_p + r_k) for the contact arm), omega = c_1 - c_2, u = -omega x c_1."""
    k = np.flatnonzero((net.pairs == p).any(axis=1))
    assert k.size == 2
    cs = []
    for c in k:
        q = net.pairs[c, 1] if net.pairs[c, 0] == p else net.pairs[c, 0]
        d = net.positions[q] - net.positions[p]
        frac = np.linalg.solve(net.cell, d)
        d = net.cell @ (frac - np.round(frac))
        L = np.linalg.norm(d)
        a = net.radii[p] if arm == "radius" else L * net.radii[p] / (net.radii[p] + net.radii[q])
        cs.append(a * d / L)
    w = cs[0] - cs[1]
    return np.r_[-np.cross(w, cs[0]), w]


@pytest.mark.parametrize("arm", ["radius", "contact"])
def test_the_deflated_turns_are_the_closed_form_and_exact_null_vectors(net, arm):
    asm = assemble(net, spin_arm=arm)
    red = reduce_system(asm)
    t = two_contact_turns(asm, red)
    kept = asm.net.pairs.ravel()
    assert t.n == 4 and np.all(np.bincount(kept, minlength=net.n_particles)[t.particle] == 2)
    for p, loc, v in zip(t.particle, t.local, t.vector):
        ref = _closed_form_turn(asm.net, p, arm)
        cos = abs(ref @ v) / np.linalg.norm(ref)
        assert cos == pytest.approx(1.0, abs=1e-12)
        hv = red.H[:, loc] @ ref                       # the assembled Hessian: an exact null vector
        assert np.abs(hv).max() < 1e-14 * np.abs(red.H[:, loc]).max() * np.abs(ref).max()
    # the dropped unknown is a rotation of the sphere, the chord's largest component
    assert np.all(np.isin(t.dropped, t.local[:, 3:]))


@pytest.mark.parametrize("arm", ["radius", "contact"])
def test_counts_and_tensor_with_and_without_deflation_against_a_dense_svd(net, arm):
    asm = assemble(net, spin_arm=arm)
    red = reduce_system(asm)
    n = asm.net.branch / asm.net.lengths[:, None]
    nn = n[:, :, None] * n[:, None, :]
    sK = (np.sqrt(asm.net.kn)[:, None, None] * nn
          + np.sqrt(asm.net.effective_kt)[:, None, None] * (np.eye(3) - nn))
    R = (sp.block_diag(list(sK)) @ asm.Bs)[:, red.idx].toarray() / np.sqrt(red.d)
    sv = np.linalg.svd(R, compute_uv=False)
    assert sv[-5] > 1e-3 and sv[-4] < 1e-12             # the gap: 4 floppy modes
    dense = red.n_zero + int((sv < 1e-9).sum())
    solvers = ["splu"] + (["pardiso"] if have_pardiso() else [])
    for solver in solvers:
        with warnings.catch_warnings():
            warnings.simplefilter("error")               # no recount, no perturbed pivot
            r1 = stiffness(net, spin_arm=arm, solver=solver)
        r0 = stiffness(net, spin_arm=arm, solver=solver, deflate=False)
        assert r1.n_turns == 4 and r0.n_turns == 0
        assert r1.n_floppy == r0.n_floppy == dense == 4
        assert r1.n_unstable == r0.n_unstable == 0
        scale = np.abs(r0.C_mandel).max()
        assert np.abs(r1.C_mandel - r0.C_mandel).max() < 1e-10 * scale
        assert r1.residual < 1e-12


def test_the_relaxed_fields_have_no_turn_component(net):
    """The solution restored on all unknowns solves the undeflated system and is orthogonal to every
    turn in the diag(H) metric (the solution a shifted solve means; without the deflation the
    turns' components are the rounding amplified by 1/eta, measured 3.6e-4 here)."""
    asm = assemble(net, spin_arm="radius")
    red = reduce_system(asm)
    t = two_contact_turns(asm, red)
    r = stiffness(net, spin_arm="radius", solver="splu")
    full = np.concatenate([r.u.reshape(6, -1), r.omega.reshape(6, -1)], axis=1).T
    Q = np.zeros((asm.ndof, 6))
    Q[asm.dof_map[asm.dof_map >= 0]] = full[asm.dof_map >= 0]
    q = Q[red.idx]
    assert np.abs(red.H @ q + red.F).max() < 1e-12 * np.abs(red.F).max()
    for loc, v in zip(t.local, t.vector):
        assert np.abs((red.d[loc] * v) @ q[loc]).max() < 1e-12 * np.abs(q).max()


def test_deflation_removes_the_turns_from_the_factor(net):
    """PARDISO's inertia of H - eta diag(H): without the deflation each turn is a negative pivot
    (eigenvalue -eta), with it the deflated matrix is positive definite."""
    if not have_pardiso():
        pytest.skip("needs MKL PARDISO")
    asm = assemble(net, spin_arm="radius")
    red = reduce_system(asm)
    red_d = deflate_turns(red, two_contact_turns(asm, red))
    f0, f1 = factorise(red, "pardiso", psd=True), factorise(red_d, "pardiso", psd=True)
    assert (f0.inertia().n_neg, f1.inertia().n_neg) == (4, 0)
    assert f1.n_perturbed == 0 and red_d.H.shape[0] == red.H.shape[0] - 4 and red_d.n_turns == 4


def test_no_turns_without_two_contact_spheres_or_under_prestress(net):
    assert stiffness(fcc(2, kt=0.5)).n_turns == 0
    delta = net.radii[net.pairs[:, 0]] + net.radii[net.pairs[:, 1]] - net.lengths
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # the turns' negative curvature under the normal forces
        pre = stiffness(replace(net, fn=net.kn * delta), prestress=True, spin_arm="radius")
    assert pre.n_turns == 0 and pre.n_unstable == 4
    with pytest.raises(ValueError, match="deflate"):
        stiffness(net, deflate="yes")
