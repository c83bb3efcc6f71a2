"""microhom.factor: inertia, solves and the memory guard of the sparse back ends, against dense
numpy eigenvalues and closed forms (never the back end's own output)."""
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


def test_bad_input_names_the_parameter():
    with pytest.raises(ValueError, match="backend"):
        factor(sp.identity(3).tocsr(), backend="umfpack")
    with pytest.raises(ValueError, match="square"):
        factor(sp.csr_matrix(np.ones((2, 3))))
