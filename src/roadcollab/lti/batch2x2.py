"""Algebra on stacks of 2x2 matrices (one per frequency bin)."""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ._bin_kernel import diff_norms2, inv2, matvec2, receiver_z2
from .kernels import kernel_path

__all__ = ["inv2x2", "matvec", "matmul", "sigma_max_2x2", "condition_2x2", "receiver_z", "diff_norms"]


def inv2x2(M: np.ndarray) -> np.ndarray:
    """Inverse of a stack of 2x2 matrices, (..., 2, 2), in closed form.

    Closed form because ``np.linalg.inv`` on a (4097, 2, 2) stack is about 6x slower and
    this runs several times per vehicle-segment. The adjugate is scaled by ``1 / det`` (one
    reciprocal per bin): numpy's complex division (Smith's algorithm) of the whole stack took
    3x longer.

    Parameters
    ----------
    M : (..., 2, 2) ndarray

    Returns
    -------
    (..., 2, 2) ndarray
    """
    M = np.asarray(M)
    if M.dtype.kind not in "fc":
        M = M.astype(float)         # np.reciprocal of integers would truncate
    if kernel_path() == "compiled":
        inv = inv2(M)
        if inv is not None:
            return inv
    a, b, c, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
    r = np.reciprocal(a * d - b * c)
    out = np.empty_like(M)
    np.multiply(d, r, out=out[..., 0, 0])
    np.multiply(b, -r, out=out[..., 0, 1])
    np.multiply(c, -r, out=out[..., 1, 0])
    np.multiply(a, r, out=out[..., 1, 1])
    return out


def matvec(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per-bin product ``M[k] @ x[k]`` for M (K, 2, 2) and x (K, 2).

    Written out for 2x2 (about 2x faster than ``einsum`` on 3000 bins); general sizes fall
    back to ``einsum``.

    Parameters
    ----------
    M : (K, p, m) ndarray
    x : (K, m) ndarray

    Returns
    -------
    (K, p) ndarray
    """
    if M.shape[-2:] != (2, 2):
        out: np.ndarray = np.einsum("kij,kj->ki", M, x)
        return out
    if kernel_path() == "compiled":      # one compiled pass over the bins (docs/speed.md, "Third pass")
        y = matvec2(M, x)
        if y is not None:
            return y
    out = np.empty(x.shape, dtype=np.result_type(M, x))
    x0, x1 = x[:, 0], x[:, 1]
    out[:, 0] = M[:, 0, 0] * x0 + M[:, 0, 1] * x1
    out[:, 1] = M[:, 1, 0] * x0 + M[:, 1, 1] * x1
    return out


def diff_norms(x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-bin 2-norms of a difference and of its reference: ``||x_k - ref_k||`` and ``||ref_k||``.

    On the compiled path one pass over the bins (the two ``np.linalg.norm`` calls with their temporaries
    took about 0.2 ms on 3,359 bins, measured); the same values to one unit in the last place (numpy's complex
    product may fuse a multiply and an add, the kernel does not).

    Parameters
    ----------
    x, ref : (K, 2) ndarray

    Returns
    -------
    num, den : (K,) float ndarray
    """
    if kernel_path() == "compiled":
        norms = diff_norms2(x, ref)
        if norms is not None:
            return norms
    return np.linalg.norm(x - ref, axis=1), np.linalg.norm(ref, axis=1)


def _mm2(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for stacks of 2x2 matrices (broadcast leading axes), written out."""
    out = np.empty(np.broadcast_shapes(A.shape, B.shape), dtype=np.result_type(A, B))
    for i in range(2):
        for j in range(2):
            np.multiply(A[..., i, 0], B[..., 0, j], out=out[..., i, j])
            out[..., i, j] += A[..., i, 1] * B[..., 1, j]
    return out


def matmul(*Ms: np.ndarray) -> np.ndarray:
    """Per-bin product of stacks of matrices, left to right.

    Stacks of 2x2 matrices are multiplied written out: numpy's ``@`` loops over the stack with a
    per-matrix kernel, 1.3 ms for two (3376, 2, 2) complex stacks against 0.1-0.2 ms here
    (measured); the sums are the same two products per entry, so results agree to round-off.

    Parameters
    ----------
    *Ms : (..., p, q) ndarray
        At least one stack, with compatible inner dimensions and broadcastable leading axes.

    Returns
    -------
    ndarray
    """
    out = np.asarray(Ms[0])
    for M in Ms[1:]:
        M = np.asarray(M)
        out = _mm2(out, M) if out.shape[-2:] == (2, 2) and M.shape[-2:] == (2, 2) else out @ M
    return out


def sigma_max_2x2(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest singular value and ``|det|`` of a stack of 2x2 matrices, in closed form.

    ``s1 s2 = |det H|`` and ``s1^2 + s2^2 = ||H||_F^2``, so
    ``s1^2 = (F + sqrt(F^2 - 4 |det H|^2)) / 2`` with ``F = ||H||_F^2``; about 20x faster than a
    batched SVD.

    Parameters
    ----------
    H : (..., 2, 2) ndarray

    Returns
    -------
    s_max, abs_det : (...,) ndarray
    """
    fro2 = np.sum(np.abs(H) ** 2, axis=(-2, -1))
    det = np.abs(H[..., 0, 0] * H[..., 1, 1] - H[..., 0, 1] * H[..., 1, 0])
    disc = np.sqrt(np.maximum(fro2**2 - 4 * det**2, 0.0))
    return np.sqrt((fro2 + disc) / 2), det


def condition_2x2(H: np.ndarray) -> np.ndarray:
    """2-norm condition numbers ``s_max / s_min = s_max^2 / |det|`` of a stack of 2x2 matrices
    (inf where singular).

    Parameters
    ----------
    H : (..., 2, 2) ndarray

    Returns
    -------
    (...,) ndarray
    """
    s1, det = sigma_max_2x2(H)
    with np.errstate(divide="ignore"):
        return np.where(det > 0, s1**2 / np.where(det > 0, det, 1.0), np.inf)


def receiver_z(T: np.ndarray | None, S: np.ndarray, E: np.ndarray, Wf: np.ndarray,
               weight: np.ndarray | None = None, *, T_inv: np.ndarray | None = None) -> np.ndarray:
    """The receiver's inversion ``z = W T^-1 (e - S w^f)`` per bin (eqs. 11-12 in factored form).

    Parameters
    ----------
    T, S : (K, 2, 2) complex ndarray
        Responses of the sender's ``T`` and ``S`` (or ``T~``, ``S~``); ``T`` may be None when
        ``T_inv`` is given.
    E, Wf : (K, 2) complex ndarray
        Spectra of the sender's ``e`` and ``w^f``.
    weight : (K,) ndarray, optional
        ``W`` per bin; none means ``W = 1``.
    T_inv : (K, 2, 2) complex ndarray, optional
        ``T^-1`` per bin, if already known (a receiver memoises it for an unchanged sender).

    Returns
    -------
    (K, 2) complex ndarray
    """
    if T_inv is None:
        if T is None:
            raise ParameterError("receiver_z needs T or T_inv")
        if weight is not None and kernel_path() == "compiled":
            # One pass, the steps below to round-off (_bin_kernel.receiver_z2).
            fused = receiver_z2(T, S, E, Wf, weight)
            if fused is not None:
                return fused
        T_inv = inv2x2(T)
    z = matvec(T_inv, E - matvec(S, Wf))
    if weight is not None:
        z *= weight[:, None]
    return z
