"""The extreme eigenvalues of a real symmetric matrix, compiled (numba; the ``"compiled"`` path of
:mod:`~roadcollab.lti.kernels`), for the stability certificate's figures (:mod:`~roadcollab.lti._cert_kernel`).

The call numba's ``np.linalg.eigvalsh`` makes, made directly: LAPACK ``dsyevd`` through numba's own helper
``numba_ez_xxxevd`` (``numba.np.linalg``), called by its symbol so that the kernels stay cacheable, with the
same arguments. The generic overload (checks, copies, dispatch on the dtype) cost 0.4 s of a fresh
installation's first run to compile, on the command's path (docs/speed.md, "Fifteenth pass").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import compiled_available, jit_options

__all__: list[str] = []

_KERNEL: dict[str, Any] = {}

#: The arguments numba's ``np.linalg.eigvalsh`` passes to ``numba_ez_xxxevd``: real double, eigenvalues only,
#: lower triangle of the Fortran-ordered matrix.
_EVD_KIND, _EVD_JOBZ, _EVD_UPLO = ord("d"), ord("N"), ord("L")
#: numba's ``ExternalFunction`` for ``numba_ez_xxxevd``, bound by :func:`_build`.
_xxxevd: Any = None


def _build() -> dict[str, Any]:
    """The compiled function (``None`` without numba); numba is imported on first use. Only compiled
    kernels call it (no Python entry point)."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(ends=None)
        return _KERNEL
    import numba

    types: Any = numba.types                    # untyped in numba
    globals()["_xxxevd"] = types.ExternalFunction("numba_ez_xxxevd", types.intc(
        types.char, types.char, types.char, types.intp, types.CPointer(types.float64), types.intp,
        types.CPointer(types.float64)))
    globals()["_eigvalsh_ends"] = numba.njit(**jit_options(internal=True))(globals()["_eigvalsh_ends"])
    _KERNEL.update(ends=globals()["_eigvalsh_ends"])
    return _KERNEL


def _eigvalsh_ends(X: np.ndarray) -> tuple[float, float]:   # pragma: no cover - compiled
    """The smallest and largest eigenvalue of a real symmetric ``X`` (n >= 1): the LAPACK ``dsyevd`` call of
    numba's ``np.linalg.eigvalsh``, with its arguments (``X`` copied to Fortran order, lower triangle,
    eigenvalues only), its check for non-finite entries and its error for a failed convergence, so the same
    bits (``test_the_certificate_eigenvalues_are_the_bits_of_eigvalsh``)."""
    n = X.shape[0]
    F = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            x = X[i, j]
            if not np.isfinite(x):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
            F[j, i] = x                             # row-major F holds X column-major
    w = np.empty(n)
    r = _xxxevd(_EVD_KIND, _EVD_JOBZ, _EVD_UPLO, n, F.ctypes, n, w.ctypes)
    if r != 0 or F.shape[0] != n:                   # F read after the call: alive until LAPACK is done
        raise ValueError("Internal algorithm failed to converge.")
    return w[0], w[n - 1]
