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
           "pole_residue_eval", "pole_residue_apply"]

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
        _COMPILED.update(numba=None, pole=None, pole_apply=None)
        return _COMPILED
    jit = numba.njit(**jit_options())

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
    _COMPILED.update(numba=numba, pole=jit(pole), pole_apply=jit(pole_apply))
    return _COMPILED


def compiled_available() -> bool:
    """Whether numba imports (the compiled kernels can be used).

    Returns
    -------
    bool
    """
    return _build()["numba"] is not None


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
