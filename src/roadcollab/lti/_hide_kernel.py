"""The hiding similarity of an obfuscated realisation in one compiled call (numba; the ``"compiled"``
path of :mod:`~roadcollab.lti.kernels`).

``Q`` is the orthogonal factor of a Gaussian matrix ``G = Q R`` with ``R``'s diagonal made positive
(:func:`~roadcollab.lti.realisation.random_orthogonal`): that factor is unique, so Householder
reflections here give LAPACK's ``Q`` to round-off. Then ``(Q^T A Q, Q^T B, C Q)``. One call instead of
``qr``, the sign fix and three products (docs/speed.md, "Fifth pass"). Plain loops over reals.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import compiled_available, jit_options

__all__ = ["qr_similarity"]

_KERNEL: dict[str, Any] = {}
_COMPILED_NAMES = ("_mul", "_mul_t", "_qr_similarity")   # callees first: compiled in order
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("_mul", "_mul_t")


def _build() -> dict[str, Any]:
    """The compiled function (``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(hide=None)
        return _KERNEL
    import numba

    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(hide=globals()["_qr_similarity"])
    return _KERNEL


def _mul(X: np.ndarray, Y: np.ndarray) -> np.ndarray:   # pragma: no cover - compiled
    """``X Y``, row by row (contiguous inner loop)."""
    out = np.zeros((X.shape[0], Y.shape[1]))
    for i in range(X.shape[0]):
        for k in range(X.shape[1]):
            a = X[i, k]
            for j in range(Y.shape[1]):
                out[i, j] += a * Y[k, j]
    return out


def _mul_t(X: np.ndarray, Y: np.ndarray) -> np.ndarray:   # pragma: no cover - compiled
    """``X^T Y`` (contiguous inner loop)."""
    out = np.zeros((X.shape[1], Y.shape[1]))
    for k in range(X.shape[0]):
        for i in range(X.shape[1]):
            q = X[k, i]
            for j in range(Y.shape[1]):
                out[i, j] += q * Y[k, j]
    return out


def _qr_similarity(G: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:   # pragma: no cover - compiled
    """``(Q^T A Q, Q^T B, C Q, Q)`` for the orthogonal factor ``Q`` of ``G = Q R``, ``diag(R) > 0``."""
    n = G.shape[0]
    R = G.copy()
    Q = np.zeros((n, n))
    for i in range(n):
        Q[i, i] = 1.0
    v = np.empty(n)
    for k in range(n - 1):
        s = 0.0
        for i in range(k, n):
            s += R[i, k] * R[i, k]
        norm = np.sqrt(s)
        if norm == 0.0:
            continue
        x0 = R[k, k]
        alpha = -norm if x0 >= 0.0 else norm      # R_kk after the reflection (dlarfg's sign)
        vv = 0.0
        for i in range(k, n):
            v[i] = R[i, k]
        v[k] = x0 - alpha
        for i in range(k, n):
            vv += v[i] * v[i]
        if vv == 0.0:
            continue
        f = 2.0 / vv
        for j in range(k, n):                     # R <- (I - f v v^T) R
            d = 0.0
            for i in range(k, n):
                d += v[i] * R[i, j]
            d *= f
            for i in range(k, n):
                R[i, j] -= d * v[i]
        for i in range(n):                        # Q <- Q (I - f v v^T)
            d = 0.0
            for j in range(k, n):
                d += Q[i, j] * v[j]
            d *= f
            for j in range(k, n):
                Q[i, j] -= d * v[j]
    for j in range(n):                            # Q diag(sign(diag R)): R's diagonal positive
        if R[j, j] < 0.0:
            for i in range(n):
                Q[i, j] = -Q[i, j]
    AQ = _mul(A, Q)
    return _mul_t(Q, AQ), _mul_t(Q, B), _mul(C, Q), Q


def qr_similarity(G: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(Q^T A Q, Q^T B, C Q, Q)`` with ``Q`` the orthogonal factor of ``G`` whose ``R`` has a positive
    diagonal (:func:`~roadcollab.lti.realisation.random_orthogonal` of the same ``G``, to round-off).

    Parameters
    ----------
    G : (n, n) ndarray
        Finite, nonsingular (a Gaussian draw).
    A, B, C : (n, n), (n, m), (p, n) ndarray

    Returns
    -------
    A2, B2, C2 : ndarray
        The transformed matrices.
    Q : (n, n) ndarray
        The orthogonal factor (a sender certifies ``A2`` from it and ``A``'s Schur form).
    """
    c = np.ascontiguousarray
    A2, B2, C2, Q = _build()["hide"](c(G, float), c(A, float), c(B, float), c(C, float))
    # Arrays that own their data (numba's have its allocator's record as base): a message holding
    # them can be frozen and its validation memoised, so encoding it does not check it again
    # (45-50 us of every paper segment, measured).
    return A2.copy(), B2.copy(), C2.copy(), Q
