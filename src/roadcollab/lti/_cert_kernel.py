"""The stability certificate's Lyapunov solve and residual check, and the eigenvalue clustering of
:mod:`~roadcollab.lti.blockdiag`, compiled (numba; the ``"compiled"`` path of :mod:`~roadcollab.lti.kernels`).

The certificate is the one of :mod:`~roadcollab.lti.stability`: a solution ``X`` of
``A^T X A - X = -I`` whose residual is checked. Here ``X`` comes from the complex Schur form
``A = U R U^H`` by a triangular Stein solve (Bartels-Stewart without a second factorisation):
``R^H Y R - Y = -I`` column by column, column ``j`` from the lower triangular system
``(R_jj R^H - I) y_j = -e_j - R^H sum_{l<j} y_l R_lj``, then ``X = Re(U Y U^H)``; or from the
eigendecomposition (the closed form of :func:`~roadcollab.lti.stability._eigen_lyapunov`). The
residual ``||A^T X A - X + I||_F`` and its scale ``||X||_F (1 + ||A||_F^2)`` are computed in the same
pass; the caller compares them and takes the eigenvalues of ``X`` (LAPACK). How ``X`` was found does
not matter to the certificate: only the checked residual and the eigenvalues of ``X`` do.

Measured against the numpy route (LAPACK ``ztrtri`` + ``ztrsyl`` and numpy products, 0.24 ms for a
receiver's order-22 ``T~`` at load 11) in docs/speed.md, "Third pass".
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg

from .kernels import compiled_available, jit_options

__all__ = ["schur_certificate", "eigen_certificate", "cluster_labels", "complex_schur"]

_KERNEL: dict[str, Any] = {}

#: The functions compiled by :func:`_build` (rebound in place, so compiled callers find compiled callees).
_COMPILED_NAMES = ("_residual", "_stein_schur", "_eigen_x", "_labels", "_real_to_complex")


def _build() -> dict[str, Any]:
    """The compiled functions (``{}`` values ``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(schur=None, eigen=None, labels=None, rsf2csf=None)
        return _KERNEL
    import numba

    jit = numba.njit(**jit_options())
    for name in _COMPILED_NAMES:
        globals()[name] = jit(globals()[name])
    _KERNEL.update(schur=globals()["_stein_schur"], eigen=globals()["_eigen_x"], labels=globals()["_labels"],
                   rsf2csf=globals()["_real_to_complex"])
    return _KERNEL


def _residual(A: np.ndarray, X: np.ndarray) -> tuple[float, float]:   # pragma: no cover - compiled
    """``(||A^T X A - X + I||_F, ||X||_F (1 + ||A||_F^2))`` for a symmetric ``X`` (NaN if it is not
    finite). Every loop is an axpy over contiguous rows, which LLVM vectorises (a reduction would not be)."""
    n = A.shape[0]
    if not np.isfinite(X).all():
        return np.nan, np.nan
    XA = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            x = X[i, k]
            for j in range(n):
                XA[i, j] += x * A[k, j]
    Rs = -X.copy()                    # A^T XA - X + I
    for k in range(n):
        for i in range(n):
            a = A[k, i]
            for j in range(n):
                Rs[i, j] += a * XA[k, j]
    for i in range(n):
        Rs[i, i] += 1.0
    return np.sqrt(np.sum(Rs * Rs)), np.sqrt(np.sum(X * X)) * (1.0 + np.sum(A * A))


def _stein_schur(R: np.ndarray, U: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float, float]:   # pragma: no cover
    """``X`` of ``A^T X A - X = -I`` from ``A = U R U^H`` (module docstring), and its residual and scale."""
    n = R.shape[0]
    Rc = np.conj(R)                                 # row k of Rc = column k of R^H (lower triangular)
    Yt = np.zeros((n, n), dtype=np.complex128)      # Yt[j] = column j of Y
    v = np.empty(n, dtype=np.complex128)
    rhs = np.empty(n, dtype=np.complex128)
    for j in range(n):
        v[:] = 0.0
        for l in range(j):
            r = R[l, j]
            for i in range(n):
                v[i] += Yt[l, i] * r
        # rhs = -e_j - R^H v
        rhs[:] = 0.0
        rhs[j] = -1.0
        for k in range(n):
            c = v[k]
            for i in range(k, n):
                rhs[i] -= Rc[k, i] * c
        # (R_jj R^H - I) y = rhs, forward substitution by columns of R^H
        rjj = R[j, j]
        y = Yt[j]
        for k in range(n):
            d = rjj * Rc[k, k] - 1.0
            yk = rhs[k] * (np.conj(d) * (1.0 / (d.real * d.real + d.imag * d.imag)))   # real reciprocal
            y[k] = yk
            c = rjj * yk
            for i in range(k + 1, n):
                rhs[i] -= Rc[k, i] * c
    # X = Re(U Y U^H) = Re(U W) with W = Y U^H, W[k, :] = sum_j Y[k, j] conj(U[:, j]) (Yt[j, k] = Y[k, j])
    UcT = np.conj(U.T).copy()                       # UcT[j, :] = conj(U[:, j])
    W = np.zeros((n, n), dtype=np.complex128)
    for k in range(n):
        for j in range(n):
            y = Yt[j, k]
            for i in range(n):
                W[k, i] += y * UcT[j, i]
    Wr = np.ascontiguousarray(W.real)
    Wi = np.ascontiguousarray(W.imag)
    X = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            ur, ui = U[i, k].real, U[i, k].imag
            for j in range(n):
                X[i, j] += ur * Wr[k, j] - ui * Wi[k, j]
    for i in range(n):                              # symmetric in exact arithmetic: symmetrise
        for j in range(i):
            a = 0.5 * (X[i, j] + X[j, i])
            X[i, j] = a
            X[j, i] = a
    res, scale = _residual(A, X)
    return X, res, scale


def _eigen_x(lam: np.ndarray, V: np.ndarray, Vinv: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float, float]:  # pragma: no cover
    """``X = Re(Vinv^H Y Vinv)``, ``Y_ik = (V^H V)_ik / (1 - conj(lam_i) lam_k)`` (the closed form of
    :func:`~roadcollab.lti.stability._eigen_lyapunov`), and its residual and scale."""
    n = V.shape[0]
    Vc = np.conj(V)
    Y = np.zeros((n, n), dtype=np.complex128)        # V^H V by rows of V
    for r in range(n):
        for i in range(n):
            c = Vc[r, i]
            for k in range(n):
                Y[i, k] += c * V[r, k]
    for i in range(n):
        for k in range(n):
            Y[i, k] /= 1.0 - np.conj(lam[i]) * lam[k]
    YV = np.zeros((n, n), dtype=np.complex128)       # Y Vinv
    for i in range(n):
        for k in range(n):
            y = Y[i, k]
            for j in range(n):
                YV[i, j] += y * Vinv[k, j]
    Yr = np.ascontiguousarray(YV.real)
    Yi = np.ascontiguousarray(YV.imag)
    X = np.zeros((n, n))                             # Re(Vinv^H YV)
    for k in range(n):
        for i in range(n):
            ar, ai = Vinv[k, i].real, Vinv[k, i].imag
            for j in range(n):
                X[i, j] += ar * Yr[k, j] + ai * Yi[k, j]
    for i in range(n):
        for j in range(i):
            a = 0.5 * (X[i, j] + X[j, i])
            X[i, j] = a
            X[j, i] = a
    res, scale = _residual(A, X)
    return X, res, scale


def _labels(lam: np.ndarray, tol: float, rel: float) -> np.ndarray:   # pragma: no cover - compiled
    """Smallest index in each eigenvalue's connected component of the graph
    ``|lam_i - lam_k| <= max(tol, rel min(d_i, d_k))``, ``d_i = |1 - |lam_i||``."""
    n = lam.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = abs(1.0 - abs(lam[i]))
    label = np.arange(n)
    changed = True
    while changed:
        changed = False
        for i in range(n):
            for k in range(n):
                if label[k] < label[i] and abs(lam[i] - lam[k]) <= max(tol, rel * min(d[i], d[k])):
                    label[i] = label[k]
                    changed = True
    return label


def _real_to_complex(T: np.ndarray, Z: np.ndarray) -> None:   # pragma: no cover - compiled
    """Real Schur form ``(T, Z)`` (complex copies) to complex Schur form in place: one Givens rotation per
    2x2 block, as ``scipy.linalg.rsf2csf``."""
    n = T.shape[0]
    eps = np.finfo(np.float64).eps
    for m in range(n - 1, 0, -1):
        if abs(T[m, m - 1]) > eps * (abs(T[m - 1, m - 1]) + abs(T[m, m])):
            a, b, c, d = T[m - 1, m - 1], T[m - 1, m], T[m, m - 1], T[m, m]
            h = 0.5 * (a - d)
            mu = h + np.sqrt(h * h + b * c)          # an eigenvalue of the block, minus d
            r = np.sqrt(abs(mu) ** 2 + abs(c) ** 2)
            gc = mu / r
            gs = c / r
            # G = [[conj(gc), gs], [-gs, gc]]; rows m-1, m of T from column m-1 on: G @ T
            for j in range(m - 1, n):
                t0, t1 = T[m - 1, j], T[m, j]
                T[m - 1, j] = np.conj(gc) * t0 + gs * t1
                T[m, j] = -gs * t0 + gc * t1
            # columns m-1, m of T (rows up to m) and of Z: X @ G^H, G^H = [[gc, -conj(gs)], [conj(gs), conj(gc)]]
            for i in range(m + 1):
                t0, t1 = T[i, m - 1], T[i, m]
                T[i, m - 1] = t0 * gc + t1 * np.conj(gs)
                T[i, m] = -t0 * np.conj(gs) + t1 * np.conj(gc)
            for i in range(n):
                t0, t1 = Z[i, m - 1], Z[i, m]
                Z[i, m - 1] = t0 * gc + t1 * np.conj(gs)
                Z[i, m] = -t0 * np.conj(gs) + t1 * np.conj(gc)
        T[m, m - 1] = 0.0


def complex_schur(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A complex Schur form ``A = U T U^H`` from LAPACK's real Schur form (``dgees``, half the time of
    ``zgees`` at n = 22) and one compiled Givens rotation per 2x2 block. A valid complex Schur form
    (unitary ``U``, upper triangular ``T``), not the one ``zgees`` returns.

    Parameters
    ----------
    A : (n, n) real ndarray
        Finite.

    Returns
    -------
    T, U : (n, n) complex ndarray
    """
    Tr, Zr = scipy.linalg.schur(np.asarray(A, dtype=float), output="real")
    T = Tr.astype(np.complex128)
    U = Zr.astype(np.complex128)
    _build()["rsf2csf"](T, U)
    return T, U


def schur_certificate(A: np.ndarray, R: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``X``, residual and scale from the complex Schur form (module docstring), compiled.

    Parameters
    ----------
    A : (n, n) real ndarray
    R, U : (n, n) complex ndarray
        ``A = U R U^H``, ``R`` upper triangular.

    Returns
    -------
    X : (n, n) ndarray
        Symmetrised.
    resid, scale : float
        ``||A^T X A - X + I||_F`` and ``||X||_F (1 + ||A||_F^2)``; NaN if ``X`` is not finite.
    """
    X, resid, scale = _build()["schur"](np.ascontiguousarray(R, complex), np.ascontiguousarray(U, complex),
                                        np.ascontiguousarray(A, float))
    return X, float(resid), float(scale)


def eigen_certificate(A: np.ndarray, lam: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``X``, residual and scale from the eigendecomposition ``A = V diag(lam) V^-1``, compiled.

    Parameters
    ----------
    A : (n, n) real ndarray
    lam : (n,) complex ndarray
    V : (n, n) complex ndarray

    Returns
    -------
    X, resid, scale
        As :func:`schur_certificate`.

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``V`` is singular.
    """
    V = np.ascontiguousarray(V, complex)
    X, resid, scale = _build()["eigen"](np.ascontiguousarray(lam, complex), V,
                                        np.ascontiguousarray(np.linalg.inv(V)), np.ascontiguousarray(A, float))
    return X, float(resid), float(scale)


def cluster_labels(lam: np.ndarray, tol: float, rel: float) -> np.ndarray:
    """The component labels of :func:`~roadcollab.lti.blockdiag._clusters`, compiled.

    Parameters
    ----------
    lam : (n,) complex ndarray
    tol, rel : float

    Returns
    -------
    (n,) int ndarray
        The smallest index of each eigenvalue's cluster.
    """
    labels: np.ndarray = _build()["labels"](np.ascontiguousarray(lam, complex), float(tol), float(rel))
    return labels
