"""Algorithm 1: offline collaborative estimation relayed from vehicle to vehicle.

Vehicle ``j`` traverses the segment, records ``y_j``, and runs its own estimator
``D_j`` (:mod:`roadcollab.estimation.estimator`). It then receives ``(T_{j-1}, S_{j-1}, e_{j-1},
w^f_{j-1})`` from vehicle ``j-1`` and forms

.. math::

    w^f_j = L_1 w^f_{j-1} + L_2 e_{j-1},\\qquad
    \\hat w_j = D_j y_j + w^f_j,\\qquad
    e_j = y_j - \\hat P_j \\hat w_j = T_j w + S_j w^f_j (+\\text{noise}),

with ``T_j = (I - P_hat_j D_j) P_hat_j``, ``S_j = -P_hat_j`` from the vehicle's *nominal*
model (it cannot know its true plant; ``oracle=True`` uses the true plant for analysis) and
the optimal learning filters (eqs. 11-12), regularised at DC by the weight ``W`` (``W_reg``) of
:class:`~roadcollab.estimation.grid.SegmentGrid`:

.. math::

    L_1 = W S_j^{-1} T_j T_{j-1}^{-1} S_{j-1},\\qquad
    L_2 = -W S_j^{-1} T_j T_{j-1}^{-1}.

Equivalently ``w^f_j = -S_j^{-1} T_j z_{j-1}`` with
``z_{j-1} = W T_{j-1}^{-1}(e_{j-1} - S_{j-1} w^f_{j-1})``, which with nominal ``T`` equals
``W P_hat_{j-1}^{-1} y_{j-1}``: Algorithm 1 blends the vehicle's own observer (its low band)
with the previous vehicle's offline model inversion (tested in ``tests/test_collaborative.py``).
Vehicle 1 has ``w^f = 0``.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from .._validation import check_signal, freeze
from ..errors import MessageError, ParameterError
from ..estimation.estimator import JDPNoise, RoadInputEstimator, build_road_input_estimator
from ..collaboration.fusion import DESIGN_SEED, posterior_responses
from ..wire.message import ExchangeMessage, InversionMessage
from ..lti.realisation import StateSpaceData, SystemCache, minreal, series
from ..models.simulation import DiscretePlant, discretize_plant
from ..estimation.grid import SegmentGrid
from ..lti.batch2x2 import inv2x2, matmul, matvec, receiver_z
from ..lti.kernels import kernel_path
from ..lti.response import FrequencyResponseCache
from ..models.vehicle import FleetSpec, Vehicle
from .vehicle_estimate import VehicleEstimate

if TYPE_CHECKING:
    from .guard import ReceiverGuard

__all__ = ["VehicleEstimate", "CollaborativeEstimator", "learning_filters"]


def learning_filters(T_j, S_j, T_prev, S_prev, weight):
    """Optimal learning filters of eqs. 11-12 on a grid, band-limited by ``weight``.

    Parameters
    ----------
    T_j, S_j, T_prev, S_prev : (K, 2, 2) complex ndarray
        Frequency responses on the active bins.
    weight : (K,) ndarray
        Band weight ``W`` on those bins.

    Returns
    -------
    L1, L2 : (K, 2, 2) complex ndarray
    """
    G = -matmul(inv2x2(S_j), T_j, inv2x2(T_prev)) * weight[:, None, None]   # = L2
    return -matmul(G, S_prev), G


class CollaborativeEstimator:
    """Vehicle ``j``'s side of Algorithm 1 on a fixed segment grid.

    Everything that does not depend on the measured data (the Lemma 1 gain, the
    discretisations, the frequency responses of ``D_j``, ``P_hat_j``, ``T_j``, ``S_j`` and
    their realisations) is built once here, as on a car that drives segment after segment.

    Parameters
    ----------
    vehicle : Vehicle
    noise : JDPNoise
        Road and sensor statistics for the Lemma 1 design.
    grid : SegmentGrid
    gamma : float
        Observer parameter of eq. 4.
    oracle : bool
        Use the true plant in ``T_j``, ``S_j`` and ``e_j`` (analysis only).
    fleet : FleetSpec, optional
        The fleet distribution the vehicle's parameter estimate came from. Needed only for the
        posterior inversion (``invert(..., posterior=True)``), which inverts ``E[P | theta_hat]``
        instead of the nominal ``P_hat``.

    Examples
    --------
    Vehicle 2 refines its estimate with vehicle 1's message (the relay runs this down a fleet,
    :class:`~roadcollab.collaboration.relay.Relay`):

    >>> import numpy as np
    >>> import roadcollab as rc
    >>> cfg = rc.ExperimentConfig(n_vehicles=2, segment_length=60.0)
    >>> first, second = rc.FleetPipeline(cfg, rc.sample_fleet(2, cfg.fleet, rng=1)).estimators
    >>> ys = rc.simulate_measurements([first, second], np.zeros((cfg.n_samples, 2)), 0.05, rng=2)
    >>> r1 = first.estimate(ys[0])                      # vehicle 1: its own observer
    >>> r2 = second.estimate(ys[1], first.message(r1), unguarded=True)  # the paper's Algorithm 1
    >>> r2.estimate.shape == (cfg.n_samples, 2)
    True

    Without ``unguarded=True`` the message goes through the vehicle's receiver guard
    (``ReceiverGuard(...).attach()``); with none attached it is refused (``ParameterError``).
    """

    def __init__(self, vehicle: Vehicle, noise: JDPNoise, grid: SegmentGrid, *, gamma: float,
                 oracle: bool = False, fleet: FleetSpec | None = None) -> None:
        if not isinstance(vehicle, Vehicle):
            raise ParameterError(f"vehicle must be a Vehicle, got {type(vehicle).__name__}")
        if not isinstance(grid, SegmentGrid):
            raise ParameterError(f"grid must be a SegmentGrid, got {type(grid).__name__}")
        self.vehicle = vehicle
        self.grid = grid
        self.oracle = bool(oracle)
        self.fleet = fleet
        dt = grid.dt
        self.estimator: RoadInputEstimator = build_road_input_estimator(
            vehicle.nominal_model, noise, gamma=gamma, dt=dt)
        self.true_plant: DiscretePlant = discretize_plant(vehicle.true_model, dt)
        self.model_plant: DiscretePlant = (self.true_plant if self.oracle
                                           else discretize_plant(vehicle.nominal_model, dt))
        om = grid.omega_dt
        self.D_f = self.estimator.frequency_response(om)            # (K, 2, 2)
        self.P_f = self.model_plant.frequency_response(om)         # P_hat_j (or P_j if oracle)
        eye = np.eye(2)
        self.T_f = matmul(eye - matmul(self.P_f, self.D_f), self.P_f)
        self.S_f = -self.P_f
        act = grid.active_index
        self._act = act
        self._w_act = grid.reg_weight[act]
        # -S_j^-1 T_j = P_hat^-1 (I - P_hat D) P_hat = (I - D P_hat): the map z_{j-1} -> w^f_j.
        self._minus_Sinv_T = -matmul(inv2x2(self.S_f[act]), self.T_f[act])
        self._W_Pinv = self._w_act[:, None, None] * inv2x2(self.P_f[act])     # z = W P_hat^-1 y
        self.T_ss, self.S_ss = self._realisations()
        # Responses of the sent realisations: obfuscator and receiver use exactly these (round-off only).
        self.T_ss_f = self.T_ss.frequency_response(om[act])
        self.S_ss_f = self.S_ss.frequency_response(om[act])
        self._offset = self.estimator.steady_offset()
        # A sender's unchanged clear T and S are evaluated (and certified, when decoded with
        # ``protocol.decode(data, systems=self.system_cache)``) once per receiver, not per segment.
        self.response_cache = FrequencyResponseCache()
        self.system_cache = SystemCache()
        self.guard: ReceiverGuard | None = None   # set by ReceiverGuard.attach; None: refused unless unguarded

    # -- realisations sent to the next vehicle ------------------------------------------------
    def _realisations(self) -> tuple[StateSpaceData, StateSpaceData]:
        """Minimal discrete realisations of ``T_j`` and ``S_j``.

        .. code-block:: text

            T = (I - P D) P :  u -> P -> [I - P D] -> y,  with  I - P D = I + (-P) o D
        """
        p = self.model_plant
        dt = self.grid.dt
        P = StateSpaceData(p.Ad, p.Bd, p.C, p.D, dt)
        e = self.estimator
        Dj = StateSpaceData(e.Ad, e.Bd, e.Cd, e.Dd, dt)
        PD = series(Dj, P)
        I_minus_PD = StateSpaceData(PD.A, PD.B, -PD.C, np.eye(2) - PD.D, dt)
        T_full = series(P, I_minus_PD)
        T = minreal(T_full, tol=1e-9)
        S = StateSpaceData(p.Ad.copy(), p.Bd.copy(), -p.C, -p.D, dt)
        freeze(T.A, T.B, T.C, T.D, S.A, S.B, S.C, S.D)     # own arrays, frozen: memos found by identity
        return T, S

    # -- per-segment work ---------------------------------------------------------------------
    def spectrum(self, y) -> np.ndarray:
        """Zero-padded spectrum of a measured window.

        Parameters
        ----------
        y : (N, 2) array_like
            Body-tip accelerations on this segment, m/s^2; ``N`` is the grid's window.

        Returns
        -------
        (K, 2) complex ndarray
        """
        y = check_signal("y", y, 2)
        if y.shape[0] != self.grid.n_samples:
            raise ParameterError(f"y must have {self.grid.n_samples} samples (the segment grid), got {y.shape[0]}")
        return self.grid.rfft(y)

    def wf_from_z(self, Z: np.ndarray) -> np.ndarray:
        """``w^f_j = -S_j^-1 T_j z`` for a band-limited road-input spectrum.

        Parameters
        ----------
        Z : (K, 2) complex ndarray
            Spectrum of ``z`` (m/s) on the grid.

        Returns
        -------
        (K, 2) complex ndarray
            ``w^f_j``, zero outside the active bins.
        """
        Wf = np.zeros_like(Z)
        Wf[self._act] = matvec(self._minus_Sinv_T, Z[self._act])
        return Wf

    @functools.cached_property
    def posterior_responses(self) -> np.ndarray:
        """Plausible true plants given this vehicle's estimate, (n, K_active, 2, 2) (see
        :func:`roadcollab.collaboration.fusion.posterior_responses`); needs ``fleet``."""
        if self.fleet is None:
            raise ParameterError("the posterior inversion needs the fleet distribution: pass fleet= to "
                                 "CollaborativeEstimator")
        return posterior_responses(self.vehicle.estimated_params, self.grid, self.fleet,
                                   rng=[DESIGN_SEED, self.vehicle.index])

    @functools.cached_property
    def _W_Pbar_inv(self) -> np.ndarray:
        return self._w_act[:, None, None] * inv2x2(self.posterior_responses.mean(axis=0))

    def invert(self, Y: np.ndarray, *, posterior: bool = False) -> np.ndarray:
        """Band-limited offline model inversion ``z_j = W P_hat_j^-1 y_j`` (spectrum).

        Parameters
        ----------
        Y : (K, 2) complex ndarray
            Record spectrum on the grid.
        posterior : bool
            Invert the posterior-mean plant ``E[P | theta_hat]`` (needs ``fleet``) instead of the
            nominal ``P_hat``.

        Returns
        -------
        (K, 2) complex ndarray
            Road-velocity spectrum, zero outside the active bins.
        """
        Z = np.zeros_like(Y)
        Z[self._act] = matvec(self._W_Pbar_inv if posterior else self._W_Pinv, Y[self._act])
        return Z

    def _check_grid(self, message) -> None:
        g = self.grid
        if message.n_samples != g.n_samples or message.sample_rate != g.sample_rate:
            raise MessageError(f"message is for a grid of {message.n_samples} samples at {message.sample_rate} Hz, "
                               f"this vehicle uses {g.n_samples} at {g.sample_rate} Hz")

    def received_z(self, message: ExchangeMessage | InversionMessage) -> np.ndarray:
        """What a message implies: ``z_{j-1} = W T_{j-1}^-1 (e_{j-1} - S_{j-1} w^f_{j-1})`` on the active bins.

        For an :class:`InversionMessage` it is the spectrum of the sent ``z``. A hostile but
        well-formed message may make it huge or non-finite; the receiver guard
        (:mod:`roadcollab.collaboration.guard`) checks it before use.

        Parameters
        ----------
        message : ExchangeMessage | InversionMessage
            From vehicle ``j - 1``, on this vehicle's grid.

        Returns
        -------
        (K_active, 2) complex ndarray
            m/s per bin of the unnormalised DFT.

        Raises
        ------
        MessageError
            If the message does not fit this vehicle's grid.
        """
        g = self.grid
        act = self._act
        if isinstance(message, InversionMessage):
            if message.z.shape != (g.nfft, 2):
                raise MessageError(f"message z must have shape ({g.nfft}, 2) on this segment grid, "
                                   f"got {message.z.shape}")
            self._check_grid(message)
            return g.rfft(message.z)[act]
        if message.e.shape != (g.nfft, 2) or message.wf.shape != (g.nfft, 2):
            raise MessageError(f"message signals must have shape ({g.nfft}, 2) on this segment grid, "
                               f"got {message.e.shape} and {message.wf.shape}")
        self._check_grid(message)
        om = g.omega_active
        S_prev = self.response_cache.response(message.S, om)
        E_prev = g.rfft(message.e)[act]
        Wf_prev = g.rfft(message.wf)[act]
        # L1 w^f + L2 e = (-S_j^-1 T_j) W T_prev^-1 (e - S_prev w^f): eqs. 11-12 in factored form, matrix-vector
        # products only (3x faster than forming L1 and L2; ``learning_filters`` does, the tests check both agree).
        with np.errstate(all="ignore"):     # a hostile T may be singular: inf/NaN are the guard's to judge
            compiled = kernel_path() == "compiled"      # then T^-1 inline in one pass (round-off apart)
            T = self.response_cache.response(message.T, om, inverse=not compiled)
            return receiver_z(T if compiled else None, S_prev, E_prev, Wf_prev, self._w_act, T_inv=None if compiled else T)

    def wf_from_active_z(self, z: np.ndarray) -> np.ndarray:
        """``w^f_j = -S_j^-1 T_j z`` from ``z`` on the active bins (see :meth:`received_z`).

        Parameters
        ----------
        z : (K_active, 2) complex ndarray
            Road-velocity spectrum on the active bins, m/s.

        Returns
        -------
        (K, 2) complex ndarray
            ``w^f_j`` on every bin (zero outside the active ones).
        """
        Wf = np.zeros((self.grid.n_bins, 2), complex)
        Wf[self._act] = matvec(self._minus_Sinv_T, z)
        return Wf

    def learn(self, message: ExchangeMessage | InversionMessage) -> np.ndarray:
        """Learning update (eqs. 11-12): ``w^f_j = L1 w^f_{j-1} + L2 e_{j-1}`` (spectrum).

        For an :class:`InversionMessage` (hardened or fused exchange) the update is
        ``w^f_j = -S_j^-1 T_j z``, identical to the optimal filters applied to ``(T, S, e, w^f)``.
        No plausibility check here: :class:`~roadcollab.collaboration.guard.ReceiverGuard` does it before use.

        Parameters
        ----------
        message : ExchangeMessage | InversionMessage
            From vehicle ``j - 1``, on this vehicle's grid.

        Returns
        -------
        (K, 2) complex ndarray
            ``w^f_j`` (spectrum).

        Raises
        ------
        MessageError
            If the message does not fit this vehicle's grid.
        """
        return self.wf_from_active_z(self.received_z(message))

    def estimate(self, y, message: ExchangeMessage | InversionMessage | None = None, *, Wf: np.ndarray | None = None,
                 Y: np.ndarray | None = None, unguarded: bool = False, sender=None) -> VehicleEstimate:
        """Run Algorithm 1 for this vehicle on one segment, the received message through the guard.

        A received message is applied only through the vehicle's receiver guard (``self.guard``, set by
        :meth:`~roadcollab.collaboration.guard.ReceiverGuard.attach`): a well-formed message can say
        anything (``z x 1e6`` cost 2.6e10 x, issue 20). ``unguarded=True`` is the named opt-out: the
        paper's exact Algorithm 1 (eqs. 11-12), for the reproduction and the Theorem 1 measurement.

        Parameters
        ----------
        y : (N, 2) array_like
            Measured body-tip accelerations, m/s^2.
        message : ExchangeMessage | InversionMessage | None
            From vehicle ``j-1``; None for vehicle 1 (``w^f = 0``).
        Wf : (K, 2) ndarray, optional
            A feed-forward spectrum computed elsewhere (e.g. the fused estimate); overrides
            ``message``.
        Y : (K, 2) complex ndarray, optional
            The spectrum of ``y`` on the grid, if already computed (``y`` is then not used).
        unguarded : bool
            Apply ``message`` without the guard: the paper's exact Algorithm 1.
        sender : hashable, optional
            Who sent ``message`` (an authenticated identity): the guard keeps its record across segments.

        Returns
        -------
        VehicleEstimate

        Raises
        ------
        ParameterError
            If a message is given, no guard is attached and ``unguarded`` is not set.
        """
        if Y is None:
            Y = self.spectrum(y)
        elif Y.shape != (self.grid.n_bins, 2):
            raise ParameterError(f"Y must have shape ({self.grid.n_bins}, 2), got {Y.shape}")
        DY = matvec(self.D_f, Y)
        if Wf is None and message is not None and not unguarded and self.guard is None:
            raise ParameterError(f"vehicle {self.vehicle.index} received a message but has no receiver guard: "
                                 f"attach one (ReceiverGuard(...).attach(), fleet_guards(..., attach=True)) "
                                 f"or pass unguarded=True to apply it as the paper's Algorithm 1 does")
        if Wf is None:
            guard = self.guard      # not None unless unguarded (refused above)
            Wf = (np.zeros_like(Y) if message is None else self.learn(message) if unguarded or guard is None
                  else guard.feedforward(message, Y, sender=sender)[0])
        return VehicleEstimate(W_obs=DY, W_hat=DY + Wf, Wf=Wf, Y=Y, P_f=self.P_f, grid=self.grid,
                               offset=self._offset)

    def hardened_message(self, result: VehicleEstimate) -> InversionMessage:
        """The hardened message: ``z_j = W P_hat_j^-1 y_j`` only (no dynamics).

        Parameters
        ----------
        result : VehicleEstimate
            This vehicle's estimate on the segment.

        Returns
        -------
        InversionMessage
        """
        g = self.grid
        return InversionMessage(mechanism="hardened", sample_rate=g.sample_rate, n_samples=g.n_samples,
                                z=g.irfft(self.invert(result.Y)), count=1)

    def fused_message(self, result: VehicleEstimate, incoming: InversionMessage | None, *,
                      posterior: bool = False, max_count: int | None = None) -> InversionMessage:
        """Running fleet average of ``z`` including this vehicle (the fused estimate).

        Parameters
        ----------
        result : VehicleEstimate
            This vehicle's estimate on the segment (for its record spectrum).
        incoming : InversionMessage | None
            The running average of the vehicles before (None for the first).
        posterior : bool
            Average posterior inversions (see :meth:`invert`).
        max_count : int, optional
            Vehicles that can have driven the segment before this one (its place in the relay):
            the incoming average weighs at most this much, whatever its ``count`` claims.

        Returns
        -------
        InversionMessage
            ``mechanism == "fused"``, ``count`` = vehicles averaged.
        """
        g = self.grid
        z, weight = g.irfft(self.invert(result.Y, posterior=posterior)), 0
        if incoming is not None:
            if incoming.mechanism != "fused" or incoming.z.shape != z.shape:
                raise MessageError(f"expected a fused message with z of shape {z.shape}, got "
                                   f"{incoming.mechanism!r} with {incoming.z.shape}")
            self._check_grid(incoming)
            weight = incoming.count if max_count is None else min(incoming.count, max_count)
            z = (weight * incoming.z + z) / (weight + 1)
        return InversionMessage(mechanism="fused", sample_rate=g.sample_rate, n_samples=g.n_samples, z=z,
                                count=weight + 1)

    def message(self, result: VehicleEstimate) -> ExchangeMessage:
        """The plain message ``(T_j, S_j, e_j, w^f_j)`` of Algorithm 1.

        Parameters
        ----------
        result : VehicleEstimate
            This vehicle's estimate on the segment.

        Returns
        -------
        ExchangeMessage
        """
        g = self.grid
        return ExchangeMessage(mechanism="none", sample_rate=g.sample_rate, n_samples=g.n_samples,
                               T=self.T_ss, S=self.S_ss, e=g.irfft(result.E), wf=g.irfft(result.Wf))
