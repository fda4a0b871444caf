"""Algebra on stacks of 2x2 matrices (one per frequency bin)."""

from __future__ import annotations

import numpy as np

__all__ = ["inv2x2", "matvec", "matmul"]


def inv2x2(M: np.ndarray) -> np.ndarray:
    """Inverse of a stack of 2x2 matrices, (..., 2, 2), in closed form.

    Closed form because ``np.linalg.inv`` on a (4097, 2, 2) stack is about 6x slower and
    this runs several times per vehicle-segment.
    """
    a, b, c, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
    det = a * d - b * c
    out = np.empty_like(M)
    out[..., 0, 0] = d
    out[..., 0, 1] = -b
    out[..., 1, 0] = -c
    out[..., 1, 1] = a
    return out / det[..., None, None]


def matvec(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per-bin product ``M[k] @ x[k]`` for M (K, 2, 2) and x (K, 2).

    Written out for 2x2 (about 2x faster than ``einsum`` on 3000 bins); general sizes fall
    back to ``einsum``.
    """
    if M.shape[-2:] != (2, 2):
        return np.einsum("kij,kj->ki", M, x)
    out = np.empty(x.shape, dtype=np.result_type(M, x))
    x0, x1 = x[:, 0], x[:, 1]
    out[:, 0] = M[:, 0, 0] * x0 + M[:, 0, 1] * x1
    out[:, 1] = M[:, 1, 0] * x0 + M[:, 1, 1] * x1
    return out


def matmul(*Ms: np.ndarray) -> np.ndarray:
    """Per-bin product of stacks of matrices, left to right."""
    out = Ms[0]
    for M in Ms[1:]:
        out = out @ M
    return out
