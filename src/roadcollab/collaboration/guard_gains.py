"""Per-band gains of the receiver guard's bounded combination (issue 20; see :mod:`.guard`).

A receiver forms ``w^f = M z_used`` with ``M = I - D P_hat`` and, per guard band ``b``,
``z_used = g_b (z_own + clip(z_msg - z_own))``. Its estimate's error is then

.. code-block:: text

    w_hat - w = (1 - g) (D P - I) w + D n + g [D (P - P_hat) w + M e_msg]
                '-- observer error --'      '-- what the message brings --'

so the honest optimum is ``g = P_obs / (P_obs + P_msg)`` with ``P_obs = E|(D P - I) w + D n|^2`` and
``P_msg = E|D (P - P_hat) w|^2 + tr(M C M^H)`` (independent terms; the sender's inversion error taken
as the receiver's, covariance ``C``). A lie can move ``z_used`` by at most ``g sqrt(kappa v_b)`` in the
band; aligned with the observer's error it costs at most ``((1 - g) + g beta)^2 P_obs`` with
``beta = (sqrt(P_msg) + sigma_max(M) sqrt(kappa v_b)) / sqrt(P_obs)``, which stays below ``rho P_obs`` for
``g <= (sqrt(rho) - 1) / (beta - 1)``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .._validation import check_int
from ..errors import ParameterError
from ..lti.batch2x2 import matmul, sigma_max_2x2

__all__ = ["bounded_gains", "third_octave_bands"]


def bounded_gains(estimator, S: np.ndarray, C: np.ndarray, bands: Sequence[np.ndarray], band_expected: np.ndarray,
                  *, noise_std: float, kappa: float, rho: float) -> np.ndarray:
    """``g_b`` per guard band: the honest optimum, capped so that the worst case stays below ``rho P_obs``.

    Parameters
    ----------
    estimator : CollaborativeEstimator
        The receiver (its ``D_f``, ``P_f``, ``posterior_responses`` and grid).
    S : (K_active, 2, 2) ndarray
        Road second moment per active bin, (m/s)^2.
    C : (K_active, 2, 2) ndarray
        The receiver's inversion error covariance per active bin, (m/s)^2.
    bands : sequence of (n_b,) int ndarray
        Active-bin indices of each band.
    band_expected : (n_bands,) ndarray
        ``v_b``, the expected honest band discrepancy, (m/s)^2.
    noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    kappa : float
        Innovation clip in units of ``v_b``.
    rho : float
        Design bound on the worst case, in units of ``P_obs``.

    Returns
    -------
    (n_bands,) ndarray
        In ``[0, 1]``.
    """
    est = estimator
    act = est.grid.active
    D = est.D_f[act]
    M = np.eye(2) - matmul(D, est.P_f[act])                          # I - D P_hat: z -> w^f
    E = matmul(D[None], est.posterior_responses) - np.eye(2)        # D P - I per posterior draw
    p_obs = np.real(np.trace(np.mean(matmul(E, S[None], E.conj().transpose(0, 1, 3, 2)), axis=0)
                             + est.grid.n_samples * noise_std ** 2 * matmul(D, D.conj().transpose(0, 2, 1)),
                             axis1=1, axis2=2))
    F = matmul(D[None], est.posterior_responses - est.P_f[act][None])      # D (P - P_hat) per draw
    p_model = np.real(np.trace(np.mean(matmul(F, S[None], F.conj().transpose(0, 1, 3, 2)), axis=0), axis1=1, axis2=2))
    p_msg = p_model + np.real(np.trace(matmul(M, C, M.conj().transpose(0, 2, 1)), axis1=1, axis2=2))
    m2 = sigma_max_2x2(M)[0] ** 2
    gains = np.zeros(len(bands))
    for i, b in enumerate(bands):
        P_obs, P_msg = p_obs[b].sum(), p_msg[b].sum()
        g = P_obs / (P_obs + P_msg)
        beta = (np.sqrt(P_msg) + np.sqrt(m2[b].max() * kappa * band_expected[i])) / np.sqrt(P_obs)
        if beta > 1.0:
            g = min(g, (np.sqrt(rho) - 1.0) / (beta - 1.0))
        gains[i] = g
    return gains


def third_octave_bands(freqs: np.ndarray, *, min_bins: int = 16) -> list[np.ndarray]:
    """Partition bins into third-octave bands, merged upwards until each has ``min_bins`` bins.

    Parameters
    ----------
    freqs : (K,) ndarray
        Increasing positive bin frequencies, Hz.
    min_bins : int
        Fewest bins per band (the last band absorbs a short remainder).

    Returns
    -------
    list of (n_b,) int ndarray
        Bin indices of each band, in order; together every index once.
    """
    min_bins = check_int("min_bins", min_bins, low=1)
    freqs = np.asarray(freqs, dtype=float)
    if freqs.ndim != 1 or freqs.size == 0 or not np.all(freqs > 0) or np.any(np.diff(freqs) <= 0):
        raise ParameterError(f"freqs must be increasing positive frequencies, got shape {freqs.shape}")
    band_id = np.floor(3.0 * np.log2(freqs / freqs[0]) + 1e-9).astype(int)
    bands: list[np.ndarray] = []
    current: list[int] = []
    for b in np.unique(band_id):
        current.extend(np.flatnonzero(band_id == b).tolist())
        if len(current) >= min_bins:
            bands.append(np.array(current))
            current = []
    if current:
        if bands:
            bands[-1] = np.concatenate([bands[-1], current])
        else:
            bands.append(np.array(current))
    return bands
