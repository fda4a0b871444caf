"""ARX identification with a common denominator (MIMO, 2 inputs x 2 outputs)."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from .realisation import StateSpaceData, continuous_poles

__all__ = ["arx_fit", "arx_poles", "arx_state_space"]


def arx_fit(u: np.ndarray, y: np.ndarray, na: int, nb: int, decimate: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares MIMO ARX with a common scalar denominator.

    ``y_c[k] + sum_i a_i y_c[k-i] = sum_{m, i=0..nb} b_{c,m,i} u_m[k-i]`` for both outputs,
    with ``a`` shared.

    Parameters
    ----------
    u, y : (N, 2) ndarray
        Input and output signals.
    na, nb : int
        Denominator and numerator orders.
    decimate : int
        Every ``decimate``-th sample is kept before the fit.

    Returns
    -------
    a : (na,) ndarray
    b : (2, 2, nb + 1) ndarray
    """
    u = u[::decimate]
    y = y[::decimate]
    N = y.shape[0]
    k0 = max(na, nb)
    rows = N - k0
    n_b = 2 * (nb + 1)
    # unknowns: [a (na), b_out0 (n_b), b_out1 (n_b)]
    X = np.zeros((2 * rows, na + 2 * n_b))
    rhs = np.empty(2 * rows)
    ks = np.arange(k0, N)
    for c in range(2):
        r = slice(c * rows, (c + 1) * rows)
        for i in range(1, na + 1):
            X[r, i - 1] = -y[ks - i, c]
        col = na + c * n_b
        for m in range(2):
            for i in range(nb + 1):
                X[r, col + m * (nb + 1) + i] = u[ks - i, m]
        rhs[r] = y[ks, c]
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    # Householder QR instead of lstsq's SVD: about 20x faster here (4 ms vs 80 ms) and
    # accurate for the column-scaled, full-rank regressor.
    Q, R = np.linalg.qr(X / scale)
    theta = scipy.linalg.solve_triangular(R, Q.T @ rhs) / scale
    a = theta[:na]
    b = theta[na:].reshape(2, 2, nb + 1)
    return a, b


def arx_poles(u: np.ndarray, y: np.ndarray, dt: float, order: int, decimate: int = 2) -> np.ndarray:
    """Continuous poles (rad/s) of a common-denominator ARX model of order ``order``.

    Parameters
    ----------
    u : (N, 2) ndarray
        Input signal (in the study: a hardened message's ``z``, m/s).
    y : (N, 2) ndarray
        Output signal (in the study: ``w_band - z``, m/s).
    dt : float
        Sample period of ``u`` and ``y``, s.
    order : int
        Order of the common denominator and of the numerators.
    decimate : int
        Every ``decimate``-th sample is kept before the fit (sample period ``dt * decimate``).

    Returns
    -------
    (order,) complex ndarray
        Roots ``z`` of the denominator mapped to the s-plane, ``log(z) / (dt * decimate)``, rad/s.
    """
    a, _ = arx_fit(u, y, order, order, decimate)
    return continuous_poles(np.roots(np.concatenate([[1.0], a])), dt * decimate)


def arx_state_space(u: np.ndarray, y: np.ndarray, dt: float, order: int, decimate: int) -> StateSpaceData:
    """Observable-form realisation (one block per output) of the fitted ARX model.

    Parameters
    ----------
    u, y : (N, 2) ndarray
        Input and output signals.
    dt : float
        Sample period, s.
    order : int
        Denominator and numerator order.
    decimate : int
        Every ``decimate``-th sample is kept before the fit.

    Returns
    -------
    StateSpaceData
        Sample period ``dt * decimate``.
    """
    a, b = arx_fit(u, y, order, order, decimate)
    n = order
    Ao = np.zeros((n, n))
    Ao[:, 0] = -a
    Ao[:-1, 1:] = np.eye(n - 1)
    A = np.kron(np.eye(2), Ao)
    B = np.zeros((2 * n, 2))
    C = np.zeros((2, 2 * n))
    D = np.zeros((2, 2))
    for c in range(2):
        C[c, c * n] = 1.0
        for m in range(2):
            bb = b[c, m]
            D[c, m] = bb[0]
            B[c * n:(c + 1) * n, m] = bb[1:] - a * bb[0]
    return StateSpaceData(A, B, C, D, dt * decimate)
