"""Per-bin 2x2 products and inverses of :mod:`~roadcollab.lti.batch2x2`, compiled (numba; the
``"compiled"`` path of :mod:`~roadcollab.lti.kernels`).

One pass over the bins with the 2x2 arithmetic in registers, where numpy makes six to eight passes
over strided views with a temporary each (``matvec`` on 3000 bins; docs/speed.md, "Third pass").
The same products and sums in the same order as the numpy path, so the results agree to round-off.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import compiled_available, jit_options, read_only

__all__ = ["matvec2", "inv2"]

_KERNEL: dict[str, Any] = {}
_COMPILED_NAMES = ("_matvec", "_inv")


def _build() -> dict[str, Any]:
    """The compiled functions (``None`` values without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(matvec=None, inv=None)
        return _KERNEL
    import numba

    jit = numba.njit(**jit_options())
    for name in _COMPILED_NAMES:
        globals()[name] = jit(globals()[name])
    _KERNEL.update(matvec=globals()["_matvec"], inv=globals()["_inv"])
    return _KERNEL


def _matvec(M: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover - compiled
    for k in range(M.shape[0]):
        x0, x1 = x[k, 0], x[k, 1]
        out[k, 0] = M[k, 0, 0] * x0 + M[k, 0, 1] * x1
        out[k, 1] = M[k, 1, 0] * x0 + M[k, 1, 1] * x1


def _inv(M: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover - compiled
    for k in range(M.shape[0]):
        a, b, c, d = M[k, 0, 0], M[k, 0, 1], M[k, 1, 0], M[k, 1, 1]
        det = a * d - b * c
        s = 1.0 / (det.real * det.real + det.imag * det.imag)       # 1 / det in real arithmetic
        r = complex(det.real * s, -det.imag * s)
        out[k, 0, 0] = d * r
        out[k, 0, 1] = b * -r
        out[k, 1, 0] = c * -r
        out[k, 1, 1] = a * r


def matvec2(M: np.ndarray, x: np.ndarray) -> np.ndarray | None:
    """``M[k] @ x[k]`` for complex ``M`` (K, 2, 2) and ``x`` (K, 2), compiled; None if the compiled
    kernel does not apply (other dtypes or shapes, or no numba).

    Parameters
    ----------
    M : (K, 2, 2) ndarray
    x : (K, 2) ndarray

    Returns
    -------
    (K, 2) complex ndarray or None
    """
    if M.dtype != np.complex128 or x.dtype != np.complex128 or M.ndim != 3 or x.shape != M.shape[:2]:
        return None
    k = _build()["matvec"]
    if k is None:
        return None
    out = np.empty(x.shape, np.complex128)
    k(read_only(np.ascontiguousarray(M)), np.ascontiguousarray(x), out)     # one specialisation to compile
    return out


def inv2(M: np.ndarray) -> np.ndarray | None:
    """Inverses of a complex (K, 2, 2) stack by the adjugate over the determinant, compiled; None if
    the compiled kernel does not apply.

    Parameters
    ----------
    M : (K, 2, 2) ndarray

    Returns
    -------
    (K, 2, 2) complex ndarray or None
    """
    if M.dtype != np.complex128 or M.ndim != 3:
        return None
    k = _build()["inv"]
    if k is None:
        return None
    out = np.empty(M.shape, np.complex128)
    k(read_only(np.ascontiguousarray(M)), out)
    return out
