"""Compiled (numba) kernels for the per-segment frequency responses, and the choice between them
and the numpy reference path.

Two paths compute the same quantities:

- ``"reference"``: numpy/scipy only (:func:`~roadcollab.lti.blockdiag.block_response`, the
  pole-residue product of :func:`~roadcollab.lti.response.ss_response`, the ``Psi`` draw's loop in
  :func:`~roadcollab.privacy.obfuscator_design.draw_obfuscator`);
- ``"compiled"``: the same evaluations as loops compiled by numba, tiles of bins with real and
  imaginary parts apart, the ``Psi`` draw's rejection loop and realisation
  (:mod:`roadcollab.privacy._draw_kernel`, from the same random generator, leaving the same state) and
  ``Psi``'s responses from its poles and residues, a receiver's complex Schur form (real Schur form and
  compiled rotations) and the triangular Stein solve of its Lyapunov certificate
  (:mod:`roadcollab.lti._cert_kernel`), and the per-bin 2x2 products and inverses
  (:mod:`roadcollab.lti._bin_kernel`). They differ from the reference by round-off only (the Schur form
  is another valid one; the certificate's residual is checked either way).

The block diagonalisation of a received system (reordering, Sylvester splits, eigenvalue clustering:
:mod:`roadcollab.lti._blockdiag_kernel`), ``Psi``'s pole residues and the hiding similarity of ``T~``, ``S~``
(:mod:`roadcollab.lti._hide_kernel`) are compiled too.

The library's default is ``"reference"`` (numpy). The compiled path passes the 300-segment exactness test and
makes ``paper`` about 3x faster per segment than the reference path (2.96-3.03x in the bench's alternating
line), but every process that uses it pays numba's start-up (import, cache load) and about 145 MiB, and a
fresh installation compiles for about 7 s of wall time when the command line compiles the sender's kernels
in a second process (docs/speed.md, "Ninth pass"). So the commands that run Algorithm 2 many times
(``roadcollab reproduce``, ``attack``, ``sweep``, ``bench``) use it unless told otherwise (``--kernels``),
and a vehicle process or a library call keeps the numpy path. The
environment variable ``ROADCOLLAB_KERNELS=compiled`` (or ``reference``) sets the default of both, and
:func:`use_kernels` selects a path for a block of code (``roadcollab bench --kernels``).

numba is compiled with ``error_model="numpy"``: its default ``"python"`` model checks every float
division for zero (to raise ``ZeroDivisionError``) and that branch blocks vectorisation (measured
3.9x slower on the same loop). ``cache=True`` keeps the machine code on disk, beside this module in
``__pycache__`` (or under ``NUMBA_CACHE_DIR`` when set), so only the first run after installation
compiles.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = ["KERNELS", "kernel_path", "environment_kernels", "use_kernels", "compiled_available", "jit_options", "read_only",
           "block_eval", "pole_residue_eval", "pole_residue_apply"]

KERNELS = ("compiled", "reference")

_CHOICE: contextvars.ContextVar[str | None] = contextvars.ContextVar("roadcollab_kernels", default=None)
#: Bins per pass of the block kernel: its per-bin arrays (2 x (n + 4 + 2 k_max m) x TILE doubles) stay in cache.
TILE = 256
#: The compiled functions once built (``{}`` before the first use; ``None`` values if numba is missing).
_COMPILED: dict[str, Any] = {}


def jit_options() -> dict[str, Any]:
    """The options every compiled kernel of the package is built with (``numba.njit(**jit_options())``).

    Returns
    -------
    dict
        ``cache=True`` (machine code kept on disk), ``error_model="numpy"`` (no zero-division branch
        in float divisions, module docstring), ``nogil=True``.
    """
    return {"cache": True, "error_model": "numpy", "nogil": True}


def read_only(x: np.ndarray) -> np.ndarray:
    """``x`` itself if it is read-only, else a read-only view of it (no copy).

    numba compiles one specialisation per argument type, and a read-only array is another type than a
    writable one. The checked messages' arrays are read-only and a vehicle's own are not, so a kernel fed
    both compiled twice (about 5.5 s of a fresh installation's first run, docs/speed.md, "Seventh pass").
    Its wrappers pass arrays the kernel only reads through this.

    Parameters
    ----------
    x : ndarray

    Returns
    -------
    ndarray
        The same data, ``flags.writeable`` False.
    """
    if x.flags.writeable:
        x = x.view()
        x.flags.writeable = False
    return x


def _build() -> dict[str, Any]:   # Long: the kernels are defined here so that numba is imported on first use only
    """Import numba and define the kernels (lazily: importing numba costs about 0.3 s)."""
    if _COMPILED:
        return _COMPILED
    try:
        import numba
    except ImportError:
        _COMPILED.update(block=None, pole=None, pole_apply=None)
        return _COMPILED
    jit = numba.njit(**jit_options())

    def block(R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, D: np.ndarray, starts: np.ndarray,  # pragma: no cover
              stops: np.ndarray, zr: np.ndarray, zi: np.ndarray, out: np.ndarray) -> None:   # - compiled
        # Long: one tile of bins through every block in one compiled pass, its three block cases inline.
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


    def pole_tile(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
                  Di: np.ndarray, zrt: np.ndarray, zit: np.ndarray, gr: np.ndarray, gi: np.ndarray,     # - compiled
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

    pole_tile = jit(pole_tile)

    def pole(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
             Di: np.ndarray, zr: np.ndarray, zi: np.ndarray, out: np.ndarray) -> None:   # - compiled
        # H = D + sum_i Res_i / (z - lambda_i), TILE bins at a time; Res (n, p*m), out (M, p*m) complex.
        M = zr.shape[0]
        pm = Rr.shape[1]
        gr, gi = np.empty(TILE), np.empty(TILE)
        ar, ai = np.empty((pm, TILE)), np.empty((pm, TILE))
        for t0 in range(0, M, TILE):
            L = min(TILE, M - t0)
            pole_tile(lr, li, Rr, Ri, Dr, Di, zr[t0:t0 + L], zi[t0:t0 + L], gr, gi, ar, ai)
            for k in range(L):
                for c in range(pm):
                    out[t0 + k, c] = complex(ar[c, k], ai[c, k])

    def pole_apply(lr: np.ndarray, li: np.ndarray, Rr: np.ndarray, Ri: np.ndarray, Dr: np.ndarray,  # pragma: no cover
                   Di: np.ndarray, zr: np.ndarray, zi: np.ndarray, x: np.ndarray, inverse: bool,     # - compiled
                   out: np.ndarray) -> None:
        # out_k = H_k x_k, or H_k^-1 x_k by the adjugate over the determinant, for a 2x2 H of pole-residue
        # form: the operations of `pole`, then _bin_kernel's `_inv` and `_matvec` per bin, without the
        # (M, 2, 2) response in memory.
        M = zr.shape[0]
        gr, gi = np.empty(TILE), np.empty(TILE)
        ar, ai = np.empty((4, TILE)), np.empty((4, TILE))
        for t0 in range(0, M, TILE):
            L = min(TILE, M - t0)
            pole_tile(lr, li, Rr, Ri, Dr, Di, zr[t0:t0 + L], zi[t0:t0 + L], gr, gi, ar, ai)
            for k in range(L):
                a, b = complex(ar[0, k], ai[0, k]), complex(ar[1, k], ai[1, k])
                c, d = complex(ar[2, k], ai[2, k]), complex(ar[3, k], ai[3, k])
                if inverse:
                    det = a * d - b * c
                    s = 1.0 / (det.real * det.real + det.imag * det.imag)
                    r = complex(det.real * s, -det.imag * s)
                    a, b, c, d = d * r, b * -r, c * -r, a * r
                x0, x1 = x[t0 + k, 0], x[t0 + k, 1]
                out[t0 + k, 0] = a * x0 + b * x1
                out[t0 + k, 1] = c * x0 + d * x1

    # Compiled by calling numba's decorator (an untyped one to mypy), as in the package's other kernel modules.
    _COMPILED.update(block=jit(block), pole=jit(pole), pole_apply=jit(pole_apply))
    return _COMPILED


def compiled_available() -> bool:
    """Whether numba imports (the compiled kernels can be used).

    Returns
    -------
    bool
    """
    return _build()["block"] is not None


def kernel_path() -> str:
    """The path in effect: :func:`use_kernels`' choice, else ``ROADCOLLAB_KERNELS``, else ``"reference"``;
    always ``"reference"`` when numba does not import.

    Returns
    -------
    {"compiled", "reference"}

    Raises
    ------
    ParameterError
        If ``ROADCOLLAB_KERNELS`` is set to anything else.
    """
    choice = _CHOICE.get() or environment_kernels() or "reference"
    return "compiled" if choice == "compiled" and compiled_available() else "reference"


def environment_kernels() -> str | None:
    """The path ``ROADCOLLAB_KERNELS`` asks for, or None when it is unset or empty.

    Returns
    -------
    {"compiled", "reference"} or None

    Raises
    ------
    ParameterError
        If ``ROADCOLLAB_KERNELS`` is set to anything else.
    """
    choice = os.environ.get("ROADCOLLAB_KERNELS") or None
    if choice is not None and choice not in KERNELS:
        raise ParameterError(f"environment variable ROADCOLLAB_KERNELS must be 'compiled' or 'reference', "
                             f"got {choice!r}")
    return choice


@contextlib.contextmanager
def use_kernels(name: str) -> Iterator[None]:
    """Evaluate with the ``"compiled"`` or ``"reference"`` kernels inside a ``with`` block.

    Parameters
    ----------
    name : {"compiled", "reference"}
        ``"compiled"`` falls back to the reference path when numba is not importable.

    Raises
    ------
    ParameterError
        For another name.
    """
    if name not in KERNELS:
        raise ParameterError(f"kernels must be one of {KERNELS}, got {name!r}")
    token = _CHOICE.set(name)
    try:
        yield
    finally:
        _CHOICE.reset(token)


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
    k(np.ascontiguousarray(R, complex), np.ascontiguousarray(Bw, complex), np.ascontiguousarray(Cw, complex),
      read_only(np.ascontiguousarray(D, float)), starts, stops, np.ascontiguousarray(z.real), np.ascontiguousarray(z.imag), out.reshape(z.size, -1))
    return out


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
    return (c(lam.real), c(lam.imag), c(Res.real), c(Res.imag), c(Dc.real).reshape(-1), c(Dc.imag).reshape(-1),
            c(z.real), c(z.imag))


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
