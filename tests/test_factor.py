"""microhom.factor: inertia, solves and the memory guard of the sparse back ends, against dense
numpy eigenvalues and closed forms (never the back end's own output)."""
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

from microhom import factor as fm
from microhom.factor import (FactorisationError, MemoryGuardError, available_backends, factor, inertia,
                             memory_check, predicted_factor_bytes)

BACKENDS = [b for b in ("pardiso", "splu") if b in available_backends()]


def _sym(n, density, seed, shift=0.0):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, random_state=rng)
    A = (A + A.T).tocsr() + sp.diags(rng.uniform(-1, 1, n) + shift)
    return A.tocsr()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("shift", [-1.0, 0.0, 4.0])
def test_inertia_matches_dense_eigenvalues(backend, shift):
    A = _sym(120, 0.05, 3, shift)
    w = np.linalg.eigvalsh(A.toarray())
    try:
        ine = inertia(A, backend=backend)
    except FactorisationError:     # SuperLU may leave the diagonal on an indefinite matrix
        assert backend == "splu"
        return
    assert (ine.n_pos, ine.n_neg, ine.n_zero) == (int((w > 0).sum()), int((w < 0).sum()), 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_ring_laplacian_inertia_closed_form(backend):
    """L - s I for the ring Laplacian (eigenvalues 2 - 2 cos(2 pi k / n)): the number below s
    is the closed-form count, on both sides of a cluster."""
    n = 64
    L = sp.diags([2 * np.ones(n), -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1]).tolil()
    L[0, n - 1] = L[n - 1, 0] = -1
    L = L.tocsr()
    lam = 2 - 2 * np.cos(2 * np.pi * np.arange(n) / n)
    for s in (1e-9, 0.3, 1.7, 3.5):
        ine = inertia((L - s * sp.identity(n)).tocsr(), backend=backend)
        assert ine.n_neg == int((lam < s).sum()), s


@pytest.mark.parametrize("backend", BACKENDS)
def test_solve_multiple_right_hand_sides(backend):
    A = _sym(200, 0.03, 5, 8.0)
    b = np.random.default_rng(0).standard_normal((200, 3))
    f = factor(A, backend=backend)
    x = f.solve(b)
    assert np.abs(A @ x - b).max() <= 1e-10 * np.abs(b).max()
    f.release()


@pytest.mark.skipif("pardiso" not in available_backends(), reason="mkl wheel not installed")
def test_pardiso_refactor_reuses_the_analysis():
    A = _sym(150, 0.04, 7, 0.5)
    U = sp.triu(A, format="csr")
    U.sort_indices()
    f = fm._Pardiso(U, upper=True)
    for s in (-0.3, 1.1):
        B = (A - s * sp.identity(150)).tocsr()
        Us = sp.triu(B, format="csr")
        Us.sort_indices()
        assert np.array_equal(Us.indices, U.indices)
        f.refactor(Us.data)
        w = np.linalg.eigvalsh(B.toarray())
        assert f.inertia().n_neg == int((w < 0).sum())
        b = np.ones(150)
        assert np.abs(B @ f.solve(b) - b).max() < 1e-9
    f.release()
    with pytest.raises(RuntimeError, match="released"):
        f.solve(np.ones(150))


def test_memory_guard_refuses_with_the_figure(monkeypatch):
    with pytest.raises(MemoryGuardError, match=r"predicted 1e\+03 GB.*available"):
        memory_check(1e12, "test", limit=1e9)
    assert memory_check(1e6, "test", limit=1e9) == 1e6
    monkeypatch.setenv("MICROHOM_MEMORY_LIMIT", "0.001")
    with pytest.raises(MemoryGuardError, match="MICROHOM_MEMORY_LIMIT"):
        memory_check(1e7, "test")
    monkeypatch.setenv("MICROHOM_MEMORY_LIMIT", "1e-6")       # 1 kB
    for b in BACKENDS:
        with pytest.raises(MemoryGuardError, match="predicted"):
            factor(_sym(50, 0.1, 1, 5.0), backend=b)


def test_predicted_factor_size_bounds_pardiso_own_count():
    """The fitted prediction (used before assembly) against PARDISO's symbolic count of the
    factor's non-zeros on a 2D contact Hessian: above it, within a factor 3."""
    if "pardiso" not in available_backends():
        pytest.skip("mkl wheel not installed")
    from microhom.kinematics import assemble
    from microhom import lattices
    rng = np.random.default_rng(0)
    net = lattices.triangular(60, 60, kn=1.0, kt=1.0)
    keep = rng.random(net.n_contacts) < 0.75
    net = net.select_contacts(keep)
    H = assemble(net).H
    n = H.shape[0]
    f = factor((H + sp.identity(n) * 1e-9).tocsr(), backend="pardiso")
    pred_nnz = fm._NNZ_COEF * n * np.log2(n)
    assert f.nnz <= pred_nnz <= 3 * f.nnz, (f.nnz, pred_nnz)
    assert predicted_factor_bytes(n, "pardiso") >= f.predicted_bytes
    f.release()


@pytest.mark.parametrize("m", [4, 6])
def test_superlu_3d_guard_predicts_the_measured_fill(m):
    """SuperLU's symmetric factor of a 3D sphere Hessian (the built FCC network of
    studies.bench_spheres, 4 m^3 spheres; sizes 1533 and 5178 unknowns, not among the calibration
    points of _NNZ_COEF_3D): the 3D prediction within a factor 2 of the measured L.nnz + U.nnz,
    the 2D n log n formula below half of it (it predicted 0.29 GB for a 4.3 GiB solve)."""
    from studies.bench_splu_fill import fill_row
    _, n, nnz, _, _ = fill_row(m)
    pred3, pred2 = fm.predicted_factor_nnz(n, 3), fm.predicted_factor_nnz(n, 2)
    assert 0.5 * nnz <= pred3 <= 2.0 * nnz, (n, nnz, pred3)
    assert pred2 < 0.5 * nnz, (n, nnz, pred2)       # the former (2D) guard fails this test
    assert predicted_factor_bytes(n, "splu", 3) == pred3 * fm._BYTES_PER_NNZ_LU3D + fm._FIXED_BYTES


def test_superlu_guard_takes_the_dimension(monkeypatch):
    """factor(dim=3) guards SuperLU with the 3D fill (refused with the figure where the 2D one
    would pass); 2D figures bit-identical to the former formula; PARDISO and CHOLMOD unchanged by
    dim; a bad dim named."""
    for n in (10, 3000, 123_457):
        for b in ("pardiso", "cholmod", "splu"):
            old = fm._NNZ_COEF * n * np.log2(n) * fm._BYTES_PER_NNZ[b] + fm._FIXED_BYTES
            assert predicted_factor_bytes(n, b) == old and predicted_factor_bytes(n, b, 2) == old
            if b != "splu":
                assert predicted_factor_bytes(n, b, 3) == old
        assert fm.predicted_general_bytes(n, "splu", 3) == predicted_factor_bytes(n, "splu", 3)
    A = sp.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(3000, 3000)).tocsr()
    limit = 0.5 * (predicted_factor_bytes(3000, "splu", 2) + predicted_factor_bytes(3000, "splu", 3))
    assert factor(A, backend="splu", max_memory=limit).dim == 2
    with pytest.raises(MemoryGuardError, match=r"3000 unknowns \(3D\): predicted"):
        factor(A, backend="splu", max_memory=limit, dim=3)
    f = factor(A, backend="splu", dim=3, shift=1e-3, scale=np.ones(3000))
    assert f.dim == 3 and f.reshift(1e-5).dim == 3
    with pytest.raises(ValueError, match="dim must be 2"):
        factor(A, backend="splu", dim=4)
    with pytest.raises(ValueError, match="dim must be 2"):
        predicted_factor_bytes(100, "splu", 1)


def test_bad_input_names_the_parameter():
    with pytest.raises(ValueError, match="backend"):
        factor(sp.identity(3).tocsr(), backend="umfpack")
    with pytest.raises(ValueError, match="square"):
        factor(sp.csr_matrix(np.ones((2, 3))))


# ---- the diagonal shift, reshift and the zero-mode count (what dem.analysis.stiffness uses) -----
ALL = [b for b in ("pardiso", "cholmod", "splu") if b in available_backends()]


def _ring(n):
    L = sp.diags([2 * np.ones(n), -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1]).tolil()
    L[0, n - 1] = L[n - 1, 0] = -1
    return L.tocsr()


def _rings(k, n):
    """k disjoint ring Laplacians of n nodes: the pencil (A, diag A) has eigenvalues
    1 - cos(2 pi j / n), each k times: exactly k zero modes, the next at 1 - cos(2 pi / n)."""
    return sp.block_diag([_ring(n)] * k, format="csr")


@pytest.mark.parametrize("backend", ALL)
def test_shifted_factor_solves_the_shifted_matrix(backend):
    """factor(A, shift=s, scale=d) solves (A + s diag d) x = b, and reshift(s2) solves with s2,
    against the explicitly shifted matrix (dense check)."""
    A = _sym(150, 0.04, 11, 6.0)
    d = np.random.default_rng(2).uniform(0.5, 2.0, 150)
    perm = np.random.default_rng(3).permutation(150) if backend == "cholmod" else None
    b = np.random.default_rng(4).standard_normal((150, 3))
    shift = -0.5 if backend == "pardiso" else 0.5
    f = factor(A, backend=backend, shift=shift, scale=d, perm=perm)
    for s in (shift, 2.0):
        if s != shift:
            g = f.reshift(s)
            assert g is not None and (g is f) == (backend == "pardiso")
            f = g
        As = (A + sp.diags(s * d)).toarray()
        x = f.solve(b)
        assert np.abs(As @ x - b).max() <= 1e-9 * np.abs(b).max(), s
        assert f.shift == s and f.A is A
    f.release()


@pytest.mark.parametrize("backend", ALL)
@pytest.mark.parametrize("count", ["pivots", "rescale", "auto"])
def test_count_zero_modes_of_disjoint_rings(backend, count):
    """k disjoint rings: exactly k zero eigenvalues of the pencil (A, diag A) (closed form), none
    negative, with every back end and rule; the shift is -eta for PARDISO's inertia count."""
    k, n = 3, 40
    A = _rings(k, n)
    d = A.diagonal()
    eta = fm.ETA
    f = factor(A, backend=backend, shift=-eta if backend == "pardiso" else eta, scale=d,
               perm=np.arange(k * n) if backend == "cholmod" else None)
    z = fm.count_zero_modes(f, count, psd=True)
    assert (z.n_zero, z.n_negative) == (k, 0), z
    assert z.method == ("inertia" if backend == "pardiso" else
                        (count if count != "auto" else "pivots"))
    if backend != "pardiso":     # the pivot gap: zero pivots about eta, rigid ones 1 - cos(2 pi / n)
        assert z.gap[0] < 1e-10 and z.gap[1] > 1e-4
    assert z.factor is None or (backend == "cholmod" and count == "rescale")
    g = z.factor or f
    x = g.solve(np.ones(k * n))
    assert np.all(np.isfinite(x))
    g.release()


@pytest.mark.parametrize("backend", [b for b in ("pardiso", "splu") if b in available_backends()])
def test_count_zero_and_negative_modes_of_an_indefinite_pencil(backend):
    """A ring (one zero mode) beside a ring shifted by -0.3 diag (negative modes where
    1 - cos(2 pi j / n) < 0.3): the counts against the closed form, psd=False."""
    n = 40
    lam = 1 - np.cos(2 * np.pi * np.arange(n) / n)
    R = _ring(n)
    A = sp.block_diag([R, R - 0.6 * sp.identity(n)], format="csr")      # diag of R = 2
    d = np.full(2 * n, 2.0)
    eta = fm.ETA
    if backend == "pardiso":     # +eta first (negative modes), then -eta on the same analysis
        f = factor(A, backend="pardiso", shift=eta, scale=d).reshift(-eta)
        assert set(f.inertias) == {eta, -eta}
    else:
        f = factor(A, backend="splu", shift=eta, scale=d)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # SuperLU may leave the diagonal: "eig"
        z = fm.count_zero_modes(f, "pivots", psd=False)
    assert (z.n_zero, z.n_negative) == (1, int((lam < 0.3).sum())), z
    f.release()


@pytest.mark.skipif("pardiso" not in available_backends(), reason="mkl wheel not installed")
def test_perturbed_pardiso_count_falls_back_to_superlu():
    """A shift far below PARDISO's pivot perturbation (1e-13): the zero pivots are perturbed, so
    the inertia is another matrix's; the count warns and is SuperLU's, which solves."""
    k, n = 2, 30
    A = _rings(k, n)
    f = factor(A, backend="pardiso", shift=-1e-15, scale=A.diagonal())
    assert f.n_perturbed > 0
    with pytest.warns(RuntimeWarning, match="perturbed .* counted with SuperLU"):
        z = fm.count_zero_modes(f, "pivots", psd=True)
    assert (z.n_zero, z.n_negative, z.method, z.factor.name) == (k, 0, "pivots", "splu")
    f.release()


def test_shift_and_count_bad_input_names_the_parameter():
    A = _ring(10)
    with pytest.raises(ValueError, match="scale"):
        factor(A, backend="splu", shift=1e-12, scale=np.ones(9))
    with pytest.raises(ValueError, match="scale"):
        factor(A, backend="splu", shift=1e-12, scale=-np.ones(10))
    with pytest.raises(ValueError, match="shift"):
        factor(A, backend="splu", shift=np.nan, scale=np.ones(10))
    plain = factor((A + sp.identity(10)).tocsr(), backend="splu")
    with pytest.raises(ValueError, match="diagonal shift"):
        fm.count_zero_modes(plain)
    with pytest.raises(ValueError, match="diagonal shift"):
        plain.reshift(1.0)
    f = factor(A, backend="splu", shift=1e-12, scale=A.diagonal())
    with pytest.raises(ValueError, match="count"):
        fm.count_zero_modes(f, "threshold")


def test_shifted_factor_keeps_the_memory_guard(monkeypatch):
    """Every back end refuses a shifted factorisation predicted above the limit, before it
    allocates (the stiffness's factors go through this guard)."""
    A = _ring(50)
    monkeypatch.setenv("MICROHOM_MEMORY_LIMIT", "1e-6")       # 1 kB
    for b in ALL:
        with pytest.raises(MemoryGuardError, match="predicted"):
            factor(A, backend=b, shift=-1e-12 if b == "pardiso" else 1e-12, scale=A.diagonal(),
                   perm=np.arange(50) if b == "cholmod" else None)


# ---- the rigidity check: the zero modes of R, not of R^T R ----------------------------------
def _incidence(edges, w, n):
    """Rows sqrt(w_e) (e_a - e_b) per edge (a, b): a network of scalar springs, A = R^T R its
    Laplacian (nullity = number of connected components)."""
    r = np.repeat(np.arange(len(edges)), 2)
    v = (np.sqrt(np.asarray(w, float))[:, None] * np.array([1.0, -1.0])).ravel()
    return sp.csr_matrix((v, (r, np.asarray(edges).ravel())), shape=(len(edges), n))


def _weakly_joined_rings(n, weight):
    """Two rings of n unit springs joined by one spring of stiffness ``weight``."""
    edges = [(i, (i + 1) % n) for i in range(n)] + [(n + i, n + (i + 1) % n) for i in range(n)]
    return _incidence(edges + [(0, n)], [1.0] * (2 * n) + [weight], 2 * n)


@pytest.mark.parametrize("backend", ALL)
@pytest.mark.parametrize("n", [120, 300])       # 240 unknowns: dense SVD; 600: subspace iteration
def test_rigidity_check_counts_a_soft_rigid_mode_as_rigid(backend, n):
    """Two rings joined by a spring of stiffness 1e-12: connected, so exactly one zero mode (the
    translation; rank-nullity of the Laplacian). The other mode (the rings against each other)
    has the pencil eigenvalue eps^2 / n = 1e-12 / n (first order, trial vector +1 / -1), below
    eta: every rule on A counts 2 (the floppy count's over-count on the identical-disk corpus
    rows); its singular value in R is 1e-6 / sqrt(n), and the check counts 1."""
    eps = 1e-6
    R = _weakly_joined_rings(n, eps ** 2)
    A = (R.T @ R).tocsr()
    d = A.diagonal()
    def fac():      # a new factor per count: CHOLMOD's rescaling count refactors in place
        return factor(A, backend=backend, shift=-fm.ETA if backend == "pardiso" else fm.ETA, scale=d)
    assert fm.count_zero_modes(fac(), "auto", psd=True).n_zero == 2          # the pencil alone
    f = fac()
    z = fm.count_zero_modes(f, "auto", psd=True, rigidity=R)
    assert (z.n_zero, z.n_pencil, z.n_negative) == (1, 2, 0), z
    assert z.sv_gap[0] < 1e-11
    assert z.sv_gap[1] == pytest.approx(eps / np.sqrt(n), rel=1e-3)
    (z.factor or f).release()


@pytest.mark.parametrize("backend", ALL)
def test_rigidity_check_keeps_exact_zero_modes(backend):
    """Three disjoint rings of 200 (the closed form of test_count_zero_modes_of_disjoint_rings):
    the check keeps the 3 zero modes; with the rings joined by springs of 1e-30 (singular value
    1e-15 / sqrt(n), below RIGID_SV) they stay floppy."""
    k, n = 3, 200
    edges = [(j * n + i, j * n + (i + 1) % n) for j in range(k) for i in range(n)]
    for extra, w, expected in (([], [], 3), ([(0, n), (n, 2 * n)], [1e-30, 1e-30], 3)):
        R = _incidence(edges + extra, [1.0] * (k * n) + w, k * n)
        A = (R.T @ R).tocsr()
        f = factor(A, backend=backend, shift=-fm.ETA if backend == "pardiso" else fm.ETA,
                   scale=A.diagonal())
        z = fm.count_zero_modes(f, "rescale", psd=True, rigidity=R)
        assert (z.n_zero, z.n_pencil) == (expected, 3), z
        (z.factor or f).release()


@pytest.mark.skipif("cholmod" not in available_backends(), reason="scikit-sparse not installed")
def test_rescale_counts_a_zero_pivot_far_above_eta():
    """A wheel: a hub joined by unit springs to 10 rim nodes that a ring of 1e9 springs joins.
    One zero mode (connected). With the hub eliminated last its zero pivot is
    eta * sum(d) / d_hub = 2e-3 relative (the delocalised zero modes of the corpus packings had
    up to 1.3e-2): it scales with the shift, and the rescaling rule counts it (it used to ask
    for a pivot below 1e-4 as well, and missed it)."""
    m = 10
    edges = [(0, 1 + i) for i in range(m)] + [(1 + i, 1 + (i + 1) % m) for i in range(m)]
    R = _incidence(edges, np.r_[np.ones(m), np.full(m, 1e9)], m + 1)
    A = (R.T @ R).tocsr()
    f = factor(A, backend="cholmod", shift=fm.ETA, scale=A.diagonal(), perm=np.arange(m + 1)[::-1])
    z = fm.count_zero_modes(f, "rescale", psd=True)
    assert z.n_zero == 1 and z.gap[0] > 1e-4, z


def test_rigidity_check_bad_input_names_the_parameter():
    R = _weakly_joined_rings(20, 1.0)
    A = (R.T @ R).tocsr()
    f = factor(A, backend="splu", shift=fm.ETA, scale=A.diagonal())
    with pytest.raises(ValueError, match="rigidity= needs psd=True"):
        fm.count_zero_modes(f, psd=False, rigidity=R)
    with pytest.raises(ValueError, match=r"rigidity must have shape \(rows, 40\)"):
        fm.count_zero_modes(f, psd=True, rigidity=R[:, :39])
    with pytest.raises(ValueError, match="R\\^T R differs from A"):
        fm.count_zero_modes(f, psd=True, rigidity=2 * R)
