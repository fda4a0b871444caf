"""The receiver guard: what a well-formed message implies is checked before it is used.

A message that decodes cleanly can still say anything: ``z x 1e3``, a static ``T = 1e-3 I``, a
near-singular ``T``, a tone, a fake pothole. Vehicle ``j`` cannot know the truth, but it has its
own record ``y_j`` and its own inversion ``z_own = W P_hat_j^-1 y_j``
(:meth:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator.invert`), and it knows the
statistics an honest sender's ``z`` obeys. For an honest sender ``i`` (eq. 11-12 with nominal
``T``), ``z_i = W P_hat_i^-1 (P_i w + n_i)``, so per bin

.. math::

    d = z_{msg} - z_{own} = W[(A_i - A_j) w + \\hat P_i^{-1} n_i - \\hat P_j^{-1} n_j],
    \\qquad A = \\hat P^{-1} P,

    v = E|d|^2 \\approx 2 W^2 \\operatorname{tr}\\big(E[(A_j - I) S (A_j - I)^H]
        + N \\sigma^2 \\hat P_j^{-1} \\hat P_j^{-H}\\big),

with the road second moment ``S`` (:func:`~roadcollab.collaboration.fusion.road_second_moment`),
the receiver's posterior plants (:func:`~roadcollab.collaboration.fusion.posterior_responses`),
the sensor noise ``sigma`` and ``N`` samples. The sender's parameter error is unknown and is taken
as distributed like the receiver's (the fleet is exchangeable): the factor 2.

Per band ``b`` (third-octave bands of the active bins, merged to at least ``min_bins`` bins) the
statistic is ``r_b = sum_b |d|^2 / sum_b v``: about 1 for an honest sender. A band is refused if
``r_b > threshold``, if ``T`` is ill-conditioned (``cond T > max_condition``) in any of its bins or
if anything in it is not finite; the whole message is refused if more than ``max_refused_fraction``
of the bands are (a sender that disagrees everywhere is not trusted anywhere), if it does not fit
the grid, or if its responses are not finite. Where refused, the receiver falls back to its own
observer (``w^f = 0``). The estimate is therefore finite, and the receiver's next message encodes.

Thresholds (stated a priori, not fitted to the tests):

- ``threshold = 10``: an honest band's ``r_b`` is a sum over ``n_b >= 16`` bins (about
  ``n_b / 1.5`` independent on the 1.5x padded grid) of two complex channels, roughly
  ``chi^2_nu / nu`` with ``nu >= 40``, whose 1e-6 quantile is below 2.6; the remaining factor of
  about 4 covers the model's approximations (the run's road is not the average road; the sender's
  parameter error is not the receiver's). An attacker can therefore shift the receiver's ``z`` by
  at most about ``sqrt(10 v)`` per band unnoticed, a few times the honest inversion error.
- ``max_condition = 1e8``: honest ``T`` measured up to 1e2, obfuscated ``Psi1 T`` up to
  ``1e4 * 1e2`` (``ObfuscationSpec.max_condition`` is 1e4); 1e8 leaves two decades.
- ``max_refused_fraction = 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .._validation import check_int, check_nonnegative, check_positive
from ..errors import MessageError, ParameterError
from ..lti.batch2x2 import condition_2x2, inv2x2, matmul
from ..wire.message import ExchangeMessage, InversionMessage
from .algorithm1 import CollaborativeEstimator

__all__ = ["GuardReport", "ReceiverGuard", "fleet_guards", "third_octave_bands"]


@dataclass(frozen=True)
class GuardReport:
    """What the guard decided about one incoming message.

    Attributes
    ----------
    accepted_bands : tuple of int
        Indices of the bands whose part of ``z`` was used.
    refused_bands : tuple of int
        Indices of the bands replaced by the receiver's own observer (``w^f = 0``).
    reasons : tuple of str
        One reason per refused band (``"band 3 (2.0-2.5 Hz): r = 41 > 10"``), or one reason for a
        whole-message refusal.
    statistics : tuple of float
        ``r_b`` per band (inf where not finite; NaN if the message was refused before).
    whole_message_refused : bool
        No part of the message was used.
    """

    accepted_bands: tuple[int, ...]
    refused_bands: tuple[int, ...]
    reasons: tuple[str, ...]
    statistics: tuple[float, ...]
    whole_message_refused: bool

    @property
    def refused(self) -> bool:
        """True if any band (or the whole message) was refused."""
        return self.whole_message_refused or bool(self.refused_bands)


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


class ReceiverGuard:
    """Plausibility check of incoming messages for one receiving vehicle.

    Parameters
    ----------
    estimator : CollaborativeEstimator
        The receiver (with ``fleet`` set: its posterior plants give the parameter uncertainty).
    road_moment : (K_active, 2, 2) ndarray
        Road second moment per active bin
        (:attr:`~roadcollab.experiments.pipeline.FleetPipeline.road_moment`), (m/s)^2.
    noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    threshold : float
        Largest accepted band statistic ``r_b`` (see the module docstring).
    max_condition : float
        Largest accepted 2-norm condition number of the sender's ``T`` per bin.
    max_refused_fraction : float
        Refuse the whole message when more than this fraction of the bands is refused.
    min_bins : int
        Fewest bins per band.
    """

    def __init__(self, estimator: CollaborativeEstimator, road_moment: np.ndarray, noise_std: float, *,
                 threshold: float = 10.0, max_condition: float = 1e8, max_refused_fraction: float = 0.5,
                 min_bins: int = 16) -> None:
        if not isinstance(estimator, CollaborativeEstimator):
            raise ParameterError(f"estimator must be a CollaborativeEstimator, got {type(estimator).__name__}")
        if estimator.fleet is None:
            raise ParameterError("estimator must have fleet= set: the guard needs the parameter uncertainty")
        grid = estimator.grid
        act = grid.active
        K = int(act.sum())
        S = np.asarray(road_moment)
        if S.shape != (K, 2, 2) or not np.isfinite(S).all():
            raise ParameterError(f"road_moment must be a finite ({K}, 2, 2) array, got shape {S.shape}")
        self.estimator = estimator
        self.noise_std = check_nonnegative("noise_std", noise_std)
        self.threshold = check_positive("threshold", threshold)
        self.max_condition = check_positive("max_condition", max_condition)
        self.max_refused_fraction = check_nonnegative("max_refused_fraction", max_refused_fraction)
        freqs = np.arange(grid.n_bins)[act] * grid.sample_rate / grid.nfft
        self.bands = third_octave_bands(freqs, min_bins=min_bins)
        self.band_edges_hz = [(float(freqs[b[0]]), float(freqs[b[-1]])) for b in self.bands]
        self.expected = self._expected_discrepancy(S)
        self.band_expected = np.array([self.expected[b].sum() for b in self.bands])

    def _expected_discrepancy(self, S: np.ndarray) -> np.ndarray:
        """``v`` per active bin (module docstring): twice the receiver's own inversion error."""
        est = self.estimator
        act = est.grid.active
        Pinv = inv2x2(est.P_f[act])                              # P_hat_j^-1
        A = matmul(Pinv[None], est.posterior_responses) - np.eye(2)     # P_hat^-1 P - I per draw
        param = np.mean(matmul(A, S[None], A.conj().transpose(0, 1, 3, 2)), axis=0)
        noise = est.grid.n_samples * self.noise_std ** 2 * matmul(Pinv, Pinv.conj().transpose(0, 2, 1))
        w2 = est.grid.reg_weight[act] ** 2
        return 2.0 * w2 * np.real(np.trace(param + noise, axis1=1, axis2=2))

    def _refuse_all(self, reason: str) -> tuple[np.ndarray, GuardReport]:
        K = int(self.estimator.grid.active.sum())
        report = GuardReport((), tuple(range(len(self.bands))), (reason,), (float("nan"),) * len(self.bands), True)
        return np.zeros((K, 2), complex), report

    def _bad_bins(self, message) -> np.ndarray:
        """Bins where the sender's ``T`` is not finite or ill-conditioned (exchange messages)."""
        K = int(self.estimator.grid.active.sum())
        if not isinstance(message, ExchangeMessage):
            return np.zeros(K, bool)
        est = self.estimator
        T = est.response_cache.response(message.T, est.grid.omega_dt[est.grid.active])
        with np.errstate(all="ignore"):
            cond = condition_2x2(T)
        return ~(cond <= self.max_condition)

    def check(self, message: ExchangeMessage | InversionMessage, Y: np.ndarray) -> tuple[np.ndarray, GuardReport]:
        """The part of ``z`` the receiver may use, and why the rest was refused.

        Parameters
        ----------
        message : ExchangeMessage | InversionMessage
            From vehicle ``j - 1``.
        Y : (K, 2) complex ndarray
            The receiver's own record spectrum on the grid.

        Returns
        -------
        z : (K_active, 2) complex ndarray
            The message's ``z`` in accepted bands, 0 in refused bands (finite everywhere).
        report : GuardReport
        """
        est = self.estimator
        if not isinstance(message, (ExchangeMessage, InversionMessage)):
            return self._refuse_all(f"not a message: {type(message).__name__}")
        try:
            z = est.received_z(message)
        except MessageError as err:
            return self._refuse_all(f"does not fit the receiver: {err}")
        bad = self._bad_bins(message)
        if bad.all():
            return self._refuse_all(f"T ill-conditioned (cond > {self.max_condition:g}) or not finite on every bin")
        act = est.grid.active
        z_own = est.invert(Y)[act]
        with np.errstate(all="ignore"):
            d2 = np.sum(np.abs(z - z_own) ** 2, axis=1)
        accepted, refused, reasons, stats = [], [], [], []
        for i, b in enumerate(self.bands):
            with np.errstate(all="ignore"):
                r = float(d2[b].sum() / self.band_expected[i])
            r = r if np.isfinite(r) else float("inf")
            stats.append(r)
            lo, hi = self.band_edges_hz[i]
            if bad[b].any():
                refused.append(i)
                reasons.append(f"band {i} ({lo:.3g}-{hi:.3g} Hz): T ill-conditioned or not finite")
            elif not r <= self.threshold or not np.isfinite(z[b]).all():
                refused.append(i)
                reasons.append(f"band {i} ({lo:.3g}-{hi:.3g} Hz): r = {r:.3g} > {self.threshold:g}")
            else:
                accepted.append(i)
        if len(refused) > self.max_refused_fraction * len(self.bands):
            z0, rep = self._refuse_all(f"{len(refused)} of {len(self.bands)} bands implausible: " + "; ".join(reasons[:3]))
            return z0, GuardReport((), rep.refused_bands, rep.reasons, tuple(stats), True)
        out = np.zeros_like(z)
        for i in accepted:
            out[self.bands[i]] = z[self.bands[i]]
        return out, GuardReport(tuple(accepted), tuple(refused), tuple(reasons), tuple(stats), False)

    def substitute(self, message: ExchangeMessage | InversionMessage, Y: np.ndarray, fallback: np.ndarray
                   ) -> tuple[np.ndarray, GuardReport]:
        """The message's ``z`` where plausible, ``fallback`` (e.g. the receiver's own inversion) elsewhere.

        Parameters
        ----------
        message : ExchangeMessage | InversionMessage
            The incoming message (an exchange, a relayed average or an aggregate).
        Y : (K, 2) complex ndarray
            The receiver's own record spectrum on the grid.
        fallback : (K, 2) complex ndarray
            Spectrum used in refused bands (and everywhere if the whole message is refused).

        Returns
        -------
        Z : (K, 2) complex ndarray
            Finite spectrum on the grid; zero outside the active bins.
        report : GuardReport
        """
        z_ok, report = self.check(message, Y)
        g = self.estimator.grid
        act_idx = np.flatnonzero(g.active)
        Z = np.zeros_like(fallback)
        if report.whole_message_refused:
            Z[act_idx] = fallback[act_idx]
            return Z, report
        Z[act_idx] = z_ok
        for b in report.refused_bands:
            Z[act_idx[self.bands[b]]] = fallback[act_idx[self.bands[b]]]
        return Z, report

    def feedforward(self, message: ExchangeMessage | InversionMessage, Y: np.ndarray
                    ) -> tuple[np.ndarray, GuardReport]:
        """``w^f_j`` from the guarded ``z`` (:meth:`check`): 0 where refused.

        Parameters
        ----------
        message : ExchangeMessage | InversionMessage
            From vehicle ``j - 1``.
        Y : (K, 2) complex ndarray
            The receiver's own record spectrum on the grid.

        Returns
        -------
        Wf : (K, 2) complex ndarray
            Finite feed-forward spectrum.
        report : GuardReport
        """
        z, report = self.check(message, Y)
        return self.estimator.wf_from_active_z(z), report


def fleet_guards(estimators: Sequence[CollaborativeEstimator], road_moment: np.ndarray, noise_std: float,
                 **options) -> tuple[ReceiverGuard, ...]:
    """One :class:`ReceiverGuard` per vehicle, for ``Relay(..., guard=...)``.

    Parameters
    ----------
    estimators : sequence of CollaborativeEstimator
        The fleet in driving order.
    road_moment : (K_active, 2, 2) ndarray
        Road second moment per active bin, (m/s)^2.
    noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    **options
        Keyword options of :class:`ReceiverGuard` (``threshold``, ``max_condition``, ...).

    Returns
    -------
    tuple of ReceiverGuard
    """
    return tuple(ReceiverGuard(e, road_moment, noise_std, **options) for e in estimators)
