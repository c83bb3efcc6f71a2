"""Certified bounds on the spectrum of a symmetric pencil ``(H, M)`` at the cost of a few sparse
factorisations (Sylvester's law of inertia).

For a real symmetric ``H`` (n, n) and a symmetric positive definite ``M``, the number of
eigenvalues of the pencil (``H v = lam M v``) below a shift ``s`` equals the number of negative
pivots of the ``LDL^T`` factorisation of ``H - s M`` (``H - s M = M^1/2 (A - s I) M^1/2`` with
``A = M^-1/2 H M^-1/2`` is congruent to ``A - s I``, and congruent matrices have the same inertia).
:func:`certified_bound` uses this twice:

1. ``n_below(eps)`` = negative pivots of ``H - eps M``: the eigenvalues below the zero threshold
   ``eps`` (the null space, e.g. floppy modes and global translations, plus any negative modes;
   ``H + eps M`` separates the two when ``H`` is not known to be positive semi-definite).
2. A shift-invert Lanczos estimate ``lam_est`` of the smallest eigenvalue above ``eps`` (scipy
   ``eigsh`` on the factor of step 1), then ``n_below(s)`` at ``s = (1 - rel_gap) lam_est``.
   If it equals ``n_below(eps)``, no eigenvalue lies in ``[eps, s)``: ``s`` is a lower bound of
   the smallest eigenvalue above the null space, whatever the eigen-solver did. If not, the
   shift is lowered and counted again (the estimate missed an eigenvalue).

**One factorisation** (``guess=``, ``null_basis=``; ``docs/theory.md`` section 9, "One
factorisation"): when the caller has an estimate of the bound and vectors ``Z`` of the null space
(the global translations), the first and only factorisation is at ``s1 = GUESS_FACTOR * guess``.
If the Rayleigh-Ritz values of ``(Z^T H Z, Z^T M Z)`` lie below ``eps`` (with a round-off margin),
Courant-Fischer gives at least ``g = Z.shape[1]`` eigenvalues below ``eps``; if the count at ``s1``
is ``g``, none lies in ``[eps, s1)`` and ``s1`` is certified. Otherwise the count at ``eps`` follows
on the same analysis (``s1`` is certified if it agrees), and only if an eigenvalue lies in
``[eps, s1)`` the estimate and the lowered shift of step 2. The factorisations use PARDISO's
minimum-degree ordering (its analysis costs half of METIS's at 1e5 disks; ``microhom.factor``).

What "certified" rests on (``docs/stiffness.md``): (a) the factorisation is backward stable (a
supernodal Bunch-Kaufman ``LDL^T``, PARDISO with no perturbed pivot, or SuperLU with symmetric
diagonal pivoting), so its inertia is that of ``H - s M + E`` with ``|E|`` of the order of the
unit round-off times ``|H|``; the reported ``lower`` subtracts the margin
``1e3 u sqrt(n) lam_max`` for that; (b) the zero threshold: eigenvalues in ``(-eps, eps)`` are
taken as the exact null space (default ``eps = 1e-12`` of the pencil's scale; measured on the
1e5-disk network: 20 exact zero modes at ``|lam| < 2e-16``, the next eigenvalue ``7.8e-10``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, eigsh

from microhom.factor import (AUTO_PARDISO_DOF_PENCIL, FactorisationError, _Pardiso, _Pencil, available_backends,
                             factor)
from microhom.options import Options, finite_real, flag, integer, merged, real
from microhom.results import Result

__all__ = ["SpectralBound", "CertificateOptions", "certified_bound", "count_below", "gershgorin_upper", "ZERO_EPS",
           "CERTIFIED_MAX_DOF", "GUESS_FACTOR"]

#: largest system certified by default (``microhom.hierarchy.spectral_lower_bound``, ``dem analyse``):
#: 1e5 frictional disks (3 unknowns each)
CERTIFIED_MAX_DOF = 300_000
#: default zero threshold of the pencil (eigenvalues in (-eps, eps) are the null space)
ZERO_EPS = 1e-12
#: ``certified_bound(guess=)``: the first shift is this fraction of the guess (a guess up to twice
#: the eigenvalue still certifies with one factorisation; the bound is then at least half of it)
GUESS_FACTOR = 0.5
_U = np.finfo(float).eps


@dataclass(frozen=True, eq=False)
class SpectralBound(Result):
    """Certified spectral facts of a symmetric pencil ``(H, M)`` (``M`` positive definite).

    lower : certified lower bound of the smallest eigenvalue above ``eps`` [units of the pencil,
        dimensionless when ``M`` is a block of ``H``], or None (no positive eigenvalue, or the
        certificate failed: see ``reason``); estimate : the Lanczos estimate of that eigenvalue
        [-]; shift : the certified shift ``s`` before the round-off margin [-]; margin : the
        round-off margin ``1e3 u sqrt(n) lam_max`` subtracted [-]; upper : an upper bound of the
        largest eigenvalue (Gershgorin, when ``M^-1/2`` was given) or None; n_zero : eigenvalues in
        ``(-eps, eps)`` (the null space); n_negative : eigenvalues below ``-eps`` (0 when ``H`` is
        known to be positive semi-definite); n_below_shift : eigenvalues below ``shift`` (equals
        ``n_zero + n_negative`` when certified); eps : the zero threshold; n : size;
        n_factorisations : numeric factorisations made; backend : the solver; time : wall time [s];
        reason : why ``lower`` is None, else empty."""

    lower: float | None
    estimate: float | None
    shift: float | None
    margin: float
    upper: float | None
    n_zero: int
    n_negative: int
    n_below_shift: int | None
    eps: float
    n: int
    n_factorisations: int
    backend: str
    time: float
    reason: str = ""

    @property
    def certified(self) -> bool:
        """True when ``lower`` is a certified bound."""
        return self.lower is not None


def count_below(H, M, s, *, backend="auto", max_memory=None, dim=2):
    """Number of eigenvalues of the pencil ``(H, M)`` below ``s``: negative pivots of one
    ``LDL^T`` of ``H - s M`` (Sylvester). Raises :class:`microhom.factor.FactorisationError` when
    the back end cannot count. ``dim``: the network's dimension (2 or 3), for the memory guard's
    predicted fill (:func:`microhom.factor.predicted_factor_nnz`)."""
    f = factor((H - s * M).tocsr(), backend=backend, max_memory=max_memory, dim=dim)
    try:
        return _neg(f)
    finally:
        f.release()


def _neg(f):
    ine = f.inertia()
    if ine is None:
        raise FactorisationError(f"{f.name} did not pivot symmetrically: no inertia")
    if getattr(f, "n_perturbed", 0):
        raise FactorisationError(f"PARDISO perturbed {f.n_perturbed} pivot(s): no certified inertia")
    if ine.n_zero:
        raise FactorisationError(f"{ine.n_zero} exactly zero pivot(s): the shift is an eigenvalue")
    return ine.n_neg


def gershgorin_upper(H, Minv_sqrt):
    """Upper bound of the largest absolute eigenvalue of ``(H, M)``: the largest absolute row sum of
    ``M^-1/2 H M^-1/2`` (Gershgorin), plus a round-off margin [-]."""
    A = (Minv_sqrt @ H @ Minv_sqrt).tocsr()
    r = float(np.asarray(abs(A).sum(axis=1)).max()) if A.shape[0] else 0.0
    return r * (1.0 + 1e3 * _U * max(A.shape[0], 1))


def _check_m(M, backend, max_memory, dim=2):
    """``M`` positive definite, by the inertia of its factorisation (else ValueError)."""
    n = M.shape[0]
    fm = factor(M, backend=backend, max_memory=max_memory, dim=dim)
    try:
        m_neg = _neg(fm)
        m_pos = fm.inertia().n_pos
    finally:
        fm.release()
    if m_neg or m_pos != n:
        raise ValueError(f"M must be symmetric positive definite; its inertia is {m_pos} positive, "
                         f"{m_neg} negative of {n}")


@dataclass(frozen=True)
class CertificateOptions(Options):
    """How :func:`certified_bound` certifies: frozen, validated when made (a value outside its range
    raises :class:`~microhom.options.OptionError`, a ``ValueError`` naming the field and its range).

    ``certified_bound(H, M, psd=True)`` is ``certified_bound(H, M, CertificateOptions(psd=True))``;
    keywords given with an options object replace its values.

    Attributes
    ----------
    eps : float
        Zero threshold of the pencil, in (0, 1e-3]: eigenvalues in ``(-eps, eps)`` are the null
        space [-].
    psd : bool
        ``H`` is known to be positive semi-definite (no negative eigenvalues: saves the
        factorisation of ``H + eps M``).
    backend : str
        :func:`microhom.factor.factor` back end; must report the inertia: ``"auto"``,
        ``"pardiso"`` or ``"splu"``.
    rel_gap : float
        In (0, 0.5]: the shift is ``(1 - rel_gap)`` times the Lanczos estimate.
    tol : float
        Lanczos tolerance (scipy ``eigsh``), >= 0 (0: machine precision).
    ncv : int
        Lanczos vectors, >= 2.
    max_tries : int
        Shifts tried, >= 1.
    max_memory : float or None
        Memory limit of each factorisation [bytes], > 0; None: the available memory.
    check_m : bool
        Factorise ``M`` to check that it is positive definite (False: the caller has, e.g. from
        its particle blocks).
    dim : int
        The network's dimension, 2 or 3: the memory guard's predicted fill of a SuperLU factor
        (:func:`microhom.factor.predicted_factor_nnz`; 3D fill grows as ``n^1.6``, not
        ``n log n``). PARDISO's guard reads its own analysis and does not need it.
    """

    eps: float = ZERO_EPS
    psd: bool = False
    backend: str = "auto"
    rel_gap: float = 1e-3
    tol: float = 1e-4
    ncv: int = 10
    max_tries: int = 4
    max_memory: float | None = None
    check_m: bool = True
    dim: int = 2

    RULES = {
        "eps": ("in (0, 1e-3]", lambda v: real(v) and 0 < v <= 1e-3),
        "psd": ("True or False", flag),
        "backend": ("one that reports the inertia: 'auto', 'pardiso' or 'splu' (CHOLMOD is LL^T only)",
                    lambda v: isinstance(v, str) and v in ("auto", "pardiso", "splu")),
        "rel_gap": ("in (0, 0.5]", lambda v: real(v) and 0 < v <= 0.5),
        "tol": ("finite and >= 0", lambda v: finite_real(v) and v >= 0),
        "ncv": ("an integer >= 2", lambda v: integer(v) and v >= 2),
        "max_tries": ("an integer >= 1", lambda v: integer(v) and v >= 1),
        "max_memory": ("None or a positive number of bytes", lambda v: v is None or (finite_real(v) and v > 0)),
        "check_m": ("True or False", flag),
        "dim": ("2 or 3", lambda v: integer(v) and v in (2, 3)),
    }


def _check_pencil(H, M, guess=None):
    """Argument checks of :func:`certified_bound` on the pencil and the guess (the options are
    checked by :class:`CertificateOptions`); returns (H, M) as CSR."""
    H = sp.csr_matrix(H)
    M = sp.csr_matrix(M)
    n = H.shape[0]
    if H.shape != (n, n) or M.shape != (n, n):
        raise ValueError(f"H and M must be square of the same shape, got {H.shape} and {M.shape}")
    for name, X in (("H", H), ("M", M)):
        scale = float(abs(X).max()) if X.nnz else 0.0
        if X.nnz and not np.isfinite(scale):
            raise ValueError(f"{name} must be finite")
        if X.nnz and float(abs(X - X.T).max()) > 1e-12 * scale:
            raise ValueError(f"{name} must be symmetric (|{name} - {name}^T| <= 1e-12 max|{name}|)")
    if guess is not None and not (np.isfinite(guess) and guess > 0):
        raise ValueError(f"guess must be a positive finite estimate of the smallest eigenvalue, got {guess!r}")
    return H, M


def _start_vector(n: int) -> np.ndarray:
    """The Lanczos start vector, (n,): fixed (seeded), so that a certificate is the same on every
    run (scipy's ``eigsh`` draws a new random one per call otherwise, which moved the estimate,
    and with it the certified bound, by up to 1e-4 relative between two runs)."""
    return np.random.default_rng(20261202).standard_normal(n)


def certified_bound(H, M, options: CertificateOptions | None = None, *, Minv_sqrt=None, lam_max=None,
                    guess=None, null_basis=None, keep_factor=False, **overrides):
    """Certified lower bound of the smallest eigenvalue of the pencil ``(H, M)`` above the zero
    threshold ``eps``, with the counts of zero and negative eigenvalues (module docstring).

    H : (n, n) real symmetric sparse; M : (n, n) symmetric positive definite sparse (checked by
    its inertia unless ``check_m=False``); options : :class:`CertificateOptions` (``eps``,
    ``psd``, ``backend``, ``rel_gap``, ``tol``, ``ncv``, ``max_tries``, ``max_memory``,
    ``check_m``), None: the defaults; ``**overrides``: any of its fields as keywords
    (``certified_bound(H, M, psd=True)``). The problem's own data: Minv_sqrt : ``M^-1/2``
    (sparse) for the Gershgorin upper bound; lam_max : a known upper bound of the largest
    eigenvalue (used for the round-off margin); guess [-] : estimate of the smallest eigenvalue
    above ``eps`` (``psd`` only): one factorisation at ``s1 = GUESS_FACTOR * guess`` certifies
    ``s1`` when its count equals the null dimension that ``null_basis`` (n, g) proves (module
    docstring, "One factorisation"); else the count at ``eps`` and, if needed, the usual path.
    keep_factor : also return the factorisation of ``H - s M`` at the certified shift (a
    :class:`microhom.factor.Factor`, the caller releases it), or None when not certified:
    ``(SpectralBound, Factor or None)`` instead of the ``SpectralBound`` alone.

    Cost: two numeric factorisations (three when not ``psd``) and about ``ncv`` solves; one
    numeric factorisation and no solve when ``guess`` is good and ``null_basis`` spans the null
    space."""
    t0 = time.perf_counter()
    o = merged(CertificateOptions, options, overrides, "certified_bound")
    H, M = _check_pencil(H, M, guess)
    if o.check_m:
        _check_m(M, o.backend, o.max_memory, o.dim)
    c = _Certificate(H, M, o, Minv_sqrt, lam_max, t0)
    kept = None
    try:
        res = c.run(guess, null_basis, keep_factor)
        if keep_factor and res.lower is not None:
            kept, c.fac = c.fac, None     # the factor of H - s M at the certified shift s
    except FactorisationError as exc:     # perturbed pivots, no symmetric pivoting: no certificate
        res = c.out(None, None, None, None, 0, 0, f"no certified inertia: {exc}")
    finally:
        if c.fac is not None:
            c.fac.release()
    return (res, kept) if keep_factor else res


class _Certificate:
    """One run of :func:`certified_bound`: the pencil, its round-off margin, the back end and the
    factorisation of the latest shift (``fac``), with the steps of the certificate as methods."""

    def __init__(self, H, M, o, Minv_sqrt, lam_max, t0):
        self.H, self.M, self.o, self.t0 = H, M, o, t0
        self.n = n = H.shape[0]
        self.nf = 0
        self.upper = gershgorin_upper(H, Minv_sqrt) if Minv_sqrt is not None else None
        lmax = lam_max if lam_max is not None else (self.upper if self.upper is not None
                                                     else _lam_max_estimate(H, M))
        self.margin = 1e3 * _U * np.sqrt(max(n, 1)) * abs(lmax)
        be = o.backend
        if be == "auto":      # SuperLU is as fast below AUTO_PARDISO_DOF_PENCIL unknowns (microhom.factor)
            be = "pardiso" if "pardiso" in available_backends() and n >= AUTO_PARDISO_DOF_PENCIL else "splu"
        self.be = be
        self.pencil = _Pencil(H, M) if be == "pardiso" else None
        self.fac = None

    def out(self, lower, est, shift, nb, n_zero, n_neg, reason):
        """The :class:`SpectralBound` of this run."""
        return SpectralBound(lower=lower, estimate=est, shift=shift, margin=float(self.margin), upper=self.upper,
                             n_zero=int(n_zero), n_negative=int(n_neg), n_below_shift=nb, eps=float(self.o.eps),
                             n=self.n, n_factorisations=self.nf, backend=self.be,
                             time=time.perf_counter() - self.t0, reason=reason)

    def factor_at(self, sh):
        """Negative pivots of ``H - sh M`` (one numeric factorisation, kept in ``fac``)."""
        self.nf += 1
        mm = self.o.max_memory
        if self.pencil is None:
            if self.fac is not None:
                self.fac.release()
            self.fac = factor((self.H - sh * self.M).tocsr(), backend=self.be, max_memory=mm, dim=self.o.dim)
        elif self.fac is None:    # matching only where H may be strongly indefinite (pre-stress)
            self.fac = _Pardiso(self.pencil.matrix(sh), upper=True, max_memory=mm, matching=not self.o.psd,
                                ordering="mmd")
        else:
            self.fac.refactor(self.pencil.at(sh))      # the analysis (ordering, symbolic factor) reused
        return _neg(self.fac)

    def certified_at(self, s, nb, n_zero, n_neg, est):
        """``s`` less the round-off margin, if that stays above ``eps``."""
        lower = s - self.margin
        if lower <= self.o.eps:
            return self.out(None, est, s, nb, n_zero, n_neg,
                            f"the round-off margin {self.margin:.2g} swallows the bound {s:.3g}")
        return self.out(float(lower), est, float(s), nb, n_zero, n_neg, "")

    def run(self, guess, null_basis, keep_factor):
        """The certificate: the guess's one factorisation, the counts at ``-eps`` and ``eps``, the
        Lanczos estimate and the lowered shifts (module docstring)."""
        o, n = self.o, self.n
        s1 = k1 = None
        if guess is not None and o.psd and GUESS_FACTOR * guess - self.margin > o.eps:
            s1 = GUESS_FACTOR * float(guess)      # one factorisation: the count at s1 ...
            k1 = self.factor_at(s1)
            if k1 < n and k1 == _proven_null(self.H, self.M, null_basis, o.eps):   # ... is the proven null space
                return self.certified_at(s1, k1, k1, 0, None)
        n_neg = 0 if o.psd else self.factor_at(-o.eps)
        n_low = self.factor_at(o.eps)
        n_zero = n_low - n_neg
        if n_low >= n:
            return self.out(None, None, None, None, n_zero, n_neg, "no eigenvalue above eps")
        if s1 is not None and k1 == n_low:        # no eigenvalue in [eps, s1): s1 holds (the factor
            _ = self.factor_at(s1) if keep_factor else None   # kept is that of H - s1 M)
            return self.certified_at(s1, k1, n_zero, n_neg, None)
        est = self.estimate(n_low)
        if est is None:
            return self.out(None, None, None, None, n_zero, n_neg,
                            "the Lanczos estimate found no eigenvalue above eps")
        return self.lowered(est, n_low, n_zero, n_neg)

    def estimate(self, n_low):
        """Smallest eigenvalue above ``eps``: dense for small pencils, else shift-invert Lanczos on
        the factor at ``eps``; None when Lanczos finds none."""
        n, eps = self.n, self.o.eps
        k = 1          # the certificate (the counts) catches a missed eigenvalue; ncv Lanczos vectors
        if n <= 50 or n - n_low <= k + 1:
            w = _dense_eigs(self.H, self.M)
            return float(w[w > eps].min())
        op = LinearOperator((n, n), matvec=self.fac.solve, dtype=float)
        w = eigsh(self.H, k=k, M=self.M, sigma=eps, which="LA", OPinv=op, tol=self.o.tol,
                  ncv=min(n - 1, int(self.o.ncv)), v0=_start_vector(n), return_eigenvectors=False)
        w = w[w > eps]
        return float(w.min()) if w.size else None

    def lowered(self, est, n_low, n_zero, n_neg):
        """Count at ``s = (1 - rel_gap) est``; lowered towards ``eps`` while an eigenvalue lies in
        ``[eps, s)`` (the estimate missed it), at most ``max_tries`` shifts."""
        eps, max_tries = self.o.eps, self.o.max_tries
        s = (1.0 - self.o.rel_gap) * est
        for _ in range(int(max_tries)):
            if s <= eps:
                break
            nb = self.factor_at(s)
            if nb == n_low:
                return self.certified_at(s, nb, n_zero, n_neg, est)
            s = np.sqrt(s * eps) if s > 1e4 * eps else 0.5 * (s + eps)   # missed eigenvalue(s)
        return self.out(None, est, None, None, n_zero, n_neg,
                        f"no shift above eps = {eps:g} certified in {max_tries} tries (eigenvalues crowd "
                        "just above the zero threshold)")


def _proven_null(H, M, Z, eps):
    """Number of eigenvalues of the pencil ``(H, M)`` below ``eps`` proven by the basis ``Z``
    (n, g): ``g`` when the largest Rayleigh-Ritz value of ``(Z^T H Z, Z^T M Z)``, plus a round-off
    margin, lies below ``eps`` (Courant-Fischer: then ``lambda_g <= theta_g < eps``), else 0.

    Margin: the computed ``Z^T H Z`` differs from the exact one entrywise by at most
    ``D = (m + 1 + sqrt(n)) u |Z|^T |H| |Z|`` (``m`` non-zeros per row; the ``sqrt(n)`` estimate of
    the dot products, as for the certificate's margin), so ``theta_g`` moves by at most the
    largest row sum of ``D`` over the smallest eigenvalue of ``Z^T M Z`` (taken 1e-8 low for its
    own round-off)."""
    if Z is None:
        return 0
    Z = np.asarray(Z, dtype=float)
    if Z.ndim != 2 or Z.shape[0] != H.shape[0] or Z.shape[1] == 0:
        return 0
    from scipy.linalg import eigh
    GH = Z.T @ (H @ Z)
    GM = Z.T @ (M @ Z)
    GH, GM = 0.5 * (GH + GH.T), 0.5 * (GM + GM.T)
    wm = np.linalg.eigvalsh(GM)
    if not wm.size or wm.min() <= 1e-12 * max(wm.max(), 1e-300):
        return 0                                  # dependent columns: no proof
    m = int(np.diff(H.indptr).max(initial=0)) if sp.isspmatrix_csr(H) else H.shape[0]
    aZ = np.abs(Z)
    D = (m + 1 + np.sqrt(H.shape[0])) * _U * (aZ.T @ (abs(H) @ aZ))
    theta = float(eigh(GH, GM, eigvals_only=True).max())
    bound = theta + float(D.sum(axis=1).max()) / (wm.min() * (1 - 1e-8))
    return int(Z.shape[1]) if bound < eps else 0


def _dense_eigs(H, M):
    from scipy.linalg import eigh
    return eigh(H.toarray(), M.toarray(), eigvals_only=True)


def _lam_max_estimate(H, M):
    """Largest |eigenvalue| of the pencil by Lanczos (for the round-off margin only)."""
    n = H.shape[0]
    if n <= 200:
        return float(np.abs(_dense_eigs(H, M)).max())
    d = np.abs(M.diagonal())
    d = np.where(d > 0, d, 1.0)
    s = sp.diags(1.0 / np.sqrt(d))
    A = s @ H @ s
    w = eigsh(A, k=1, which="LM", v0=_start_vector(n), return_eigenvectors=False, tol=1e-3)
    return 2.0 * float(np.abs(w).max())
