"""Triangular forms of composed realisations, from the forms of their parts.

A sender of the ``paper`` mechanism builds ``T~ = Q^T D^-1 A D Q`` from a series connection ``A``
of systems whose Schur forms it has (its own ``T``, ``S``, memoised, and the small ``Psi`` it just
drew), a balancing ``D`` (powers of two) and a random orthogonal ``Q``. It certifies ``T~`` before
sending it (:mod:`~roadcollab.lti.stability`). A Schur decomposition of the 20-22 state ``T~``
costs 45 us of LAPACK ``dgees`` per system; this module gives the same certificate a triangular
form without one:

- *Series.* ``A = [[A1, 0], [X, A2]]`` with ``A1 = U1 R1 U1^H``, ``A2 = U2 R2 U2^H``: with
  ``U = [[0, U1], [U2, 0]]`` (unitary), ``A = U R U^H`` for the upper triangular
  ``R = [[R2, U2^H X U1], [0, R1]]`` (check: ``A U = U R`` block by block).
- *Hidden.* ``A~ = M^-1 A M`` with ``M = D Q``: ``A~ = W^-H R W^H`` for ``W = Q^T D U``, and
  ``X = Re(W Y W^H)`` solves ``A~^T X A~ - X = -I`` when ``R^H Y R - Y = -H``,
  ``H = (W^H W)^-1 = U^H D^-2 U`` (:func:`~roadcollab.lti._cert_kernel.hidden_figures`, which
  forms ``W`` and ``H`` itself).

The certificate is checked against ``A~`` itself (its residual), so this is only a cheaper way to
find ``X``; when the check fails the sender certifies ``A~`` as a receiver does, from its own
Schur form. Measured in docs/speed.md, "Ninth pass".
"""

from __future__ import annotations

import numpy as np

__all__ = ["series_schur"]


def series_schur(first: tuple[np.ndarray, np.ndarray], second: tuple[np.ndarray, np.ndarray],
                 A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A complex Schur form of the series connection ``A`` (:func:`~roadcollab.lti.realisation.series`)
    from the Schur forms of its two parts (module docstring).

    Parameters
    ----------
    first, second : (R, U) of (n1, n1), (n2, n2) complex ndarray
        ``A1 = U1 R1 U1^H`` and ``A2 = U2 R2 U2^H``: the systems acting first and second.
    A : (n1 + n2, n1 + n2) ndarray
        ``[[A1, 0], [X, A2]]``; only ``X`` is read.

    Returns
    -------
    R, U : (n, n) complex ndarray
        ``A = U R U^H`` (to round-off), ``R`` upper triangular with ``R2``'s eigenvalues first.
    """
    (R1, U1), (R2, U2) = first, second
    n1, n2 = R1.shape[0], R2.shape[0]
    n = n1 + n2
    R = np.zeros((n, n), dtype=complex)
    R[:n2, :n2] = R2
    R[n2:, n2:] = R1
    R[:n2, n2:] = U2.conj().T @ (np.asarray(A[n1:, :n1], dtype=float) @ U1)
    U = np.zeros((n, n), dtype=complex)
    U[:n1, n2:] = U1
    U[n1:, :n2] = U2
    return R, U
