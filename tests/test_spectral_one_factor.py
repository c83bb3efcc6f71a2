"""The one-factorisation certificate (``certified_bound(guess=, null_basis=)``) and the lean default
of the hierarchy above ``dense_max`` (issue 22, "within 2x the exact solve").

The truth is scipy's dense generalised eigen-solver on (H, M) (another routine than the
certificate's Sylvester count); the exact moduli come from ``dem.analysis.stiffness``."""
import numpy as np
import pytest
from scipy.linalg import eigh

from dem.analysis.stiffness import stiffness
from microhom import lattices
from microhom.factor import available_backends
from microhom.hierarchy import block_preconditioner, plan_memory, relaxation_hierarchy
from microhom.kinematics import assemble
from microhom.multilevel import near_null_space
from microhom.network import ContactNetwork
from microhom.spectral import GUESS_FACTOR, certified_bound
from test_hierarchy_certify import _weak_band  # noqa: E402  (the same network, one definition)

BACKENDS = [b for b in ("pardiso", "splu") if b in available_backends()]


def _diluted(nx, ny, z, seed=0):
    """Jittered triangular lattice, contacts kept with probability z/6, random stiffnesses."""
    rng = np.random.default_rng(seed)
    base = lattices.triangular(nx, ny, kn=1.0, kt=1.0)
    pos = base.positions + 0.1 * rng.uniform(-1, 1, base.positions.shape)
    i, j = base.pairs.T
    br = pos[j] + base.image_shifts() @ base.cell.T - pos[i]
    keep = rng.random(base.n_contacts) < z / 6
    m = int(keep.sum())
    return ContactNetwork(positions=pos, radii=np.full(base.n_particles, 0.5), cell=base.cell,
                          pairs=base.pairs[keep], branch=br[keep], kn=rng.uniform(0.5, 2.0, m),
                          kt=rng.uniform(0.5, 1.0, m), sliding=False)


def _cut():
    """A polydisperse diluted lattice with the contacts across its middle line removed: floppy
    modes beyond the translations (test_hierarchy_certify's weak band at zero stiffness)."""
    return _weak_band(0.0)


def _pencil(net):
    asm = assemble(net, pin=False)
    M, _, _, n_bad = block_preconditioner(asm)
    assert n_bad == 0
    w = eigh(asm.H.toarray(), M.toarray(), eigvals_only=True)
    zero = np.abs(w) < 1e-10 * np.abs(w).max()
    return asm, M, near_null_space(asm)[:, :2], int(zero.sum()), float(w[~zero].min())


@pytest.fixture(scope="module")
def rigid():
    """A network whose null space is the two global translations (dense check)."""
    asm, M, Z, n_zero, lam1 = _pencil(_diluted(14, 14, z=5.0, seed=3))
    assert n_zero == 2
    return asm, M, Z, lam1


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("over", [1.0, 1.9])
def test_one_factorisation_bound_is_below_the_dense_eigenvalue(rigid, backend, over):
    """A guess up to twice the eigenvalue: one numeric factorisation, the bound half the guess
    (less the round-off margin), below the dense eigenvalue."""
    asm, M, Z, lam1 = rigid
    b = certified_bound(asm.H, M, psd=True, backend=backend, guess=over * lam1, null_basis=Z)
    assert b.certified and b.n_factorisations == 1
    assert b.n_zero == 2 and b.n_negative == 0 and b.n_below_shift == 2
    assert b.shift == pytest.approx(GUESS_FACTOR * over * lam1)
    assert b.lower <= lam1 and b.lower >= 0.45 * over * lam1


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_too_high_guess_is_caught_and_lowered(rigid, backend):
    """A guess 10 times the eigenvalue: the count at 5 lam1 exceeds the null space, the
    certificate counts again at eps, estimates and lowers the shift: the bound is still below
    the dense eigenvalue, and tight (the usual path's 1e-3 below)."""
    asm, M, Z, lam1 = rigid
    b = certified_bound(asm.H, M, psd=True, backend=backend, guess=10 * lam1, null_basis=Z)
    assert b.certified and b.n_factorisations >= 3
    assert b.lower <= lam1 <= b.lower * (1 + 3e-3)
    assert b.n_zero == 2


def test_a_basis_that_is_not_null_proves_nothing(rigid):
    """Two vectors that are not null vectors: their Ritz values are far above eps, the count at
    the guessed shift is not taken as certified without the count at eps."""
    asm, M, Z, lam1 = rigid
    fake = np.random.default_rng(0).standard_normal(Z.shape)
    b = certified_bound(asm.H, M, psd=True, guess=lam1, null_basis=fake)
    assert b.certified and b.n_factorisations == 2      # s1 confirmed by the count at eps
    assert b.lower <= lam1 and b.n_zero == 2


def test_floppy_modes_need_the_count_at_eps():
    """A network with floppy modes (null space larger than the translations): the count at the
    guessed shift exceeds the translations, the count at eps confirms it (two factorisations,
    three when the factor at s1 is kept), and the bound is below the dense eigenvalue."""
    asm, M, Z, n_zero, lam1 = _pencil(_cut())
    assert n_zero > 2
    b = certified_bound(asm.H, M, psd=True, guess=lam1, null_basis=Z)
    assert b.certified and b.n_factorisations == 2 and b.n_zero == n_zero
    assert b.lower <= lam1
    b, fac = certified_bound(asm.H, M, psd=True, guess=lam1, null_basis=Z, keep_factor=True)
    assert b.n_factorisations == 3 and fac is not None
    x = fac.solve(M @ np.ones(M.shape[0]))         # the kept factor is that of H - s1 M
    r = (asm.H - b.shift * M) @ x - M @ np.ones(M.shape[0])
    assert np.abs(r).max() <= 1e-6 * np.abs(M @ np.ones(M.shape[0])).max()
    fac.release()


def test_bad_guess_argument(rigid):
    asm, M, Z, lam1 = rigid
    for g in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match="guess"):
            certified_bound(asm.H, M, psd=True, guess=g)
    net = _diluted(6, 6, z=5.0)
    for g in (0.0, -1e-3, float("nan"), "x"):
        with pytest.raises(ValueError, match="spectral_guess"):
            relaxation_hierarchy(net, spectral_guess=g)
    with pytest.raises(ValueError, match="max_order"):
        relaxation_hierarchy(net, max_order="fast")
    with pytest.raises(ValueError, match="preconditioner"):
        relaxation_hierarchy(net, preconditioner="lean")


def test_lean_default_above_dense_max_and_the_former_default():
    """Above dense_max the default is the lean path (one block-Jacobi step, then the factorised
    ones): certified, the exact moduli inside; max_order=16 still runs the multilevel CG; below
    dense_max nothing changed (multilevel). The guess path gives the same kind of interval."""
    net = _diluted(30, 30, z=4.6, seed=2)
    ex = stiffness(net)
    h = relaxation_hierarchy(net, dense_max=100)
    assert h.preconditioner == "block" and h.n_factor_steps >= 1 and h.order <= 5
    assert h.certified and h.valid and h.certificate_factorisations >= 2
    for e, x in ((h.K, ex.K), (h.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12) and e.rel_width <= 0.01
    old = relaxation_hierarchy(net, dense_max=100, max_order=16)
    assert old.preconditioner == "amg" and old.certified
    small = relaxation_hierarchy(net, dense_max=5000)    # ndof <= dense_max: the dense bound
    assert small.preconditioner == "amg" and small.certificate_factorisations == 0
    g = relaxation_hierarchy(net, dense_max=100, spectral_guess=h.spectral_bound)
    assert g.certified and g.spectral_bound <= h.spectral_bound
    for e, x in ((g.K, ex.K), (g.G, ex.G)):
        assert e.lower <= x * (1 + 1e-12) and x <= e.upper * (1 + 1e-12)


def test_plan_memory_counts_the_kept_factor():
    """The certificate's factor (about 0.47 GB at 1e5 disks with PARDISO) is in the plan."""
    p0 = plan_memory(100_000, 205_000)
    p1 = plan_memory(100_000, 205_000, factor=True)
    assert p0.factor == 0 and p1.factor > 2e8
    assert p1.total == p0.total + p1.factor


def test_plan_memory_gives_superlu_its_3d_fill_for_spheres():
    """Below PARDISO's threshold (SuperLU takes the certificate) the 3D plan counts SuperLU's
    measured 3D fill (``5 n^1.6`` non-zeros: 4.6e7 at 23 944 unknowns, docs/spheres.md), not
    the 2D ``n log n`` law, which is 8-55 times lower on spheres."""
    from microhom.factor import AUTO_PARDISO_DOF_PENCIL
    N = (AUTO_PARDISO_DOF_PENCIL - 1) // 6                # 6 unknowns per sphere: SuperLU's range
    p2 = plan_memory(N, 3 * N, dim=2, factor=True)
    p3 = plan_memory(N, 3 * N, dim=3, factor=True)
    n3 = 6 * N
    assert p3.factor >= 5.0 * n3 ** 1.6 * 22            # the law at the measured 22-24 bytes per non-zero
    assert p3.factor > 3 * p2.factor                     # not the 2D figure


def test_lean_default_is_not_taken_when_the_factor_does_not_fit():
    """A memory limit that holds the hierarchy but not the certificate's factor: no sparse
    certificate (stated), the multilevel CG as before."""
    net = _diluted(30, 30, z=4.6, seed=2)
    p0 = plan_memory(net.n_particles, net.n_contacts, dense=False)   # as _memory_guard plans it
    h = relaxation_hierarchy(net, dense_max=100, max_memory=p0.total + 1000)
    assert any("does not fit" in r for r in h.reasons)
    assert h.spectral_bound is None and h.preconditioner == "amg" and h.certificate_factorisations == 0
