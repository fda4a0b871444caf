"""The first-order modal recursions of :func:`~roadcollab.lti.modal.modal_states`, compiled (numba; the
``"compiled"`` path of :mod:`~roadcollab.lti.kernels`).

``xi[k+1] = lam xi[k] + u[k]`` for every mode in one call: 24 us for two modes over 4,600 steps against 150 us
for the two ``scipy.signal.lfilter`` calls of the numpy path, and no import of ``scipy.signal`` (0.3-0.45 s,
which every process of a ``reproduce`` paid on its first run: docs/speed.md, "Fourteenth pass"). The same
complex product and sum per step as ``lfilter``'s transposed direct form with ``b = [0, 1]``, ``a = [1, -lam]``
(``-(-lam) xi`` is ``lam xi`` exactly), so the states are the same bits (the test checks it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import compiled_available, jit_options

__all__ = ["modal_kernel"]

_KERNEL: dict[str, Any] = {}


def modal_kernel() -> Any:
    """The compiled recursion ``(lam, u, xi0, out) -> None``, or None without numba; numba is imported on first use.

    Returns
    -------
    numba dispatcher or None
        Called with C-ordered complex128 arrays ``lam`` (k,), ``u`` (N, k), ``xi0`` (k,), read-only, and
        ``out`` (N + 1, k), which it fills.
    """
    if not _KERNEL:
        if compiled_available():
            import numba

            globals()["_modal"] = numba.njit(**jit_options())(globals()["_modal"])
            _KERNEL.update(modal=globals()["_modal"])
        else:
            _KERNEL.update(modal=None)
    return _KERNEL["modal"]


def _modal(lam: np.ndarray, u: np.ndarray, xi0: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover - compiled
    n_steps, k = u.shape
    for i in range(k):
        l = lam[i]
        x = xi0[i]
        out[0, i] = x
        for n in range(n_steps):
            x = u[n, i] + l * x
            out[n + 1, i] = x
