"""One vehicle's results on one segment (Algorithm 1): its observer, its estimate and the spectra
behind them."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..estimation.grid import SegmentGrid
from ..lti.batch2x2 import matvec

__all__ = ["VehicleEstimate"]


@dataclass(frozen=True, eq=False)
class VehicleEstimate:
    """Vehicle ``j``'s results on one segment.

    Attributes
    ----------
    observer_only : (N, 2) ndarray
        ``D_j y_j``, m/s: the vehicle alone.
    W_obs : (K, 2) complex ndarray
        Spectrum of ``D_j y_j``.
    estimate : (N, 2) ndarray
        ``w_hat_j = D_j y_j + w^f_j``, m/s: Algorithm 1.
    W_hat, E, Wf : (K, 2) complex ndarray
        Spectra of ``w_hat_j``, ``e_j`` and ``w^f_j`` on the grid (all bins).
    Y : (K, 2) complex ndarray
        Spectrum of the measurement ``y_j``.
    """

    W_obs: np.ndarray
    W_hat: np.ndarray
    Wf: np.ndarray
    Y: np.ndarray
    P_f: np.ndarray
    grid: SegmentGrid
    offset: np.ndarray

    # Time signals and the residual are computed on first use: a car that only forwards a
    # message needs neither (saves two inverse FFTs per segment).
    @functools.cached_property
    def observer_only(self) -> np.ndarray:
        return self.grid.irfft(self.W_obs, self.grid.n_samples) + self.offset

    @functools.cached_property
    def estimate(self) -> np.ndarray:
        return self.grid.irfft(self.W_hat, self.grid.n_samples) + self.offset

    @functools.cached_property
    def E(self) -> np.ndarray:
        return self.Y - matvec(self.P_f, self.W_hat)
