"""Vectorised arithmetic modulo the Goldilocks prime ``p = 2^64 - 2^32 + 1`` on ``uint64`` arrays.

The NTT of :mod:`.secagg_flp` on numpy object arrays of Python ints took 22 s of a 23 s proof for one
spectrum of the fusion study (13,504 coordinates, 234,588 bits; loaded 2-core machine); no installable
library does 64-bit prime-field NTTs on numpy arrays (``galois`` falls back to Python ints above 2^32),
so the reduction is written out here: ``2^64 = 2^32 - 1`` and ``2^96 = -1`` modulo ``p``. Every
function takes and returns canonical values in ``[0, p)``; numpy's ``uint64`` arithmetic wraps
modulo ``2^64``, which the carries below account for.
"""

from __future__ import annotations

import numpy as np

P = 2 ** 64 - 2 ** 32 + 1
_P = np.uint64(P)
_EPS = np.uint64(2 ** 32 - 1)
_M32 = np.uint64(2 ** 32 - 1)
_S32 = np.uint64(32)


def add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a + b mod p``."""
    s = a + b
    s = np.where(s < a, s + _EPS, s)
    out: np.ndarray = np.where(s >= _P, s - _P, s)
    return out


def sub(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b mod p``."""
    d = a - b
    out: np.ndarray = np.where(a < b, d - _EPS, d)
    return out


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a b mod p`` (128-bit product from 32-bit limbs, then the Goldilocks reduction)."""
    a0, a1 = a & _M32, a >> _S32
    b0, b1 = b & _M32, b >> _S32
    ll, lh, hl, hh = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = lh + hl
    c_mid = (mid < lh).astype(np.uint64)                 # worth 2^96
    lo = ll + (mid << _S32)
    c_lo = (lo < ll).astype(np.uint64)
    hi = hh + (mid >> _S32) + c_lo + (c_mid << _S32)
    h0, h1 = hi & _M32, hi >> _S32
    t0 = lo - h1
    t0 = np.where(lo < h1, t0 - _EPS, t0)
    t1 = h0 * _EPS
    r = t0 + t1
    r = np.where(r < t1, r + _EPS, r)
    out: np.ndarray = np.where(r >= _P, r - _P, r)
    return out


def ntt(a: np.ndarray, w: int) -> np.ndarray:
    """Evaluations at ``w^0, ..., w^(n-1)`` of the polynomials whose coefficients are the rows of ``a`` (uint64)."""
    n = a.shape[-1]
    if n == 1:
        return a
    w2 = w * w % P
    even, odd = ntt(a[..., 0::2], w2), ntt(a[..., 1::2], w2)
    tw = np.array([pow(w, k, P) for k in range(n // 2)], dtype=np.uint64)
    t = mul(odd, np.broadcast_to(tw, odd.shape))
    return np.concatenate([add(even, t), sub(even, t)], axis=-1)
