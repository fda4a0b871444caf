"""The per-bin oracle and its two windowed variants as batched linear maps of the records (test helper).

Each map takes ``j`` batches of records, ``(N, 2, M)`` each, and returns the scored, band-limited estimate
``(m, 2, M)``, column by column, so :meth:`~roadcollab.estimation.window_mmse.WindowedMMSE.expected_error`
can evaluate it in closed form and ``tools/window_bound.py`` can score it on runs:

- ``oracle_per_bin``: :class:`~roadcollab.collaboration.fusion.LinearMMSE` with the true plants, per bin of the
  zero-padded grid (the reproduction's ``oracle_per_bin``);
- ``zeroed``: the same estimate set to zero outside the window (the truth is zero there);
- ``free_response``: the per-bin oracle re-applied to every record extended into the padding by its plant's
  free response from the state that the zeroed estimate leaves at the window's end.
"""

from __future__ import annotations

import numpy as np
import scipy.fft


def _spectral(lmmse, grid, j):
    act = grid.active_index

    def estimate(recs):
        Ystack = np.concatenate([scipy.fft.rfft(y, n=grid.nfft, axis=0)[act] for y in recs], axis=1)
        X = np.zeros((grid.n_bins, 2, recs[0].shape[2]), complex)
        X[act] = np.einsum("kij,kjm->kim", lmmse.gains[j - 1], Ystack)
        return X
    return estimate


def _scored(grid, sl, X):
    return scipy.fft.irfft(grid.weight[:, None, None] * X, n=grid.nfft, axis=0)[sl]


def _end_state(plant, w):
    x = np.zeros((4, w.shape[2]))
    for k in range(w.shape[0]):
        x = plant.Ad @ x + plant.Bd @ w[k]
    return x


def per_bin_variants(lmmse, grid, sl, plants, j):
    """``{name: map}`` of the three estimators from the records of vehicles ``1..j`` (module docstring)."""
    estimate, N = _spectral(lmmse, grid, j), grid.n_samples

    def oracle(recs):
        return _scored(grid, sl, estimate(recs))

    def zeroed(recs):
        x = scipy.fft.irfft(estimate(recs), n=grid.nfft, axis=0)[:N]
        return _scored(grid, sl, scipy.fft.rfft(x, n=grid.nfft, axis=0))

    def free_response(recs):
        x = scipy.fft.irfft(estimate(recs), n=grid.nfft, axis=0)[:N]
        extended = []
        for p, y in zip(plants, recs):
            s, tail = _end_state(p, x), np.empty((grid.nfft - N, 2, y.shape[2]))
            for k in range(tail.shape[0]):
                tail[k] = p.C @ s
                s = p.Ad @ s
            extended.append(np.concatenate([y, tail]))
        return _scored(grid, sl, estimate(extended))

    return {"oracle_per_bin": oracle, "zeroed": zeroed, "free_response": free_response}
