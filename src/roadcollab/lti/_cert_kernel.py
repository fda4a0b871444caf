"""Compiled (numba) parts of a receiver's stability certificate and Schur form (the ``"compiled"`` path
of :mod:`~roadcollab.lti.kernels`).

- *The Lyapunov solve.* The certificate is the one of :mod:`~roadcollab.lti.stability`: a solution
  ``X`` of ``A^T X A - X = -I`` whose residual is checked against ``A`` itself. Here ``X`` comes from
  the complex Schur form ``A = U R U^H`` by a triangular Stein solve (Bartels-Stewart without a
  second factorisation): ``R^H Y R - Y = -I`` column by column, column ``j`` from the lower
  triangular system ``(R_jj R^H - I) y_j = -e_j - R^H sum_{l<j} y_l R_lj``, then ``X = Re(U Y U^H)``.
  How ``X`` was found does not matter to the certificate: only its checked residual and eigenvalues.
- *The complex Schur form* from LAPACK's real one (``dgees``, about half the time of ``zgees`` at
  n = 22) and one Givens rotation per 2x2 block (as ``scipy.linalg.rsf2csf``, compiled).

Plain loops over real pairs: numba's array expressions cost seconds of first-run compilation each.
Measurements in docs/speed.md, "Third pass".
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg

from . import _evd_kernel
from .kernels import compiled_available, jit_options, read_only

__all__ = ["schur_lyapunov", "schur_certificate", "certificate_figures", "hidden_figures", "hidden_parts", "complex_schur"]

_KERNEL: dict[str, Any] = {}

#: The right-hand side the compiled solves take when they solve with ``-I`` (not read).
_NO_RHS = np.zeros((1, 1), dtype=complex)

#: The functions compiled by :func:`_build` (rebound in place, so compiled callers find compiled callees).
_COMPILED_NAMES = ("_stein_parts", "_stein_schur", "_certificate", "_certificate_figures", "_hidden_parts",
                   "_real_to_complex")
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("_stein_parts",)
#: The compiled extreme eigenvalues (:mod:`~roadcollab.lti._evd_kernel`), bound by :func:`_build`.
_eigvalsh_ends: Any = None


def _build() -> dict[str, Any]:
    """The compiled functions (``{}`` values ``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(schur=None, certificate=None, figures=None, hidden=None, rsf2csf=None)
        return _KERNEL
    import numba

    globals()["_eigvalsh_ends"] = _evd_kernel._build()["ends"]     # compiled callee, before its callers
    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(schur=globals()["_stein_schur"], certificate=globals()["_certificate"],
                   figures=globals()["_certificate_figures"], hidden=globals()["_hidden_parts"], rsf2csf=globals()["_real_to_complex"])
    return _KERNEL


def _stein_parts(R: np.ndarray, H: np.ndarray, general: bool) -> tuple[np.ndarray, np.ndarray]:   # pragma: no cover - compiled
    """``Y`` of ``R^H Y R - Y = -I`` for an upper triangular ``R`` (module docstring) as ``(Yr, Yi)``,
    row ``j`` = column ``j`` of ``Y``; ``R^H Y R - Y = -H`` if ``general`` (``H`` is not read
    otherwise). Complex numbers as real pairs, plain loops: no array expressions, which cost seconds
    of first-run compilation."""
    n = R.shape[0]
    Rr = np.empty((n, n))
    Ri = np.empty((n, n))                           # R^H column k = conj(R row k)
    for i in range(n):
        for j in range(n):
            Rr[i, j] = R[i, j].real
            Ri[i, j] = R[i, j].imag
    Yr = np.zeros((n, n))                           # row j = column j of Y
    Yi = np.zeros((n, n))
    vr = np.empty(n)
    vi = np.empty(n)
    hr = np.empty(n)
    hi = np.empty(n)
    for j in range(n):
        for i in range(n):
            vr[i] = 0.0
            vi[i] = 0.0
            hr[i] = -H[i, j].real if general else 0.0
            hi[i] = -H[i, j].imag if general else 0.0
        for l in range(j):                          # v = sum_{l<j} y_l R_lj
            a, b = Rr[l, j], Ri[l, j]
            for i in range(n):
                vr[i] += Yr[l, i] * a - Yi[l, i] * b
                vi[i] += Yr[l, i] * b + Yi[l, i] * a
        if not general:
            hr[j] = -1.0                            # h = -e_j - R^H v (-H e_j - R^H v if general)
        for k in range(n):
            a, b = vr[k], vi[k]
            for i in range(k, n):                   # (R^H)_ik = conj(R_ki)
                hr[i] -= Rr[k, i] * a + Ri[k, i] * b
                hi[i] -= Rr[k, i] * b - Ri[k, i] * a
        pr, pi = Rr[j, j], Ri[j, j]
        for k in range(n):                          # (R_jj R^H - I) y = h, forward substitution
            dr = pr * Rr[k, k] + pi * Ri[k, k] - 1.0      # R_jj conj(R_kk) - 1
            di = pi * Rr[k, k] - pr * Ri[k, k]
            q = 1.0 / (dr * dr + di * di)
            yr = (hr[k] * dr + hi[k] * di) * q
            yi = (hi[k] * dr - hr[k] * di) * q
            Yr[j, k] = yr
            Yi[j, k] = yi
            cr = pr * yr - pi * yi                  # c = R_jj y_k
            ci = pr * yi + pi * yr
            for i in range(k + 1, n):
                hr[i] -= Rr[k, i] * cr + Ri[k, i] * ci
                hi[i] -= Rr[k, i] * ci - Ri[k, i] * cr
    return Yr, Yi


def _stein_schur(R: np.ndarray) -> np.ndarray:   # pragma: no cover - compiled
    """``Y`` of ``R^H Y R - Y = -I`` for an upper triangular ``R``, complex (:func:`_stein_parts`)."""
    n = R.shape[0]
    Yr, Yi = _stein_parts(R, np.zeros((1, 1), dtype=np.complex128), False)
    Y = np.empty((n, n), dtype=np.complex128)
    for j in range(n):
        for k in range(n):
            Y[k, j] = complex(Yr[j, k], Yi[j, k])
    return Y


def _certificate(R: np.ndarray, U: np.ndarray, A: np.ndarray, H: np.ndarray, general: bool
                 ) -> tuple[np.ndarray, float, float]:   # pragma: no cover - compiled
    """The Stein solve, ``X = Re(U Y U^H)`` symmetrised, and the residual figures of
    :func:`~roadcollab.lti.stability._verified_gain` in one call: ``(X, ||A^T X A - X + I||_F,
    ||X||_F (1 + ||A||_F^2))``; the residual is NaN when ``X`` is not finite. With ``general``, ``Y``
    solves ``R^H Y R - Y = -H`` (``A = U^-H R U^H`` with ``H = (U^H U)^-1``: :func:`hidden_figures`);
    the residual is always the one of ``A`` itself. Real pairs, plain loops, every inner loop a
    contiguous ``axpy`` (so numba vectorises it; reductions it cannot reorder)."""
    n = R.shape[0]
    Yr, Yi = _stein_parts(R, H, general)                        # Y[k, j] = Yr[j, k] + i Yi[j, k]
    Ur = np.empty((n, n))
    Ui = np.empty((n, n))
    Ha = np.empty((n, n))                           # U^H = Ha + i Hb
    Hb = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            a, b = U[i, j].real, U[i, j].imag
            Ur[i, j] = a
            Ui[i, j] = b
            Ha[j, i] = a
            Hb[j, i] = -b
    Va = np.zeros((n, n))                           # V = Y U^H
    Vb = np.zeros((n, n))
    for k in range(n):
        for j in range(n):
            ya, yb = Yr[j, k], Yi[j, k]
            for b in range(n):
                Va[k, b] += ya * Ha[j, b] - yb * Hb[j, b]
                Vb[k, b] += ya * Hb[j, b] + yb * Ha[j, b]
    X = np.zeros((n, n))                            # Re(U V)
    for a in range(n):
        for k in range(n):
            ur, ui = Ur[a, k], Ui[a, k]
            for b in range(n):
                X[a, b] += ur * Va[k, b] - ui * Vb[k, b]
    finite = True
    nx = 0.0
    for a in range(n):                              # 0.5 (X + X^T)
        for b in range(a, n):
            v = 0.5 * (X[a, b] + X[b, a])
            X[a, b] = v
            X[b, a] = v
            if not np.isfinite(v):
                finite = False
            nx += v * v if a == b else 2.0 * v * v
    na = 0.0
    for a in range(n):
        for b in range(n):
            na += A[a, b] * A[a, b]
    P = np.zeros((n, n))                            # X A
    for a in range(n):
        for k in range(n):
            x = X[a, k]
            for b in range(n):
                P[a, b] += x * A[k, b]
    M = np.zeros((n, n))                            # A^T P
    for k in range(n):
        for a in range(n):
            c = A[k, a]
            for b in range(n):
                M[a, b] += c * P[k, b]
    res = 0.0
    for a in range(n):                              # ||A^T X A - X + I||_F
        for b in range(n):
            s = M[a, b] - X[a, b]
            if a == b:
                s += 1.0
            res += s * s
    resid = np.sqrt(res) if finite else np.nan
    return X, resid, np.sqrt(nx) * (1.0 + na)


def _certificate_figures(R: np.ndarray, U: np.ndarray, A: np.ndarray, H: np.ndarray, general: bool
                         ) -> tuple[float, float, float, float, float]:   # pragma: no cover - compiled
    """``(radius, resid, scale, lambda_min(X), lambda_max(X))``: the spectral radius from ``diag(R)``
    and, when it is below 1, :func:`_certificate` and the extreme eigenvalues of its ``X`` (LAPACK
    ``dsyevd`` through numba, :mod:`~roadcollab.lti._evd_kernel`); otherwise, or when ``X`` is not
    finite, ``resid`` and the eigenvalues are NaN. ``H``, ``general``: as :func:`_certificate`."""
    n = R.shape[0]
    radius = 0.0
    for i in range(n):
        radius = max(radius, abs(R[i, i]))
    if not radius < 1.0:
        return radius, np.nan, np.nan, np.nan, np.nan
    X, resid, scale = _certificate(R, U, A, H, general)
    if not (np.isfinite(resid) and np.isfinite(scale)):
        return radius, resid, scale, np.nan, np.nan
    lo, hi = _eigvalsh_ends(X)
    return radius, resid, scale, lo, hi


def _hidden_parts(U: np.ndarray, scale: np.ndarray, Q: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:   # pragma: no cover - compiled
    """``(W, H)`` of ``A = Q^T D^-1 (U R U^H) D Q``, ``D = diag(scale)``: ``W = Q^T D U`` and
    ``H = (W^H W)^-1 = U^H D^-2 U`` (``U`` unitary, ``Q`` orthogonal), so that ``A = W^-H R W^H`` and
    ``X = Re(W Y W^H)`` for ``R^H Y R - Y = -H`` (:mod:`~roadcollab.lti.composed_schur`). A kernel of
    its own, not calling :func:`_certificate_figures`: compiling that again inside it cost 3 s of a
    fresh installation's first run (measured)."""
    n = U.shape[0]
    W = np.zeros((n, n), dtype=np.complex128)
    for k in range(n):                              # W = Q^T (D U): row k of D U, scattered
        sk = scale[k]
        for i in range(n):
            q = Q[k, i] * sk
            for j in range(n):
                W[i, j] += q * U[k, j]
    H = np.zeros((n, n), dtype=np.complex128)
    for k in range(n):                              # H = sum_k conj(U_k.)^T U_k. / scale_k^2
        f = 1.0 / (scale[k] * scale[k])
        for i in range(n):
            if U[k, i] == 0:
                # Its terms are signed zeros (U is finite), and a sum that starts at +0 is never -0: adding
                # them changes no bit. U of a series connection is two thirds zeros (the composed form's
                # [[0, U1], [U2, 0]], Psi's pairs): 25 % of this kernel (docs/speed.md, "Eleventh pass").
                continue
            c = np.conj(U[k, i]) * f
            for j in range(n):
                H[i, j] += c * U[k, j]
    return W, H


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


#: ``dgees``'s optimal workspace by matrix order (a pure function of ``n`` for one LAPACK build).
_LWORK: dict[int, int] = {}


def _no_sort(wr: float, wi: float) -> None:
    """``dgees``'s selection callback when no eigenvalues are reordered (``sort_t = 0``)."""
    return None


def complex_schur(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A complex Schur form ``A = U T U^H`` from LAPACK's real Schur form (``dgees``, half the time of
    ``zgees`` at n = 22) and one compiled Givens rotation per 2x2 block. A valid complex Schur form
    (unitary ``U``, upper triangular ``T``), not the one ``zgees`` returns.

    Parameters
    ----------
    A : (n, n) real ndarray
        Finite, ``n >= 1``.

    Returns
    -------
    T, U : (n, n) complex ndarray

    Raises
    ------
    ValueError
        If ``A`` is not a finite non-empty square matrix.
    numpy.linalg.LinAlgError
        If LAPACK finds no Schur form.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if A.ndim != 2 or n != A.shape[1] or n == 0 or not np.isfinite(A).all():
        raise ValueError(f"expected a finite, non-empty square matrix, got shape {A.shape}")
    lwork = _LWORK.get(n)
    if lwork is None:           # LAPACK's optimal workspace, queried once per order as scipy's schur does
        lwork = _LWORK[n] = int(scipy.linalg.lapack.dgees(_no_sort, A, lwork=-1)[-2][0])
    # dgees directly: scipy.linalg.schur's call with the same workspace, bit for bit (tested), without
    # its batch wrapper and per-call workspace query (about 40 of 130 us at n = 22, docs/speed.md).
    Tr, _, _, _, Zr, _, info = scipy.linalg.lapack.dgees(_no_sort, A, lwork=lwork)
    if info != 0:
        raise np.linalg.LinAlgError(f"dgees failed (info={info})")
    # C order: dgees returns Fortran arrays, but a 1x1 one is C-contiguous too and numba then compiled the
    # rotations a second time (docs/speed.md, "Seventh pass"); the certificate wants C order anyway.
    T = np.array(Tr, dtype=np.complex128, order="C")
    U = np.array(Zr, dtype=np.complex128, order="C")
    _build()["rsf2csf"](T, U)
    return T, U


def schur_lyapunov(R: np.ndarray, U: np.ndarray) -> np.ndarray:
    """``X`` of ``A^T X A - X = -I`` from ``A = U R U^H``: the triangular Stein solve compiled, then
    ``X = Re(U Y U^H)`` (BLAS). The caller verifies ``X`` (its residual against ``A`` itself).

    Parameters
    ----------
    R, U : (n, n) complex ndarray
        ``R`` upper triangular.

    Returns
    -------
    (n, n) ndarray
    """
    Y = _build()["schur"](np.ascontiguousarray(R, complex))
    X: np.ndarray = np.real(U @ Y @ U.conj().T)
    return X


def schur_certificate(R: np.ndarray, U: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``X`` of ``A^T X A - X = -I`` from ``A = U R U^H`` and the figures its verification needs, in one
    compiled call (the Stein solve, ``X = Re(U Y U^H)`` symmetrised, the residual): what
    :func:`schur_lyapunov` followed by the residual of
    :func:`~roadcollab.lti.stability._verified_gain` compute, to round-off.

    Parameters
    ----------
    R, U : (n, n) complex ndarray
        ``R`` upper triangular.
    A : (n, n) ndarray
        Real, finite.

    Returns
    -------
    X : (n, n) ndarray
        Symmetric.
    resid : float
        ``||A^T X A - X + I||_F`` (NaN if ``X`` is not finite).
    scale : float
        ``||X||_F (1 + ||A||_F^2)``.
    """
    X, resid, scale = _build()["certificate"](np.ascontiguousarray(R, complex), np.ascontiguousarray(U, complex),
                                               read_only(np.ascontiguousarray(A, float)), _NO_RHS, False)
    return X, float(resid), float(scale)


def certificate_figures(R: np.ndarray, U: np.ndarray, A: np.ndarray) -> tuple[float, float, float, float, float]:
    """Everything :func:`~roadcollab.lti.stability.spectral_radius_and_gain` needs from a complex Schur
    form, in one compiled call: the radius, and the figures of :func:`schur_certificate` with the
    extreme eigenvalues of its ``X`` (what the numpy path's ``eigvalsh`` gives, to round-off). One call
    instead of a certificate call and ``np.linalg.eigvalsh``: the four certificates of a ``paper``
    vehicle-segment spent about 30 us in the glue between them (docs/speed.md, "Ninth pass").

    Parameters
    ----------
    R, U : (n, n) complex ndarray
        ``R`` upper triangular, ``A = U R U^H``; ``n >= 1``.
    A : (n, n) ndarray
        Real, finite.

    Returns
    -------
    radius : float
        ``max |R_ii|``.
    resid, scale : float
        As :func:`schur_certificate`; NaN residual when ``radius >= 1`` (not computed) or ``X`` is not
        finite.
    lo, hi : float
        Smallest and largest eigenvalue of ``X``; NaN when ``resid`` or ``scale`` is not finite.
    """
    out = _build()["figures"](np.ascontiguousarray(R, complex), np.ascontiguousarray(U, complex),
                              read_only(np.ascontiguousarray(A, float)), _NO_RHS, False)
    return float(out[0]), float(out[1]), float(out[2]), float(out[3]), float(out[4])


def hidden_figures(R: np.ndarray, U: np.ndarray, scale: np.ndarray, Q: np.ndarray, A: np.ndarray
                   ) -> tuple[float, float, float, float, float]:
    """:func:`certificate_figures` of ``A = Q^T D^-1 (U R U^H) D Q`` from that form, without a Schur
    decomposition of ``A``: ``Y`` of ``R^H Y R - Y = -H`` with ``W = Q^T D U``, ``H = U^H D^-2 U``, and
    ``X = Re(W Y W^H)`` solves ``A^T X A - X = -I`` (:mod:`~roadcollab.lti.composed_schur`); the residual
    is checked against ``A`` itself as always. A sender knows this form of its hidden ``T~``, ``S~``.

    Parameters
    ----------
    R, U : (n, n) complex ndarray
        A complex Schur form of the matrix before hiding; ``n >= 1``.
    scale : (n,) ndarray
        ``diag(D)``, positive.
    Q : (n, n) ndarray
        Orthogonal.
    A : (n, n) ndarray
        Real, finite: the hidden matrix.

    Returns
    -------
    radius, resid, scale, lo, hi : float
        As :func:`certificate_figures`.
    """
    W, H = hidden_parts(U, scale, Q)
    out = _build()["figures"](np.ascontiguousarray(R, complex), W, read_only(np.ascontiguousarray(A, float)), H, True)
    return float(out[0]), float(out[1]), float(out[2]), float(out[3]), float(out[4])


def hidden_parts(U: np.ndarray, scale: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``W = Q^T D U`` and ``H = U^H D^-2 U`` of :func:`hidden_figures` (compiled).

    Parameters
    ----------
    U : (n, n) complex ndarray
        Unitary.
    scale : (n,) ndarray
        ``diag(D)``, positive.
    Q : (n, n) ndarray
        Orthogonal.

    Returns
    -------
    W, H : (n, n) complex ndarray
    """
    c = np.ascontiguousarray
    W, H = _build()["hidden"](c(U, complex), read_only(c(scale, float)), read_only(c(Q, float)))
    return W, H
