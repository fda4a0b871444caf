"""The frequency grid on which Algorithm 1 is applied offline, and the evaluation band.

A vehicle acts after it has traversed a segment (Algorithm 1, step 1), so its learning
filters need not be causal. They are applied per bin on a zero-padded DFT grid: a recorded
window of ``n_samples`` is padded to ``nfft`` samples and every LTI map is its frequency
response at ``z = exp(j 2 pi k / nfft)``. Signals that cross the network live on this padded
periodic grid (``nfft`` samples), which is what makes Theorem 1 exact to round-off.

DC handling: accelerations cannot see a constant road velocity; ``P`` has
a double transmission zero at ``s = 0`` and every inverse is singular there. All estimators
are therefore evaluated, and every inverse is applied, through one zero-phase band weight

.. math:: W(f) = \\frac{1}{1 + (f_{lo}/f)^{2n}}\\cdot\\frac{1}{1 + (f/f_{hi})^{2n}},\\qquad W(0) = 0,

the squared magnitude of an order-``n`` Butterworth band-pass. The MSE of every estimator is
the mean squared difference of ``W``-filtered truth and ``W``-filtered estimate. The inverses
themselves are regularised by the same shape at half the corner (``W_reg``), so estimates
that contain inverses are not weighted twice inside the band.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft

from .._validation import check_int, check_positive, check_real, check_signal
from ..errors import ParameterError

try:    # the binding scipy.fft.rfft and irfft end in, after their dispatch (docs/speed.md, "Eleventh pass")
    from scipy.fft._pocketfft import pypocketfft as _pocketfft
except ImportError:      # pragma: no cover - another scipy layout: scipy.fft itself
    _pocketfft = None

__all__ = ["SegmentGrid", "bin_index"]


def bin_index(mask: np.ndarray) -> slice | np.ndarray:
    """The bins of a boolean mask as a slice when they are contiguous, else the mask itself.

    Indexing a (3001, 2) complex spectrum with the mask copies it through a gather (60 us
    measured); with the slice it is a view, and the elements are the same.

    Parameters
    ----------
    mask : (n_bins,) bool ndarray

    Returns
    -------
    slice | (n_bins,) bool ndarray
    """
    on = np.flatnonzero(mask)
    if on.size and on[-1] - on[0] + 1 == on.size:
        return slice(int(on[0]), int(on[-1]) + 1)
    return mask


@dataclass(frozen=True, eq=False)
class SegmentGrid:
    """Zero-padded DFT grid for a recorded window.

    Parameters
    ----------
    n_samples : int
        Samples in the recorded window, ``N``.
    sample_rate : float
        Hz.
    band_low_hz : float
        ``f_lo`` of the evaluation band (> 0), Hz.
    band_high_hz : float | None
        ``f_hi``; None means no upper limit (up to Nyquist).
    band_order : int
        Butterworth order ``n`` of the band edges.
    pad_factor : float
        ``nfft >= pad_factor * N`` (>= 1.25), rounded up to a fast FFT length.
    regularization_low_hz : float | None
        Corner of the weight ``W_reg`` that regularises every inverse at DC (default
        ``band_low_hz / 2``). It sits below the evaluation band so that estimates built from
        inverses are not weighted twice in band (``W W_reg`` is within 0.5 % of ``W`` from
        ``band_low_hz`` up).

    Attributes
    ----------
    nfft : int
        Padded length, a fast FFT length ``>= pad_factor * N``.
    freqs : (n_bins,) ndarray
        Bin frequencies, Hz. This and the other arrays below are read-only.
    omega_dt : (n_bins,) ndarray
        Normalised bin frequencies, rad/sample.
    weight, reg_weight : (n_bins,) ndarray
        The band weight ``W`` and the regularisation weight ``W_reg`` (0 at DC).
    active : (n_bins,) bool ndarray
        Bins where ``W_reg > 0``.
    active_index : slice | (n_bins,) bool ndarray
        The same bins as a slice when they are contiguous (always for a band-pass ``W_reg``;
        :func:`bin_index`).
    omega_active : (K_active,) ndarray
        ``omega_dt`` on the active bins (one array: what is computed from it is found by identity).

    Examples
    --------
    >>> import numpy as np
    >>> from roadcollab import SegmentGrid
    >>> g = SegmentGrid(1000, 100.0, band_low_hz=0.5)
    >>> g.nfft >= 1250                     # zero-padded: at least pad_factor * N
    True
    >>> g.rfft(np.zeros((1000, 2))).shape == (g.nfft // 2 + 1, 2)
    True
    """

    n_samples: int
    sample_rate: float
    band_low_hz: float = 0.5
    band_high_hz: float | None = None
    band_order: int = 4
    pad_factor: float = 1.5
    regularization_low_hz: float | None = None
    # Derived in __post_init__ (see Attributes).
    nfft: int = field(init=False)
    freqs: np.ndarray = field(init=False, repr=False)
    omega_dt: np.ndarray = field(init=False, repr=False)
    weight: np.ndarray = field(init=False, repr=False)
    reg_weight: np.ndarray = field(init=False, repr=False)
    active: np.ndarray = field(init=False, repr=False)
    active_index: slice | np.ndarray = field(init=False, repr=False)
    omega_active: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_int("n_samples", self.n_samples, low=16)
        check_positive("sample_rate", self.sample_rate)
        check_real("band_low_hz", self.band_low_hz, low=0.0, low_open=True, high=self.sample_rate / 2)
        if self.band_high_hz is not None:
            check_real("band_high_hz", self.band_high_hz, low=self.band_low_hz, low_open=True)
        check_int("band_order", self.band_order, low=1, high=16)
        check_real("pad_factor", self.pad_factor, low=1.25, high=8.0)
        nfft = scipy.fft.next_fast_len(int(np.ceil(self.pad_factor * self.n_samples)), real=True)
        object.__setattr__(self, "nfft", int(nfft))
        f = np.fft.rfftfreq(nfft, d=1.0 / self.sample_rate)
        object.__setattr__(self, "freqs", f)
        object.__setattr__(self, "omega_dt", 2.0 * np.pi * f / self.sample_rate)
        with np.errstate(divide="ignore"):
            W = 1.0 / (1.0 + (self.band_low_hz / np.where(f > 0, f, 1.0)) ** (2 * self.band_order))
        W[0] = 0.0
        if self.band_high_hz is not None:
            W = W / (1.0 + (f / self.band_high_hz) ** (2 * self.band_order))
        # Bins where a weight is below round-off carry nothing; zeroing them keeps every
        # inverse from amplifying round-off near the transmission zeros at DC.
        W[W < 1e-12] = 0.0
        f_reg = self.band_low_hz / 2 if self.regularization_low_hz is None else check_real(
            "regularization_low_hz", self.regularization_low_hz, low=0.0, low_open=True, high=self.band_low_hz)
        with np.errstate(divide="ignore"):
            Wr = 1.0 / (1.0 + (f_reg / np.where(f > 0, f, 1.0)) ** (2 * self.band_order))
        Wr[0] = 0.0
        if self.band_high_hz is not None:
            Wr = Wr / (1.0 + (f / self.band_high_hz) ** (2 * self.band_order))
        Wr[Wr < 1e-12] = 0.0
        object.__setattr__(self, "weight", W)
        object.__setattr__(self, "reg_weight", Wr)
        object.__setattr__(self, "active", Wr > 0)
        object.__setattr__(self, "active_index", bin_index(self.active))
        object.__setattr__(self, "omega_active", np.array(self.omega_dt[self.active_index]))
        # A frozen grid with frozen arrays: what depends on them only (exp(j omega_dt), a response cache's
        # key) is found by identity instead of comparing 3000-6000 entries (lti.response.unit_circle).
        for arr in (self.freqs, self.omega_dt, self.weight, self.reg_weight, self.active, self.active_index,
                    self.omega_active):
            if isinstance(arr, np.ndarray):
                arr.setflags(write=False)

    @property
    def dt(self) -> float:
        return 1.0 / self.sample_rate

    @property
    def n_bins(self) -> int:
        return self.freqs.size

    def rfft(self, x) -> np.ndarray:
        """Spectrum (n_bins, channels) of a signal of up to ``nfft`` samples (zero-padded).

        Parameters
        ----------
        x : (N, channels) array_like
            ``N <= nfft`` samples.

        Returns
        -------
        (n_bins, channels) complex ndarray
        """
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[0] > self.nfft:
            raise ParameterError(f"signal must have shape (<= {self.nfft}, channels), got {x.shape}")
        if _pocketfft is not None and x.flags.aligned:
            # What scipy.fft.rfft(x, n=nfft, axis=0) runs after its backend dispatch and argument handling
            # (zero padding to nfft, then pocketfft's r2c): the same bits, about 6 us less per transform
            # (five per paper vehicle-segment; tested against scipy.fft).
            if x.shape[0] < self.nfft:
                padded = np.zeros((self.nfft, x.shape[1]))
                padded[:x.shape[0]] = x
                x = padded
            out: np.ndarray = _pocketfft.r2c(x, (0,), True, 0, None, scipy.fft.get_workers())
            return out
        return scipy.fft.rfft(x, n=self.nfft, axis=0)

    def irfft(self, X, n: int | None = None) -> np.ndarray:
        """Time signal of the first ``n`` (default ``nfft``) samples of a spectrum.

        Parameters
        ----------
        X : (n_bins, channels) complex array_like
        n : int, optional
            Samples kept (default ``nfft``).

        Returns
        -------
        (n, channels) ndarray
        """
        if (_pocketfft is not None and isinstance(X, np.ndarray) and X.dtype == np.complex128 and X.ndim == 2
                and X.shape[0] == self.nfft // 2 + 1 and X.flags.aligned):
            # scipy.fft.irfft(X, n=nfft, axis=0) after its dispatch: pocketfft's c2r, the same bits (see rfft).
            x = _pocketfft.c2r(X, (0,), self.nfft, False, 2, None, scipy.fft.get_workers())
        else:
            x = scipy.fft.irfft(X, n=self.nfft, axis=0)
        return x if n is None else x[:n]

    def band_limit(self, x, n: int | None = None) -> np.ndarray:
        """Apply the zero-phase band weight ``W`` to a time signal.

        Parameters
        ----------
        x : (N, channels) array_like
        n : int, optional
            Samples returned (default ``N``).

        Returns
        -------
        (n, channels) ndarray
        """
        x = check_signal("x", x)
        return self.band_limited(self.rfft(x), x.shape[0] if n is None else n)

    def band_limited_many(self, spectra, n: int | None = None) -> np.ndarray:
        """:meth:`band_limited` of several spectra at once, side by side: the same bits as one call each.

        The transforms run along contiguous rows (one spectrum's channel per row): ten (n_bins, 2)
        spectra took 0.62 ms against 0.82 ms one call each, where pocketfft's strided columns of
        one (n_bins, 20) array took 0.97 ms (measured).

        Parameters
        ----------
        spectra : sequence of (n_bins, channels) complex array_like
        n : int, optional
            Samples kept (default ``nfft``).

        Returns
        -------
        (n, total channels) ndarray
            A transposed view; columns in the order of ``spectra`` and their channels.
        """
        rows = np.concatenate([np.asarray(X, dtype=complex).T for X in spectra], axis=0)
        if rows.shape[1] != self.n_bins:
            raise ParameterError(f"spectra must have {self.n_bins} bins, got {rows.shape[1]}")
        rows *= self.weight
        if _pocketfft is not None:
            x = _pocketfft.c2r(rows, (1,), self.nfft, False, 2, None, scipy.fft.get_workers())
        else:
            x = scipy.fft.irfft(rows, n=self.nfft, axis=1)
        return (x if n is None else x[:, :n]).T

    def band_limited(self, X, n: int | None = None) -> np.ndarray:
        """Time signal of a spectrum weighted by the zero-phase band weight ``W``: how every
        estimate and every truth is scored.

        Parameters
        ----------
        X : (n_bins, channels) complex array_like
        n : int, optional
            Samples kept (default ``nfft``).

        Returns
        -------
        (n, channels) ndarray
        """
        return self.irfft(self.weight[:, None] * X, n)
