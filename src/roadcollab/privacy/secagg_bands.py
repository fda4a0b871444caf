"""The public box of :mod:`.secagg_validity` for spectra: a bound per frequency band from road statistics.

A vehicle's secure-aggregation input is its inversion spectrum ``Z`` (``(n_bins, 2)`` complex, the
rfft of the padded grid); the validated vector is ``u = (Re Z, Im Z)`` of the active bins, ``4 K``
values. The bound of bin ``k``, track ``t`` is

``B_kt = kappa * max_{k' in band(k)} sqrt((W_k'^2 S_k'tt + C_k'tt) / 2)``,

``S`` the road model's prior second moment per bin, ``W`` the band weight, ``C`` the expected inversion
error of an honest vehicle (the public nominal models and sensor noise,
:class:`~roadcollab.collaboration.guard.ReceiverGuard` (its ``_inversion_error``); the largest over the fleet), so
``B / kappa`` is the standard deviation of one real part of an honest message, maximised over the band.
The bins of the inactive part of the grid and the imaginary parts of the DC and Nyquist bins get a bound
of 0 (they are sent as 0 and proven to be 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_real
from ..errors import ParameterError
from .secagg_flp import ValidityEncoding

__all__ = ["SpectralBox"]


@dataclass(frozen=True)
class SpectralBox:
    """Per-band bounds on an inversion spectrum and the map to the validated vector.

    Parameters
    ----------
    active : (n_bins,) bool ndarray
        Active bins of the grid.
    std : (K_active, 2) ndarray
        Standard deviation of one real part of an honest message per active bin and track, m/s
        (spectrum units).
    bands : sequence of int arrays
        Active-bin indices of each band (e.g. :attr:`ReceiverGuard.bands`).
    kappa : float
        The stated multiple.
    resolution : float
        Target fixed-point step, spectrum units.
    """

    active: np.ndarray
    std: np.ndarray
    bands: tuple[np.ndarray, ...]
    kappa: float = 6.0
    resolution: float = 1e-3

    def __post_init__(self) -> None:
        check_real("kappa", self.kappa, low=0.0, low_open=True)
        std = np.asarray(self.std, float)
        K = int(np.sum(self.active))
        if std.shape != (K, 2) or not np.all(np.isfinite(std)) or np.any(std < 0):
            raise ParameterError(f"std must be a finite non-negative ({K}, 2) array, got shape {std.shape}")

    def bounds(self) -> np.ndarray:
        """``B`` of the active bins, (K_active, 2)."""
        std = np.asarray(self.std, float)
        B = np.zeros_like(std)
        for b in self.bands:
            B[b] = self.kappa * std[b].max(axis=0)
        return B

    def encoding(self) -> ValidityEncoding:
        """The :class:`~.secagg_flp.ValidityEncoding` of ``u = (Re, Im)`` of every bin."""
        n = self.active.size
        full = np.zeros((n, 2))
        full[self.active] = self.bounds()
        imag = full.copy()
        imag[[0, n - 1]] = 0.0                       # DC and Nyquist are real
        return ValidityEncoding(np.concatenate([full.ravel(), imag.ravel()]), self.resolution)

    def to_vector(self, Z: ArrayLike) -> np.ndarray:
        """``u`` of a spectrum ``(n_bins, 2)``; inactive bins and the DC/Nyquist imaginary parts dropped to 0.

        Parameters
        ----------
        Z : (n_bins, 2) complex array_like
            Spectrum (rfft of the padded grid), m/s.
        """
        Z = np.where(np.asarray(self.active)[:, None], np.asarray(Z, complex), 0)
        Z[[0, -1]] = Z[[0, -1]].real
        return np.concatenate([Z.real.ravel(), Z.imag.ravel()])

    def from_vector(self, u: ArrayLike) -> np.ndarray:
        """The spectrum ``(n_bins, 2)`` of ``u``.

        Parameters
        ----------
        u : (4 n_bins,) array_like
            From :meth:`to_vector` (or an aggregate of such vectors).
        """
        u = np.asarray(u, float)
        h = u.size // 2
        out: np.ndarray = (u[:h] + 1j * u[h:]).reshape(-1, 2)
        return out
