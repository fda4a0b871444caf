"""Discrete-time stability certificates: spectral radius and a verified Lyapunov bound.

The certificate rests on a solution ``X`` of ``A^T X A - X = -I`` whose residual is *checked*,
never on how ``X`` was found: if ``X`` is positive definite and the residual small, then
``V(x) = x^T X x`` decreases along ``x_{k+1} = A x_k`` and
``||A^k||_2 <= sqrt(lambda_max(X) / lambda_min(X))`` for every ``k``. So ``X`` may come from the
cheapest solver that works. From the eigendecomposition ``A = V diag(lambda) V^-1`` it is closed
form, ``X = V^-H Y V^-1`` with ``Y_ik = (V^H V)_ik / (1 - conj(lambda_i) lambda_k)``: a few
``n x n`` products where scipy's bilinear Schur solver takes 0.25-0.4 ms at n = 14..22 (measured
on the 2-core machine; the eigendecomposition is needed for the spectral radius anyway). A
defective or ill-conditioned ``V`` (the vehicles' ``T`` has the plant's poles twice) fails the
residual check.

Given a complex Schur form ``A = U R U^H`` (a receiver computes one anyway to evaluate the
sender's systems, :mod:`~roadcollab.lti.blockdiag`), ``X`` comes from one triangular Sylvester
solve instead: the Cayley map ``R_c = (R - I)(R + I)^-1`` is upper triangular, and
``R^H Y R - Y = -I`` becomes ``R_c^H Y + Y R_c = -2 (R^H + I)^-1 (R + I)^-1`` (LAPACK ``ztrsyl``),
``X = Re(U Y U^H)``; this is scipy's bilinear method without its second Schur decomposition.
Either way the residual is verified, and scipy's solver is the last fallback.
"""

from __future__ import annotations

import math
import warnings
from typing import Callable

import numpy as np
import numpy.typing as npt
import scipy.linalg

from ._cert_kernel import certificate_figures as _compiled_figures, schur_certificate as _compiled_schur_certificate
from ._cert_kernel import hidden_figures as _hidden_figures
from .kernels import kernel_path

__all__ = ["LYAPUNOV_RTOL", "spectral_radius_and_gain", "hidden_radius_and_gain"]

#: Largest relative residual of the Lyapunov solution ``A^T X A - X + I``.
LYAPUNOV_RTOL = 1e-8


def _verified_gain(A: np.ndarray, X: np.ndarray) -> float:
    """``sqrt(cond X)`` if ``X`` is finite, positive definite and solves ``A^T X A - X = -I`` to
    ``LYAPUNOV_RTOL`` relative (to ``||X|| (1 + ||A||^2)``); inf otherwise."""
    X = 0.5 * (X + X.T)
    if not np.isfinite(X).all():
        return math.inf
    eye = np.eye(A.shape[0])
    resid = np.linalg.norm(A.T @ X @ A - X + eye)
    scale = np.linalg.norm(X) * (1.0 + np.linalg.norm(A) ** 2)
    return _checked_gain(X, float(resid), float(scale))


def _checked_gain(X: np.ndarray, resid: float, scale: float) -> float:
    """``sqrt(cond X)`` for a finite symmetric ``X`` whose residual ``resid`` passes against
    ``LYAPUNOV_RTOL * scale`` and which is positive definite; inf otherwise (NaN figures fail)."""
    ev = np.linalg.eigvalsh(X)
    if not (resid <= LYAPUNOV_RTOL * scale and ev[0] > 0.0):
        return math.inf
    return float(math.sqrt(ev[-1] / ev[0]))


def _eigen_lyapunov(lam: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``X`` of ``A^T X A - X = -I`` from ``A = V diag(lam) V^-1`` (real part; may be inaccurate,
    the caller verifies it)."""
    G = V.conj().T @ V
    Y = G / (1.0 - lam.conj()[:, None] * lam[None, :])
    Vinv = np.linalg.inv(V)
    return np.real(Vinv.conj().T @ Y @ Vinv)


def _schur_lyapunov(R: np.ndarray, U: np.ndarray) -> np.ndarray:
    """``X`` of ``A^T X A - X = -I`` from ``A = U R U^H`` (module docstring; the caller verifies it)."""
    n = R.shape[0]
    eye = np.eye(n)
    Rp_inv, info = scipy.linalg.lapack.ztrtri(R + eye)        # (R + I)^-1, upper (solve_triangular: 3x slower)
    if info != 0:
        raise np.linalg.LinAlgError(f"ztrtri failed (info={info})")
    Rc = (R - eye) @ Rp_inv
    rhs = -2.0 * (Rp_inv.conj().T @ Rp_inv)
    Y, scale, info = scipy.linalg.lapack.ztrsyl(Rc, Rc, rhs, trana="C", tranb="N")
    if info < 0 or not scale > 0:
        raise np.linalg.LinAlgError(f"ztrsyl failed (info={info})")
    return np.real(U @ (Y / scale) @ U.conj().T)


def _figures_gain(figures: Callable[[], tuple[float, float, float, float, float]], R: np.ndarray
                  ) -> tuple[float, float]:
    """Radius and verified gain from a compiled certificate's ``(radius, resid, scale, lo, hi)``
    (inf gain if the call fails, the residual check fails or ``X`` is not positive definite)."""
    try:
        radius, resid, scale, lo, hi = figures()
    except (np.linalg.LinAlgError, ValueError):
        return float(np.max(np.abs(np.diag(R)))), math.inf
    if not (resid <= LYAPUNOV_RTOL * scale and lo > 0.0):       # NaN figures fail here too
        return radius, math.inf
    return radius, float(math.sqrt(hi / lo))


def _compiled_radius_and_gain(A: np.ndarray, schur: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """Radius and verified gain from a Schur form in one compiled call (the compiled path's
    :func:`_schur_gain` with the radius and ``X``'s eigenvalues; inf gain if anything fails)."""
    return _figures_gain(lambda: _compiled_figures(schur[0], schur[1], A), schur[0])


def hidden_radius_and_gain(A: np.ndarray, R: np.ndarray, U: np.ndarray, scale: np.ndarray, Q: np.ndarray
                           ) -> tuple[float, float]:
    """Radius and verified gain of ``A = Q^T D^-1 (U R U^H) D Q``, ``D = diag(scale)``, from that form
    (compiled path; :mod:`~roadcollab.lti.composed_schur`), checked against ``A`` itself as every
    certificate here.

    Parameters
    ----------
    A : (n, n) ndarray
        Finite, real, ``n >= 1``.
    R, U : (n, n) complex ndarray
        A complex Schur form of ``D Q A Q^T D^-1``.
    scale : (n,) ndarray
        Positive.
    Q : (n, n) ndarray
        Orthogonal.

    Returns
    -------
    radius : float
        ``max |R_ii|``.
    gain : float
        ``sqrt(cond X)``; inf when the radius is not below 1 or the check fails (the caller then
        certifies ``A`` another way).
    """
    return _figures_gain(lambda: _hidden_figures(R, U, scale, Q, A), R)


def _schur_gain(A: np.ndarray, schur: tuple[np.ndarray, np.ndarray]) -> float:
    """The verified gain from :func:`_schur_lyapunov` (inf if it fails)."""
    try:
        if kernel_path() == "compiled":
            # The Stein solve, X and its residual in one compiled call (docs/speed.md, "Fifth pass").
            X, resid, scale = _compiled_schur_certificate(schur[0], schur[1], A)
            if not (math.isfinite(resid) and math.isfinite(scale)):
                return math.inf
            return _checked_gain(X, resid, scale)
        return _verified_gain(A, _schur_lyapunov(*schur))
    except (np.linalg.LinAlgError, ValueError):
        return math.inf


def spectral_radius_and_gain(A: npt.ArrayLike, *,
                             schur: tuple[np.ndarray, np.ndarray] | Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
                             eig: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, float]:
    """Computed spectral radius of ``A`` and a certified bound on ``sup_k ||A^k||_2``.

    Parameters
    ----------
    A : (n, n) array_like
        Finite, real.
    schur : (R, U) or callable, optional
        A complex Schur form ``A = U R U^H`` (e.g. memoised by the caller): the radius is read from
        its diagonal and the certificate comes from one triangular Sylvester solve. A callable
        returning one is called only when the eigendecomposition's certificate fails (a defective
        or ill-conditioned ``A``): the eigen route is cheaper when it works (0.41 vs 0.67 ms for a
        sender's two obfuscated systems, measured), and a receiver then has the Schur form it
        evaluates ``A`` with anyway.
    eig : (lam, V), optional
        The eigendecomposition ``A = V diag(lam) V^-1`` (``np.linalg.eig(A)``) if already computed
        (a system object memoises it for its frequency response); ignored when ``schur`` is a tuple.

    Returns
    -------
    radius : float
        ``max |eig(A)|`` as computed (0 for ``n = 0``).
    gain : float
        ``sqrt(cond X)`` for a verified Lyapunov solution ``X`` (module docstring), inf when none
        is found (``X`` not positive definite, residual too large, or the solvers failed). 1 for
        ``n = 0``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the eigenvalues cannot be computed.
    """
    A = np.asarray(A, dtype=float)
    if A.shape[0] == 0:
        return 0.0, 1.0
    if schur is not None and not callable(schur) and kernel_path() == "compiled":
        # The receiver's route on the compiled path (every system it decodes, and a sender's check
        # of its own outgoing ones): radius, Stein solve, residual and eigenvalues in one call.
        radius, gain = _compiled_radius_and_gain(A, schur)
        if not radius < 1.0:
            return radius, math.inf
        if math.isfinite(gain):
            return radius, gain
        return radius, _last_resort_gain(A)
    with np.errstate(all="ignore"):      # huge but finite entries may overflow inside LAPACK
        if schur is not None and not callable(schur):
            radius = float(np.max(np.abs(np.diag(schur[0]))))
            if not radius < 1.0:
                return radius, math.inf
            gain = _schur_gain(A, schur)
        else:
            lam, V = np.linalg.eig(A) if eig is None else eig
            radius = float(np.max(np.abs(lam)))
            if not radius < 1.0:
                return radius, math.inf
            try:
                gain = _verified_gain(A, _eigen_lyapunov(lam, V))
            except (np.linalg.LinAlgError, ValueError):
                gain = math.inf
            if not math.isfinite(gain) and schur is not None:
                try:
                    gain = _schur_gain(A, schur())
                except (np.linalg.LinAlgError, ValueError):
                    gain = math.inf
        if math.isfinite(gain):
            return radius, gain
    return radius, _last_resort_gain(A)


def _last_resort_gain(A: np.ndarray) -> float:
    """The verified gain from scipy's Lyapunov solver, the fallback of every route (inf if it fails)."""
    with np.errstate(all="ignore"):      # huge but finite entries may overflow inside LAPACK
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)   # judged by the residual
                X = scipy.linalg.solve_discrete_lyapunov(A.T, np.eye(A.shape[0]))
            return _verified_gain(A, X)
        except (np.linalg.LinAlgError, ValueError):
            return math.inf      # overflow inside the solver (inf/NaN): no certificate
