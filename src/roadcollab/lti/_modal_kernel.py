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

from .kernels import compiled_available, jit_options, read_only

__all__ = ["modal_states2"]

_KERNEL: dict[str, Any] = {}


def _build() -> dict[str, Any]:
    """The compiled function (``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(modal=None)
        return _KERNEL
    import numba

    globals()["_modal"] = numba.njit(**jit_options())(globals()["_modal"])
    _KERNEL.update(modal=globals()["_modal"])
    return _KERNEL


def modal_states2(lam: np.ndarray, u: np.ndarray, xi0: np.ndarray) -> np.ndarray | None:
    """:func:`~roadcollab.lti.modal.modal_states` compiled; None without numba.

    Parameters
    ----------
    lam : (k,) array_like
    u : (N, k) array_like
    xi0 : (k,) array_like

    Returns
    -------
    (N + 1, k) complex ndarray or None
    """
    k = _build()["modal"]
    if k is None:
        return None

    def c16(x: np.ndarray) -> np.ndarray:   # one specialisation: C-ordered complex128, read-only
        return read_only(np.ascontiguousarray(x, dtype=np.complex128))

    lam, u = np.asarray(lam), np.asarray(u)
    out = np.empty((u.shape[0] + 1, lam.size), np.complex128)
    k(c16(lam), c16(u.reshape(u.shape[0], lam.size)), c16(xi0), out)
    return out


def _modal(lam: np.ndarray, u: np.ndarray, xi0: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover - compiled
    n_steps, k = u.shape
    for i in range(k):
        l = lam[i]
        x = xi0[i]
        out[0, i] = x
        for n in range(n_steps):
            x = u[n, i] + l * x
            out[n + 1, i] = x
