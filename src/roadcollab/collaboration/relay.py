"""The relay engine: one segment's measurements passed down a fleet under an exchange mechanism.

Vehicle ``j`` (a :class:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator`) estimates from its
own record and the message of vehicle ``j-1`` (Algorithm 1), then builds the message it sends
on. How that message looks is the *exchange mechanism*:

==================== ==================================================================================
``none``             Algorithm 1 in the clear: ``(T_j, S_j, e_j, w^f_j)``.
``paper``            Algorithm 2: the same, covered by a fresh ``Psi^S1``, ``Psi^S2`` per message.
``paper_vehicle``    Algorithm 2 with one ``Psi`` draw per vehicle, reused for every message.
``hardened``         Only ``z_j = W_reg P_hat_j^-1 y_j`` (no dynamics); the same estimates.
``fused``            The running fleet average of the ``z_i`` of vehicles ``1..j``; the estimate is
                     that average.
``fused_posterior``  The same with each vehicle inverting its posterior-mean plant
                     ``E[P_i | theta_hat_i]`` under the (public) fleet distribution.
``dp``               ``hardened`` with the Gaussian mechanism on every sample of ``z``.
==================== ==================================================================================

Every command (the reproduction, the applications, recorded drives, the security study and
the benchmark) relays through :class:`Relay`, so a fix here reaches all of them and recorded
drives equal the simulation by construction.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from .._validation import check_nonnegative
from ..collaboration.algorithm1 import CollaborativeEstimator, VehicleEstimate
from ..collaboration.guard import GuardReport, ReceiverGuard
from ..errors import ParameterError
from ..wire.message import ExchangeMessage, InversionMessage
from ..privacy.baselines import dp_message
from ..privacy.obfuscation import ObfuscationChannel, ObfuscationSpec, Obfuscator, obfuscate_spectra
from ..models.simulation import add_sensor_noise, simulate_response

__all__ = ["MECHANISMS", "Exchange", "RelayStep", "Relay", "simulate_measurements"]

#: Exchange mechanisms the relay knows.
MECHANISMS = ("none", "paper", "paper_vehicle", "hardened", "fused", "fused_posterior", "dp")


@dataclass(frozen=True)
class Exchange:
    """How a vehicle turns its estimate into the message it sends.

    Parameters
    ----------
    mechanism : str
        One of :data:`MECHANISMS`.
    obfuscation : ObfuscationSpec
        Distribution of ``Psi`` for ``paper`` and ``paper_vehicle``.
    dp_sigma : float
        Noise standard deviation (m/s) per sample of ``z`` for ``dp``.
    """

    mechanism: str = "none"
    obfuscation: ObfuscationSpec = field(default_factory=ObfuscationSpec)
    dp_sigma: float = 0.0

    def __post_init__(self) -> None:
        if self.mechanism not in MECHANISMS:
            raise ParameterError(f"mechanism must be one of {MECHANISMS}, got {self.mechanism!r}")
        if not isinstance(self.obfuscation, ObfuscationSpec):
            raise ParameterError(f"obfuscation must be an ObfuscationSpec, got {type(self.obfuscation).__name__}")
        check_nonnegative("dp_sigma", self.dp_sigma)


@dataclass(frozen=True, eq=False)
class RelayStep:
    """What one vehicle did on the segment.

    Attributes
    ----------
    result : VehicleEstimate
        Its own observer and its Algorithm-1 estimate (spectra on the grid).
    message : ExchangeMessage | InversionMessage
        What it sent on.
    clear : ExchangeMessage | None
        For ``paper`` and ``paper_vehicle``: the message before obfuscation (never sent), for
        measuring Theorem 1 independently; built on first access (``make_clear``).
    psi : (Obfuscator, Obfuscator) | None
        For ``paper`` and ``paper_vehicle``: the private draws ``Psi^S1``, ``Psi^S2``.
    guard : GuardReport | None
        With a receiver guard: what it accepted and refused of the incoming message.
    make_clear : callable, optional
        Builds ``clear`` (a sender that does not measure Theorem 1 never pays for it: 0.31 ms per
        ``paper`` message).
    """

    result: VehicleEstimate
    message: ExchangeMessage | InversionMessage
    psi: tuple[Obfuscator, Obfuscator] | None = None
    guard: GuardReport | None = None
    make_clear: Callable[[], ExchangeMessage] | None = field(default=None, repr=False)

    @functools.cached_property
    def clear(self) -> ExchangeMessage | None:
        return None if self.make_clear is None else self.make_clear()

    @property
    def estimate_spectrum(self) -> np.ndarray:
        """Spectrum (K, 2) of the mechanism's road-velocity estimate: the fleet average for
        ``fused``, Algorithm 1's ``w_hat_j`` otherwise."""
        if isinstance(self.message, InversionMessage) and self.message.mechanism == "fused":
            return self.result.grid.rfft(self.message.z)
        return self.result.W_hat


class Relay:
    """Algorithm 1 relayed down a fleet under one exchange mechanism.

    Parameters
    ----------
    estimators : sequence of CollaborativeEstimator
        The vehicles in driving order, all on one :class:`~roadcollab.estimation.grid.SegmentGrid`.
    exchange : Exchange | str
        The mechanism (a name means its defaults).
    rng : numpy.random.Generator | int | None
        Randomness of the mechanism (``Psi`` draws, DP noise).
    guard : sequence of ReceiverGuard | None, optional
        One receiver guard per vehicle (:func:`~roadcollab.collaboration.guard.fleet_guards`; None
        entries allowed): each incoming message is checked before use, implausible bands fall back
        to the receiver's observer, and the step carries the :class:`GuardReport`. Without (None) each
        vehicle's own guard (:meth:`~roadcollab.collaboration.guard.ReceiverGuard.attach`) is used; a
        vehicle that has none refuses the message with a ``ParameterError``.
    unguarded : bool
        The named opt-out: every message applied as the paper's Algorithm 1 does, exactly (the
        reproduction and the Theorem 1 measurement). ``fused`` chains learn nothing from
        the message: there the incoming average is checked the same way, refused bands are
        replaced by the receiver's own inversion and a wholly refused average restarts the chain.

    Examples
    --------
    Three vehicles drive one road segment; Algorithm 1 with Algorithm 2 on every message:

    >>> import numpy as np, roadcollab as rc
    >>> cfg = rc.ExperimentConfig(n_vehicles=3, n_runs=1)
    >>> pipe = rc.FleetPipeline(cfg, rc.sample_fleet(3, cfg.fleet, rng=1))
    >>> road = pipe.road(np.random.default_rng(2))
    >>> ys = rc.simulate_measurements(pipe.estimators, road.velocity, cfg.sensor_noise_std, rng=3)
    >>> steps = rc.Relay(pipe.estimators, rc.Exchange("paper", cfg.obfuscation), rng=4, unguarded=True).run(ys)
    >>> [s.message.mechanism for s in steps]
    ['paper', 'paper', 'paper']
    >>> steps[-1].result.estimate.shape == (cfg.n_samples, 2)   # vehicle 3's road velocity, m/s
    True
    """

    def __init__(self, estimators: Sequence[CollaborativeEstimator], exchange: Exchange | str = "none", *,
                 rng=None, guard: Sequence[ReceiverGuard | None] | None = None, unguarded: bool = False) -> None:
        estimators = list(estimators)
        if not estimators or not all(isinstance(e, CollaborativeEstimator) for e in estimators):
            raise ParameterError("estimators must be a non-empty sequence of CollaborativeEstimator")
        if any(e.grid is not estimators[0].grid for e in estimators):
            raise ParameterError("estimators must share one SegmentGrid")
        self.estimators = estimators
        self.exchange = Exchange(exchange) if isinstance(exchange, str) else exchange
        if not isinstance(self.exchange, Exchange):
            raise ParameterError(f"exchange must be an Exchange or a mechanism name, got {type(exchange).__name__}")
        self.rng = np.random.default_rng(rng)
        self.unguarded = bool(unguarded)
        if self.unguarded and guard is not None:
            raise ParameterError("guard and unguarded=True exclude each other")
        self.guard = None if guard is None else tuple(guard)
        if self.guard is not None and (len(self.guard) != len(estimators) or not all(
                g is None or (isinstance(g, ReceiverGuard) and g.estimator is e) for g, e in zip(self.guard, estimators))):
            raise ParameterError(f"guard must hold one ReceiverGuard (or None) per vehicle, built on that vehicle's "
                                 f"estimator ({len(estimators)} vehicles), got {len(self.guard)} entries")
        self._channels: dict[int, ObfuscationChannel] = {}

    @property
    def grid(self):
        return self.estimators[0].grid

    def channel(self, j: int) -> ObfuscationChannel:
        """Vehicle ``j``'s persistent ``Psi`` draw (``paper_vehicle``), drawn on first use.

        Parameters
        ----------
        j : int
            Index of the vehicle in driving order.

        Returns
        -------
        ObfuscationChannel
        """
        if j not in self._channels:
            est = self.estimators[j]
            self._channels[j] = ObfuscationChannel.draw(est.T_ss, est.S_ss, self.grid, self.exchange.obfuscation,
                                                         rng=self.rng)
        return self._channels[j]

    def send(self, j: int, result: VehicleEstimate, incoming=None) -> RelayStep:
        """Vehicle ``j``'s outgoing message for its estimate ``result``.

        Parameters
        ----------
        j : int
            Position in the fleet (0-based).
        result : VehicleEstimate
            Its estimate on this segment.
        incoming : InversionMessage | None
            The message it received (used by ``fused`` only: the running average).

        Returns
        -------
        RelayStep
        """
        est, mech = self.estimators[j], self.exchange.mechanism
        if mech == "none":
            return RelayStep(result, est.message(result))
        if mech in ("paper", "paper_vehicle"):
            ch = self.channel(j) if mech == "paper_vehicle" else None
            msg, psi1, psi2 = obfuscate_spectra(est.T_ss, est.S_ss, result.E, result.Wf, self.grid,
                                                self.exchange.obfuscation, rng=self.rng, channel=ch)
            return RelayStep(result, msg, psi=(psi1, psi2), make_clear=functools.partial(est.message, result))
        if mech == "hardened":
            return RelayStep(result, est.hardened_message(result))
        if mech in ("fused", "fused_posterior"):
            # Vehicle j has j predecessors: a count above that cannot buy the average more weight.
            return RelayStep(result, est.fused_message(result, incoming, posterior=mech == "fused_posterior",
                                                       max_count=j))
        return RelayStep(result, dp_message(est.hardened_message(result), self.exchange.dp_sigma, rng=self.rng))

    def step(self, j: int, y, incoming=None, *, Y: np.ndarray | None = None) -> RelayStep:
        """Vehicle ``j`` estimates from its record and the incoming message, and sends on.

        Parameters
        ----------
        j : int
            Position in the fleet (0-based).
        y : (N, 2) array_like
            Its measured body-tip accelerations, m/s^2 (ignored if ``Y`` is given).
        incoming : ExchangeMessage | InversionMessage | None
            From vehicle ``j-1`` (None for the first vehicle).
        Y : (K, 2) complex ndarray, optional
            The spectrum of ``y`` on the grid, if already computed.

        Returns
        -------
        RelayStep
        """
        est = self.estimators[j]
        fused = self.exchange.mechanism in ("fused", "fused_posterior")
        # The relay's guards, else the vehicle's own (ReceiverGuard.attach); unguarded: the paper's Algorithm 1.
        guard = (None if self.unguarded or incoming is None else
                 est.guard if self.guard is None else self.guard[j])
        if fused and guard is not None:
            return self._guarded_fused_step(j, y, incoming, Y, guard)
        # The fused chain's estimate is the average itself: Algorithm 1 is not run on it.
        learn_from = None if fused else incoming
        if guard is None:       # without unguarded=True, estimate refuses a message it cannot guard
            return self.send(j, est.estimate(y, learn_from, Y=Y, unguarded=self.unguarded), incoming)
        Y = est.spectrum(y) if Y is None else Y
        assert learn_from is not None   # a guard only with a message, and the fused chain returned above
        Wf, report = guard.feedforward(learn_from, Y)
        return replace(self.send(j, est.estimate(y, Wf=Wf, Y=Y), incoming), guard=report)

    def _guarded_fused_step(self, j: int, y, incoming, Y, guard: ReceiverGuard) -> RelayStep:
        """A fused chain's step with the incoming average checked against the receiver's own
        inversion: refused bands of the average are replaced by that inversion (so the new
        average there is the receiver's own), a wholly refused average restarts the chain."""
        est = self.estimators[j]
        Y = est.spectrum(y) if Y is None else Y
        own = est.invert(Y, posterior=self.exchange.mechanism == "fused_posterior")
        Z, report = guard.substitute(incoming, Y, own)
        incoming = None if report.whole_message_refused else (
            replace(incoming, z=self.grid.irfft(Z)) if report.refused_bands else incoming)
        return replace(self.send(j, est.estimate(y, None, Y=Y), incoming), guard=report)

    def run(self, measurements, *, spectra=None) -> list[RelayStep]:
        """Relay one segment down the whole fleet.

        Parameters
        ----------
        measurements : sequence of (N, 2) array_like
            Each vehicle's record, in driving order (``None`` entries allowed with ``spectra``).
        spectra : sequence of (K, 2) complex ndarray, optional
            Their spectra on the grid (saves one FFT per vehicle when several mechanisms relay
            the same records).

        Returns
        -------
        list of RelayStep
            One per vehicle.
        """
        if len(measurements) != len(self.estimators):
            raise ParameterError(f"measurements must hold one record per vehicle ({len(self.estimators)}), "
                                 f"got {len(measurements)}")
        steps: list[RelayStep] = []
        incoming = None
        for j, y in enumerate(measurements):
            s = self.step(j, y, incoming, Y=None if spectra is None else spectra[j])
            steps.append(s)
            incoming = s.message
        return steps


def simulate_measurements(estimators: Sequence[CollaborativeEstimator], w, noise_std: float, *, rng=None
                          ) -> list[np.ndarray]:
    """Each vehicle's noisy body-tip accelerations on a road, in driving order.

    Parameters
    ----------
    estimators : sequence of CollaborativeEstimator
        The vehicles (their *true* plants are simulated).
    w : (N, 2) array_like
        Road velocity under each wheel, m/s, per sample.
    noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    rng : numpy.random.Generator | int | None
        Noise draws, one vehicle after the other.

    Returns
    -------
    list of (N, 2) ndarray
        m/s^2.
    """
    rng = np.random.default_rng(rng)
    return [add_sensor_noise(simulate_response(e.true_plant, w), noise_std, rng=rng) for e in estimators]
