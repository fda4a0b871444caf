"""Compiled (numba) kernels for the per-segment frequency responses, and the choice between them
and the numpy reference path.

Two paths compute the same quantities:

- ``"reference"``: numpy/scipy only (:func:`~roadcollab.lti.blockdiag.block_response` and the
  pole-residue product of :func:`~roadcollab.lti.response.ss_response`);
- ``"compiled"``: the same evaluations as loops compiled by numba, one pass over the bins with the
  per-bin work in registers. They differ from the reference by round-off only (a different
  summation order; tested to 1e-12 relative per bin).

The default is ``"reference"`` (numpy): measured, the compiled path made ``paper`` only 1.02-1.3x faster per
segment (median, docs/speed.md) while importing numba and loading its cache added 0.4-0.9 s to every process
that evaluates a response (a vehicle, a short command), so it is opt-in until it pays for itself. The
environment variable ``ROADCOLLAB_KERNELS=compiled`` (or ``reference``) sets the default, and
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

import numpy as np

from ..errors import ParameterError

__all__ = ["KERNELS", "kernel_path", "use_kernels", "compiled_available", "jit_options", "block_eval",
           "pole_residue_eval"]

KERNELS = ("compiled", "reference")

_CHOICE: contextvars.ContextVar[str | None] = contextvars.ContextVar("roadcollab_kernels", default=None)
#: The compiled functions once built (``{}`` before the first use; ``None`` values if numba is missing).
_COMPILED: dict = {}


def jit_options() -> dict:
    """The options every compiled kernel of the package is built with (``numba.njit(**jit_options())``).

    Returns
    -------
    dict
        ``cache=True`` (machine code kept on disk), ``error_model="numpy"`` (no zero-division branch
        in float divisions, module docstring), ``nogil=True``.
    """
    return {"cache": True, "error_model": "numpy", "nogil": True}


def _build() -> dict:
    """Import numba and define the kernels (lazily: importing numba costs about 0.3 s)."""
    if _COMPILED:
        return _COMPILED
    try:
        import numba
    except ImportError:
        _COMPILED.update(block=None, pole=None)
        return _COMPILED
    jit = numba.njit(**jit_options())

    @jit
    def block(R, Bw, Cw, D, starts, stops, z, out):   # pragma: no cover - compiled
        # (z I - R_b) X_b = Bw_b by back substitution per diagonal block (R_b upper triangular), then
        # H = D + sum_b Cw_b X_b; every step a loop over the bins (innermost and contiguous, so
        # LLVM vectorises it). Reciprocals in real arithmetic: 1/d = conj(d) / |d|^2.
        M = z.shape[0]
        p, m = D.shape
        n = R.shape[0]
        X = np.empty((n, m, M), np.complex128)
        g = np.empty(M, np.complex128)
        for q in range(p):
            for r in range(m):
                for k in range(M):
                    out[q, r, k] = D[q, r]
        for b in range(starts.shape[0]):
            i0, i1 = starts[b], stops[b]
            for i in range(i1 - 1, i0 - 1, -1):
                lr, li = R[i, i].real, R[i, i].imag
                for k in range(M):
                    dr = z[k].real - lr
                    di = z[k].imag - li
                    s = 1.0 / (dr * dr + di * di)
                    g[k] = complex(dr * s, -di * s)
                for r in range(m):
                    bir = Bw[i, r]
                    for k in range(M):
                        X[i, r, k] = bir
                    for j in range(i + 1, i1):
                        rij = R[i, j]
                        for k in range(M):
                            X[i, r, k] += rij * X[j, r, k]
                    for k in range(M):
                        X[i, r, k] *= g[k]
            for q in range(p):
                for r in range(m):
                    for i in range(i0, i1):
                        c = Cw[q, i]
                        for k in range(M):
                            out[q, r, k] += c * X[i, r, k]

    @jit
    def pole(lam, Res, D, z, out):   # pragma: no cover - compiled
        # H = D + sum_i Res_i / (z - lambda_i); Res (n, p*m), out (p*m, M).
        M = z.shape[0]
        n, pm = Res.shape
        g = np.empty(M, np.complex128)
        for c in range(pm):
            for k in range(M):
                out[c, k] = D[c]
        for i in range(n):
            lr, li = lam[i].real, lam[i].imag
            for k in range(M):
                dr = z[k].real - lr
                di = z[k].imag - li
                s = 1.0 / (dr * dr + di * di)
                g[k] = complex(dr * s, -di * s)
            for c in range(pm):
                rc = Res[i, c]
                for k in range(M):
                    out[c, k] += g[k] * rc

    _COMPILED.update(block=block, pole=pole)
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
    choice = _CHOICE.get() or os.environ.get("ROADCOLLAB_KERNELS") or "reference"
    if choice not in KERNELS:
        raise ParameterError(f"environment variable ROADCOLLAB_KERNELS must be 'compiled' or 'reference', "
                             f"got {choice!r}")
    return "compiled" if choice == "compiled" and compiled_available() else "reference"


@contextlib.contextmanager
def use_kernels(name: str):
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


def block_eval(R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, D: np.ndarray, blocks, z: np.ndarray) -> np.ndarray:
    """``D + sum_b Cw_b (z I - R_b)^-1 Bw_b`` over the diagonal blocks of ``R``, compiled.

    Parameters
    ----------
    R : (n, n) complex ndarray
        Upper triangular within each block (entries between blocks are not read).
    Bw : (n, m) complex ndarray
    Cw : (p, n) complex ndarray
    D : (p, m) ndarray
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
    out = np.empty((D.shape[0], D.shape[1], z.size), complex)
    k(np.ascontiguousarray(R, complex), np.ascontiguousarray(Bw, complex), np.ascontiguousarray(Cw, complex),
      np.ascontiguousarray(D, complex), starts, stops, np.ascontiguousarray(z, complex), out)
    return out.transpose(2, 0, 1).copy()


def pole_residue_eval(lam: np.ndarray, Res: np.ndarray, D: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``D + sum_i Res_i / (z - lambda_i)``, compiled.

    Parameters
    ----------
    lam : (n,) complex ndarray
        Poles.
    Res : (n, p * m) complex ndarray
        Residues, flattened per pole.
    D : (p, m) ndarray
    z : (M,) complex ndarray

    Returns
    -------
    (M, p, m) complex ndarray
    """
    k = _build()["pole"]
    out = np.empty((D.size, z.size), complex)
    k(np.ascontiguousarray(lam, complex), np.ascontiguousarray(Res, complex),
      np.ascontiguousarray(D, complex).reshape(-1), np.ascontiguousarray(z, complex), out)
    return out.T.reshape(z.size, *D.shape).copy()
