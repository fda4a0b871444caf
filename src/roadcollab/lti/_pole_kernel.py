"""Compiled (numba) evaluation of pole-residue forms ``H(z) = D + sum_i Res_i / (z - lambda_i)`` over many
bins (the ``"compiled"`` path of :func:`~roadcollab.lti.response.ss_response` for a system with well
conditioned eigenvectors, and of an obfuscator ``Psi``'s responses and products from its design's poles
and residues), ``TILE`` bins at a time with real and imaginary parts apart.

Module-level functions compiled in place (:func:`_build`), so that numba's on-disk cache loads them in
every later process; as closures (before) they were compiled again by every process.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import TILE, compiled_available, complex_parts, jit_options, read_only

__all__ = ["pole_residue_eval", "pole_residue_apply"]

_KERNEL: dict[str, Any] = {}

#: The functions compiled by :func:`_build` (rebound in place, so compiled callers find compiled callees).
_COMPILED_NAMES = ("_pole_tile", "_pole", "_pole_apply")
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("_pole_tile",)


def _build() -> dict[str, Any]:
    """The compiled kernels (``None`` values without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(pole=None, pole_apply=None)
        return _KERNEL
    import numba

    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(pole=globals()["_pole"], pole_apply=globals()["_pole_apply"])
    return _KERNEL


def _pole_tile(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
               Di: np.ndarray, zrt: np.ndarray, zit: np.ndarray, gr: np.ndarray, gi: np.ndarray,    # - compiled
               ar: np.ndarray, ai: np.ndarray) -> None:
    # H = D + sum_i Res_i / (z - lambda_i) on one tile of bins, real and imaginary parts apart
    # (ar, ai: (p*m, TILE); the first len(zrt) columns are written).
    L = zrt.shape[0]
    n, pm = Rr.shape
    for c in range(pm):
        for k in range(L):
            ar[c, k] = Dr[c]
            ai[c, k] = Di[c]
    for i in range(n):
        lri, lii = lr[i], li[i]
        for k in range(L):
            dr = zrt[k] - lri
            di = zit[k] - lii
            s = 1.0 / (dr * dr + di * di)
            gr[k] = dr * s
            gi[k] = -di * s
        for c in range(pm):
            rr, ri = Rr[i, c], Ri[i, c]
            arc, aic = ar[c], ai[c]
            for k in range(L):
                arc[k] += rr * gr[k] - ri * gi[k]
                aic[k] += rr * gi[k] + ri * gr[k]


def _pole(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
          Di: np.ndarray, zr: np.ndarray, zi: np.ndarray, out: np.ndarray) -> None:   # - compiled
    # H = D + sum_i Res_i / (z - lambda_i), TILE bins at a time; Res (n, p*m), out (M, p*m) complex.
    M = zr.shape[0]
    pm = Rr.shape[1]
    gr, gi = np.empty(TILE), np.empty(TILE)
    ar, ai = np.empty((pm, TILE)), np.empty((pm, TILE))
    for t0 in range(0, M, TILE):
        L = min(TILE, M - t0)
        _pole_tile(lr, li, Rr, Ri, Dr, Di, zr[t0:t0 + L], zi[t0:t0 + L], gr, gi, ar, ai)
        for k in range(L):
            for c in range(pm):
                out[t0 + k, c] = complex(ar[c, k], ai[c, k])

def _pole_apply(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
                Di: np.ndarray, zr: np.ndarray, zi: np.ndarray, x: np.ndarray, inverse: bool,    # - compiled
                out: np.ndarray) -> None:
    # out_k = H_k x_k, or H_k^-1 x_k by the adjugate over the determinant, for a 2x2 H of pole-residue
    # form: the operations of `pole`, then _bin_kernel's `_inv` and `_matvec` per bin, without the
    # (M, 2, 2) response in memory. The per-bin complex operations are spelt out in real arithmetic, each
    # as numba computes it (a product (a + ib)(c + id) = (ac - bd) + i(ad + bc), a sum per part, -r both
    # parts negated), so the same bits; the inverse's loop over the tile then vectorises (docs/speed.md,
    # "Eleventh pass": 54 -> 31 us per inverse on every bin of the bench grid).
    M = zr.shape[0]
    gr, gi = np.empty(TILE), np.empty(TILE)
    ar, ai = np.empty((4, TILE)), np.empty((4, TILE))
    for t0 in range(0, M, TILE):
        L = min(TILE, M - t0)
        _pole_tile(lr, li, Rr, Ri, Dr, Di, zr[t0:t0 + L], zi[t0:t0 + L], gr, gi, ar, ai)
        a0r, a1r, a2r, a3r = ar[0], ar[1], ar[2], ar[3]
        a0i, a1i, a2i, a3i = ai[0], ai[1], ai[2], ai[3]
        if inverse:
            for k in range(L):
                # [[a, b], [c, d]] <- [[d, -b], [-c, a]] r, r = 1 / (a d - b c) as conj(det) / |det|^2
                pr, pi, qr, qi = a0r[k], a0i[k], a1r[k], a1i[k]
                ur, ui, vr, vi = a2r[k], a2i[k], a3r[k], a3i[k]
                dr = (pr * vr - pi * vi) - (qr * ur - qi * ui)
                di = (pr * vi + pi * vr) - (qr * ui + qi * ur)
                s = 1.0 / (dr * dr + di * di)
                rr, ri = dr * s, -di * s
                nr, ni = -rr, -ri
                a0r[k], a0i[k] = vr * rr - vi * ri, vr * ri + vi * rr
                a1r[k], a1i[k] = qr * nr - qi * ni, qr * ni + qi * nr
                a2r[k], a2i[k] = ur * nr - ui * ni, ur * ni + ui * nr
                a3r[k], a3i[k] = pr * rr - pi * ri, pr * ri + pi * rr
        for k in range(L):
            x0 = x[t0 + k, 0]
            x1 = x[t0 + k, 1]
            x0r, x0i, x1r, x1i = x0.real, x0.imag, x1.real, x1.imag
            out[t0 + k, 0] = complex((a0r[k] * x0r - a0i[k] * x0i) + (a1r[k] * x1r - a1i[k] * x1i),
                                     (a0r[k] * x0i + a0i[k] * x0r) + (a1r[k] * x1i + a1i[k] * x1r))
            out[t0 + k, 1] = complex((a2r[k] * x0r - a2i[k] * x0i) + (a3r[k] * x1r - a3i[k] * x1i),
                                     (a2r[k] * x0i + a2i[k] * x0r) + (a3r[k] * x1i + a3i[k] * x1r))


def pole_residue_eval(lam: np.ndarray, Res: np.ndarray, D: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``D + sum_i Res_i / (z - lambda_i)``, compiled.

    Parameters
    ----------
    lam : (n,) complex ndarray
        Poles.
    Res : (n, p * m) complex ndarray
        Residues, flattened per pole.
    D : (p, m) ndarray, real or complex
    z : (M,) complex ndarray

    Returns
    -------
    (M, p, m) complex ndarray
    """
    k = _build()["pole"]
    z = np.asarray(z, dtype=complex)
    out = np.empty((z.size,) + np.shape(D), complex)
    k(*_pole_arrays(lam, Res, D, z), out.reshape(z.size, -1))
    return out


def _pole_arrays(lam: np.ndarray, Res: np.ndarray, D: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, ...]:
    """The real and imaginary parts, contiguous, that the pole-residue kernels take."""
    lam = np.asarray(lam, dtype=complex)
    Res = np.asarray(Res, dtype=complex)
    Dc = np.asarray(D, dtype=complex)
    c = np.ascontiguousarray
    zr, zi = complex_parts(z)
    return (c(lam.real), c(lam.imag), c(Res.real), c(Res.imag), c(Dc.real).reshape(-1), c(Dc.imag).reshape(-1),
            zr, zi)


def pole_residue_apply(lam: np.ndarray, Res: np.ndarray, D: np.ndarray, z: np.ndarray, x: np.ndarray, *,
                       inverse: bool = False) -> np.ndarray:
    """``H(z_k) x_k`` (or ``H(z_k)^-1 x_k``) per point for the 2x2 ``H = D + sum_i Res_i / (z - lambda_i)``,
    compiled, without forming the responses: equal, bit for bit, to :func:`pole_residue_eval` followed by
    :func:`~roadcollab.lti.batch2x2.inv2x2` (when ``inverse``) and :func:`~roadcollab.lti.batch2x2.matvec`
    on the compiled path (tested).

    Parameters
    ----------
    lam : (n,) complex ndarray
        Poles.
    Res : (n, 4) complex ndarray
        Residues, flattened per pole (row-major 2x2).
    D : (2, 2) ndarray, real or complex
    z : (M,) complex ndarray
    x : (M, 2) complex ndarray
    inverse : bool
        Apply ``H^-1`` (adjugate over the determinant, no check of a singular bin: inf/NaN propagate).

    Returns
    -------
    (M, 2) complex ndarray
    """
    k = _build()["pole_apply"]
    z = np.asarray(z, dtype=complex)
    x = np.ascontiguousarray(x, dtype=complex)
    if np.shape(D) != (2, 2) or x.shape != (z.size, 2):
        raise ValueError(f"expected a 2x2 D and x of shape ({z.size}, 2), got {np.shape(D)} and {x.shape}")
    out = np.empty((z.size, 2), complex)
    k(*_pole_arrays(lam, Res, D, z), read_only(x), bool(inverse), out)
    return out
