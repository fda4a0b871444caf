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

__all__ = ["matvec2", "inv2", "receiver_z2", "diff_norms2"]

_KERNEL: dict[str, Any] = {}
_COMPILED_NAMES = ("_matvec", "_inv", "_receiver_z", "_diff_norms")


def _build() -> dict[str, Any]:
    """The compiled functions (``None`` values without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(matvec=None, inv=None, receiver_z=None, diff_norms=None)
        return _KERNEL
    import numba

    jit = numba.njit(**jit_options())
    for name in _COMPILED_NAMES:
        globals()[name] = jit(globals()[name])
    _KERNEL.update(matvec=globals()["_matvec"], inv=globals()["_inv"], receiver_z=globals()["_receiver_z"],
                   diff_norms=globals()["_diff_norms"])
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


def _diff_norms(x: np.ndarray, ref: np.ndarray, num: np.ndarray, den: np.ndarray) -> None:  # pragma: no cover
    # num_k = ||x_k - ref_k||, den_k = ||ref_k|| in the order of np.linalg.norm(axis=1) on a complex (K, 2):
    # |v|^2 per entry, the two summed, the square root. numpy's complex product may fuse a multiply and an
    # add (this CPU's does), this loop does not: equal to one unit in the last place.       - compiled
    for k in range(num.shape[0]):
        r0, r1 = ref[k, 0], ref[k, 1]
        d0, d1 = x[k, 0] - r0, x[k, 1] - r1
        num[k] = np.sqrt((d0.real * d0.real + d0.imag * d0.imag) + (d1.real * d1.real + d1.imag * d1.imag))
        den[k] = np.sqrt((r0.real * r0.real + r0.imag * r0.imag) + (r1.real * r1.real + r1.imag * r1.imag))


def _receiver_z(T: np.ndarray, S: np.ndarray, E: np.ndarray, Wf: np.ndarray, w: np.ndarray,
                out: np.ndarray) -> None:   # pragma: no cover - compiled
    # z = w T^-1 (E - S Wf) per bin, T^-1 = adj(T) / det(T), with w folded into 1 / |det|^2: real
    # arithmetic on the interleaved parts (the complex-typed loop ran at half this speed, measured).
    Tf, Sf = T.reshape(-1).view(np.float64), S.reshape(-1).view(np.float64)
    Ef, Wff, of = E.reshape(-1).view(np.float64), Wf.reshape(-1).view(np.float64), out.reshape(-1).view(np.float64)
    for k in range(w.shape[0]):
        t = 8 * k
        v = 4 * k
        x0r, x0i, x1r, x1i = Wff[v], Wff[v + 1], Wff[v + 2], Wff[v + 3]
        d0r = Ef[v] - (Sf[t] * x0r - Sf[t + 1] * x0i + Sf[t + 2] * x1r - Sf[t + 3] * x1i)
        d0i = Ef[v + 1] - (Sf[t] * x0i + Sf[t + 1] * x0r + Sf[t + 2] * x1i + Sf[t + 3] * x1r)
        d1r = Ef[v + 2] - (Sf[t + 4] * x0r - Sf[t + 5] * x0i + Sf[t + 6] * x1r - Sf[t + 7] * x1i)
        d1i = Ef[v + 3] - (Sf[t + 4] * x0i + Sf[t + 5] * x0r + Sf[t + 6] * x1i + Sf[t + 7] * x1r)
        ar, ai, br, bi = Tf[t], Tf[t + 1], Tf[t + 2], Tf[t + 3]
        cr, ci, dr, di = Tf[t + 4], Tf[t + 5], Tf[t + 6], Tf[t + 7]
        detr = (ar * dr - ai * di) - (br * cr - bi * ci)
        deti = (ar * di + ai * dr) - (br * ci + bi * cr)
        s = w[k] / (detr * detr + deti * deti)
        rr, ri = detr * s, -deti * s                          # w / det
        u0r = dr * d0r - di * d0i - (br * d1r - bi * d1i)     # adj(T) (E - S Wf)
        u0i = dr * d0i + di * d0r - (br * d1i + bi * d1r)
        u1r = ar * d1r - ai * d1i - (cr * d0r - ci * d0i)
        u1i = ar * d1i + ai * d1r - (cr * d0i + ci * d0r)
        of[v], of[v + 1] = u0r * rr - u0i * ri, u0r * ri + u0i * rr
        of[v + 2], of[v + 3] = u1r * rr - u1i * ri, u1r * ri + u1i * rr


def receiver_z2(T: np.ndarray, S: np.ndarray, E: np.ndarray, Wf: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """``w T^-1 (E - S W^f)`` per bin for complex (K, 2, 2) ``T``, ``S``, (K, 2) ``E``, ``W^f`` and real
    (K,) ``w`` in one compiled pass: the per-step path of :func:`~roadcollab.lti.batch2x2.receiver_z` to
    round-off (22 against 43-46 us on 2974 bins, measured); None if the kernel does not apply.

    Parameters
    ----------
    T, S : (K, 2, 2) complex ndarray
    E, Wf : (K, 2) complex ndarray
    w : (K,) float ndarray

    Returns
    -------
    (K, 2) complex ndarray or None
    """
    K = T.shape[0] if T.ndim == 3 else -1
    if (T.dtype != np.complex128 or S.dtype != np.complex128 or E.dtype != np.complex128 or Wf.dtype != np.complex128
            or T.shape != (K, 2, 2) or S.shape != T.shape or E.shape != (K, 2) or Wf.shape != E.shape
            or w.dtype != np.float64 or w.shape != (K,)):
        return None
    k = _build()["receiver_z"]
    if k is None:
        return None
    out = np.empty((K, 2), np.complex128)
    c = np.ascontiguousarray
    k(read_only(c(T)), read_only(c(S)), read_only(c(E)), read_only(c(Wf)), read_only(c(w)), out)
    return out


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


def diff_norms2(x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-bin 2-norms ``||x_k - ref_k||`` and ``||ref_k||`` of complex (K, 2) arrays in one compiled pass,
    ``np.linalg.norm(x - ref, axis=1)`` and ``np.linalg.norm(ref, axis=1)`` to one unit in the last place;
    None if the compiled kernel does not apply (other dtypes or shapes, or no numba).

    Parameters
    ----------
    x, ref : (K, 2) complex ndarray

    Returns
    -------
    (num, den) : two (K,) float ndarrays, or None
    """
    if x.dtype != np.complex128 or ref.dtype != np.complex128 or x.ndim != 2 or x.shape != ref.shape or x.shape[1] != 2:
        return None
    k = _build()["diff_norms"]
    if k is None:
        return None
    num, den = np.empty(x.shape[0]), np.empty(x.shape[0])
    k(read_only(np.ascontiguousarray(x)), read_only(np.ascontiguousarray(ref)), num, den)
    return num, den
