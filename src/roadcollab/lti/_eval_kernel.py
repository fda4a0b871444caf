"""The compiled evaluation of a block-diagonalised Schur form over many bins (the ``"compiled"`` path of
:func:`~roadcollab.lti.blockdiag.block_response`).

``H(z) = D + sum_b Cw_b (z I - R_b)^-1 Bw_b`` over the diagonal blocks ``R_b`` of
:func:`~roadcollab.lti.blockdiag.block_schur`, ``TILE`` bins at a time with real and imaginary parts
apart. Blocks of one and two eigenvalues go through their resolvent entries, blocks of four (of a
system with two outputs) through a back substitution unrolled per bin, larger ones through a back
substitution one operation at a time over the tile. On the obfuscated ``T~``, ``S~`` of the bench
(20 systems), the unrolled four-blocks took the evaluation from 86-94 to 75-77 us per system, the
same output bit for bit (docs/speed.md, "Tenth pass").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .kernels import TILE, compiled_available, complex_parts, jit_options, read_only

__all__ = ["block_eval"]

_KERNEL: dict[str, Any] = {}

#: The functions compiled by :func:`_build` (rebound in place, so the compiled ``_block`` calls the compiled ``_four``).
_COMPILED_NAMES = ("_four", "_block")
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("_four",)


def _build() -> dict[str, Any]:
    """The compiled evaluation (``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(block=None)
        return _KERNEL
    import numba

    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(block=globals()["_block"])
    return _KERNEL


def _four(R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, i0: int, m: int, L: int, gr: np.ndarray,  # pragma: no cover
          gi: np.ndarray, ar: np.ndarray, ai: np.ndarray) -> None:                                # - compiled
    # Long: the four states unrolled, so that the bin loop is straight-line code LLVM vectorises.
    # A 4-state block of a system with two outputs: the general case's back substitution
    # (z I - R_b) X = Bw_b and its products with Cw_b, per bin in registers instead of one pass over the
    # tile's bins per operation; the same operations in the same order, so the same bits (tested).
    # Clusters of four are the second most common block of an obfuscated T~, S~ (Psi's poles come twice).
    i1, i2, i3 = i0 + 1, i0 + 2, i0 + 3
    r01r, r01i = R[i0, i1].real, R[i0, i1].imag
    r02r, r02i = R[i0, i2].real, R[i0, i2].imag
    r03r, r03i = R[i0, i3].real, R[i0, i3].imag
    r12r, r12i = R[i1, i2].real, R[i1, i2].imag
    r13r, r13i = R[i1, i3].real, R[i1, i3].imag
    r23r, r23i = R[i2, i3].real, R[i2, i3].imag
    c00r, c00i, c01r, c01i = Cw[0, i0].real, Cw[0, i0].imag, Cw[0, i1].real, Cw[0, i1].imag
    c02r, c02i, c03r, c03i = Cw[0, i2].real, Cw[0, i2].imag, Cw[0, i3].real, Cw[0, i3].imag
    c10r, c10i, c11r, c11i = Cw[1, i0].real, Cw[1, i0].imag, Cw[1, i1].real, Cw[1, i1].imag
    c12r, c12i, c13r, c13i = Cw[1, i2].real, Cw[1, i2].imag, Cw[1, i3].real, Cw[1, i3].imag
    g0r, g0i, g1r, g1i = gr[i0], gi[i0], gr[i1], gi[i1]
    g2r, g2i, g3r, g3i = gr[i2], gi[i2], gr[i3], gi[i3]
    for r in range(m):
        b0r, b0i, b1r, b1i = Bw[i0, r].real, Bw[i0, r].imag, Bw[i1, r].real, Bw[i1, r].imag
        b2r, b2i, b3r, b3i = Bw[i2, r].real, Bw[i2, r].imag, Bw[i3, r].real, Bw[i3, r].imag
        a0r, a0i, a1r, a1i = ar[r], ai[r], ar[m + r], ai[m + r]
        for k in range(L):
            x3r = b3r * g3r[k] - b3i * g3i[k]
            x3i = b3r * g3i[k] + b3i * g3r[k]
            yr = b2r + (r23r * x3r - r23i * x3i)
            yi = b2i + (r23r * x3i + r23i * x3r)
            x2r = yr * g2r[k] - yi * g2i[k]
            x2i = yr * g2i[k] + yi * g2r[k]
            yr = b1r + (r12r * x2r - r12i * x2i)
            yi = b1i + (r12r * x2i + r12i * x2r)
            yr2 = yr + (r13r * x3r - r13i * x3i)
            yi2 = yi + (r13r * x3i + r13i * x3r)
            x1r = yr2 * g1r[k] - yi2 * g1i[k]
            x1i = yr2 * g1i[k] + yi2 * g1r[k]
            yr = b0r + (r01r * x1r - r01i * x1i)
            yi = b0i + (r01r * x1i + r01i * x1r)
            yr2 = yr + (r02r * x2r - r02i * x2i)
            yi2 = yi + (r02r * x2i + r02i * x2r)
            yr = yr2 + (r03r * x3r - r03i * x3i)
            yi = yi2 + (r03r * x3i + r03i * x3r)
            x0r = yr * g0r[k] - yi * g0i[k]
            x0i = yr * g0i[k] + yi * g0r[k]
            sr = a0r[k] + (c00r * x0r - c00i * x0i)
            si = a0i[k] + (c00r * x0i + c00i * x0r)
            sr = sr + (c01r * x1r - c01i * x1i)
            si = si + (c01r * x1i + c01i * x1r)
            sr = sr + (c02r * x2r - c02i * x2i)
            si = si + (c02r * x2i + c02i * x2r)
            a0r[k] = sr + (c03r * x3r - c03i * x3i)
            a0i[k] = si + (c03r * x3i + c03i * x3r)
            sr = a1r[k] + (c10r * x0r - c10i * x0i)
            si = a1i[k] + (c10r * x0i + c10i * x0r)
            sr = sr + (c11r * x1r - c11i * x1i)
            si = si + (c11r * x1i + c11i * x1r)
            sr = sr + (c12r * x2r - c12i * x2i)
            si = si + (c12r * x2i + c12i * x2r)
            a1r[k] = sr + (c13r * x3r - c13i * x3i)
            a1i[k] = si + (c13r * x3i + c13i * x3r)


def _block(R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, D: np.ndarray, starts: np.ndarray,  # pragma: no cover
           stops: np.ndarray, zr: np.ndarray, zi: np.ndarray, out: np.ndarray) -> None:   # - compiled
    # Long: one tile of bins through every block in one compiled pass, its block cases inline.
    # H = D + sum_b Cw_b (z I - R_b)^-1 Bw_b, TILE bins at a time so every per-bin array stays in
    # the L1/L2 cache, real and imaginary parts in separate arrays (the bin loops are innermost
    # and contiguous, so LLVM vectorises them; over 1-D row views, 30 % faster than indexing the
    # 2-D arrays in the loop: 149-159 against 221-232 us for an order-18 system, same output). Blocks of one and two eigenvalues through their
    # resolvent entries (g_i = 1 / (z - R_ii); N_01 = g_0 R_01 g_1), as the numpy path does; larger
    # ones by back substitution, (z I - R_b) X_b = Bw_b. Reciprocals in real arithmetic.
    M = zr.shape[0]
    p, m = D.shape
    n = R.shape[0]
    pm = p * m
    nb = starts.shape[0]
    big = 1
    for b in range(nb):
        big = max(big, stops[b] - starts[b])
    gr = np.empty((n, TILE))
    gi = np.empty((n, TILE))
    ar = np.empty((pm, TILE))
    ai = np.empty((pm, TILE))
    hr = np.empty(TILE)
    hi = np.empty(TILE)
    xr = np.empty((big, m, TILE))
    xi = np.empty((big, m, TILE))
    for t0 in range(0, M, TILE):
        L = min(TILE, M - t0)
        zrt = zr[t0:t0 + L]
        zit = zi[t0:t0 + L]
        for i in range(n):
            lr, li = R[i, i].real, R[i, i].imag
            gri = gr[i]
            gii = gi[i]
            for k in range(L):
                dr = zrt[k] - lr
                di = zit[k] - li
                s = 1.0 / (dr * dr + di * di)
                gri[k] = dr * s
                gii[k] = -di * s
        for c in range(pm):
            d = D[c // m, c % m]
            for k in range(L):
                ar[c, k] = d
                ai[c, k] = 0.0
        for b in range(nb):
            i0, i1 = starts[b], stops[b]
            sz = i1 - i0
            if sz == 1:
                for c in range(pm):
                    res = Cw[c // m, i0] * Bw[i0, c % m]
                    rr, ri = res.real, res.imag
                    arc = ar[c]
                    aic = ai[c]
                    g0 = gr[i0]
                    g1 = gi[i0]
                    for k in range(L):
                        arc[k] += rr * g0[k] - ri * g1[k]
                        aic[k] += rr * g1[k] + ri * g0[k]
            elif sz == 2:
                i, l = i0, i0 + 1
                gri, gii, grl, gil = gr[i], gi[i], gr[l], gi[l]
                for k in range(L):
                    hr[k] = gri[k] * grl[k] - gii[k] * gil[k]
                    hi[k] = gri[k] * gil[k] + gii[k] * grl[k]
                rho = R[i, l]
                for c in range(pm):
                    q, r = c // m, c % m
                    r0 = Cw[q, i] * Bw[i, r]
                    r1 = Cw[q, l] * Bw[l, r]
                    r2 = Cw[q, i] * rho * Bw[l, r]
                    a0, b0, a1, b1, a2, b2 = r0.real, r0.imag, r1.real, r1.imag, r2.real, r2.imag
                    arc = ar[c]
                    aic = ai[c]
                    for k in range(L):
                        arc[k] += (a0 * gri[k] - b0 * gii[k]) + (a1 * grl[k] - b1 * gil[k]) + (a2 * hr[k] - b2 * hi[k])
                        aic[k] += (a0 * gii[k] + b0 * gri[k]) + (a1 * gil[k] + b1 * grl[k]) + (a2 * hi[k] + b2 * hr[k])
            elif sz == 4 and p == 2:
                _four(R, Bw, Cw, i0, m, L, gr, gi, ar, ai)
            else:
                for ii in range(sz - 1, -1, -1):
                    i = i0 + ii
                    for r in range(m):
                        br, bi = Bw[i, r].real, Bw[i, r].imag
                        for k in range(L):
                            xr[ii, r, k] = br
                            xi[ii, r, k] = bi
                        for jj in range(ii + 1, sz):
                            rr, ri = R[i, i0 + jj].real, R[i, i0 + jj].imag
                            for k in range(L):
                                xr[ii, r, k] += rr * xr[jj, r, k] - ri * xi[jj, r, k]
                                xi[ii, r, k] += rr * xi[jj, r, k] + ri * xr[jj, r, k]
                        for k in range(L):
                            a, bb = xr[ii, r, k], xi[ii, r, k]
                            xr[ii, r, k] = a * gr[i, k] - bb * gi[i, k]
                            xi[ii, r, k] = a * gi[i, k] + bb * gr[i, k]
                for c in range(pm):
                    q, r = c // m, c % m
                    for ii in range(sz):
                        cr, ci = Cw[q, i0 + ii].real, Cw[q, i0 + ii].imag
                        for k in range(L):
                            ar[c, k] += cr * xr[ii, r, k] - ci * xi[ii, r, k]
                            ai[c, k] += cr * xi[ii, r, k] + ci * xr[ii, r, k]
        for k in range(L):
            for c in range(pm):
                out[t0 + k, c] = complex(ar[c, k], ai[c, k])


def block_eval(R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, D: np.ndarray, blocks: Sequence[tuple[int, int]],
               z: np.ndarray) -> np.ndarray:
    """``D + sum_b Cw_b (z I - R_b)^-1 Bw_b`` over the diagonal blocks of ``R``, compiled.

    Parameters
    ----------
    R : (n, n) complex ndarray
        Upper triangular within each block (entries between blocks are not read).
    Bw : (n, m) complex ndarray
    Cw : (p, n) complex ndarray
    D : (p, m) real ndarray
    blocks : list of (int, int)
        ``[start, stop)`` of each diagonal block.
    z : (M,) complex ndarray

    Returns
    -------
    (M, p, m) complex ndarray
    """
    k = _build()["block"]
    starts = np.array([b[0] for b in blocks], dtype=np.int64)
    stops = np.array([b[1] for b in blocks], dtype=np.int64)
    z = np.asarray(z, dtype=complex)
    out = np.empty((z.size, D.shape[0], D.shape[1]), complex)
    zr, zi = complex_parts(z)
    k(np.ascontiguousarray(R, complex), np.ascontiguousarray(Bw, complex), np.ascontiguousarray(Cw, complex),
      read_only(np.ascontiguousarray(D, float)), starts, stops, zr, zi, out.reshape(z.size, -1))
    return out
