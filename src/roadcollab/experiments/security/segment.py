"""One segment of the security study: every vehicle's messages on four exchanges, the attacks on them and
what they cost.

A segment is one run of :func:`roadcollab.experiments.security.study.run_attack_study`: a fresh road,
fresh sensor noise and fresh obfuscators for the same fleet. The exchanges run side by side on the same
measurements: in the clear (``none``), Algorithm 2 (``paper``), z only (``hardened``) and z with Gaussian
noise (``dp``, one chain per privacy level). Each vehicle's outgoing messages are attacked, timed and
scored, and :func:`attack_segment` returns it all as one :class:`SegmentAttacks`.

Randomness: the segment's seed spawns, in order, the road, the sensor noise, the obfuscators, the
Gaussian-mechanism noise and the measurements of the "own road" attack; each stream is drawn vehicle by
vehicle in fleet order, so the draws do not depend on how the work is split.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ...collaboration.relay import Exchange, Relay
from ...errors import ParameterError
from ...lti.arx import arx_poles
from ..seeds import RUN_STREAMS, run_stream
from ...lti.batch2x2 import receiver_z
from ...models.simulation import add_sensor_noise, simulate_response
from ...models.vehicle import half_car_model
from ...privacy import baselines
from ...privacy.attacks import (attack_model_reduction, attack_multiplicity, attack_pole_intersection, attack_signals_prior, attack_signals_reduction, pole_errors)
from ...privacy.physical_fit import attack_physical_fit
from ...wire import protocol

if TYPE_CHECKING:  # annotations only
    from ...estimation.grid import SegmentGrid
    from ...wire.message import ExchangeMessage, InversionMessage
    from ..pipeline import FleetPipeline
    from .config import AttackStudyConfig

__all__ = ["SegmentAttacks", "attack_segment", "target_poles", "dp_mse_key", "EXACT_MECHANISMS",
           "TIMED_MECHANISMS"]

#: Exchanges whose estimates are compared with the clear exchange's (exactness).
EXACT_MECHANISMS = ("none", "paper", "hardened")
#: Exchanges timed per message: ``dp`` is the chain of the first privacy level, ``aead`` the sealed hardened message.
TIMED_MECHANISMS = ("none", "paper", "hardened", "dp", "aead")
#: Vehicles (the first ones) whose MSE enters the baselines table.
MSE_VEHICLES = 3
#: Vehicles (the first ones) whose poles and attack estimates the first segment keeps (Figs. 8-10).
EXAMPLE_VEHICLES = 3


@dataclass(frozen=True)
class SegmentAttacks:
    """What one segment contributes to the security study.

    Parameters
    ----------
    pole_errors : tuple of (str, str, ndarray)
        ``(mechanism, attack, errors)`` for every attack made, in the order made; ``errors`` (4,) is the
        relative error of each of the target's poles after Hungarian matching (``inf`` if unmatched).
    features : dict
        Linkability feature (1-D ndarray) per ``(mechanism, vehicle)``, vehicle 0-based.
    max_rel_diff : dict
        Per mechanism of :data:`EXACT_MECHANISMS`: the largest change of any estimate, relative to the
        largest absolute value of the clear exchange's estimate of that vehicle.
    mse : dict
        (3,) MSE of vehicles 1..3, (m/s)^2, per mechanism (``"dp_eps_{epsilon:g}"`` for the DP chains).
    timing_ms : dict
        Per mechanism of :data:`TIMED_MECHANISMS`: wall-clock time of each timed message, ms.
    nbytes : dict
        Per mechanism of :data:`TIMED_MECHANISMS`: encoded size of each timed message, bytes.
    arx_poles : tuple of ndarray
        Per vehicle: poles (rad/s) of an ARX model of the map from its hardened ``z`` to ``w - z``.
    pole_examples : tuple of dict
        First segment only (else empty): per vehicle 1..3, its ``"vehicle"`` number, ``"true"`` poles and the
        poles each attack estimates from its paper message (rad/s).
    dp_sigmas : dict
        Gaussian-mechanism standard deviation of the noise on ``z`` (m/s) per privacy level epsilon.
    last_z : (nfft, 2) ndarray or None
        First segment only: the last vehicle's hardened ``z`` (m/s), what Paillier encrypts.
    """

    pole_errors: tuple[tuple[str, str, np.ndarray], ...]
    features: dict[tuple[str, int], np.ndarray]
    max_rel_diff: dict[str, float]
    mse: dict[str, np.ndarray]
    timing_ms: dict[str, tuple[float, ...]]
    nbytes: dict[str, tuple[int, ...]]
    arx_poles: tuple[np.ndarray, ...]
    pole_examples: tuple[dict, ...]
    dp_sigmas: dict[float, float]
    last_z: np.ndarray | None


def target_poles(pipe) -> list[np.ndarray]:
    """What the attacks aim at: the continuous-time poles (rad/s) of ``S_j = -P_hat_j`` per vehicle.

    Parameters
    ----------
    pipe : roadcollab.experiments.reproduction.study.FleetPipeline
        The study's fleet.

    Returns
    -------
    list of (4,) complex ndarray
        One per vehicle, in fleet order.
    """
    return [e.S_ss.continuous_poles() for e in pipe.estimators]


def dp_mse_key(epsilon: float) -> str:
    """Key of the DP chain of privacy level ``epsilon`` in :attr:`SegmentAttacks.mse`.

    Parameters
    ----------
    epsilon : float
        Privacy level.

    Returns
    -------
    str
        ``"dp_eps_{epsilon:g}"``.
    """
    return f"dp_eps_{epsilon:g}"


@dataclass(frozen=True)
class _Road:
    """A segment's road as the study uses it: the input, the attacker's band-limited copy and the scoring truth."""

    grid: SegmentGrid
    scored: slice
    w: np.ndarray          # (N, 2) road velocity, m/s
    w_band: np.ndarray     # (nfft, 2) band-limited like z, m/s
    truth: np.ndarray      # band-limited road velocity over the scored samples, m/s

    @classmethod
    def of(cls, pipe, cfg, rng) -> _Road:
        """Draw the segment's road from ``rng``."""
        grid = pipe.grid
        w = pipe.road(rng).velocity
        W_true = grid.rfft(w)
        w_band = grid.irfft(grid.reg_weight[:, None] * W_true)
        truth = grid.band_limited(W_true, grid.n_samples)[cfg.scored]
        return cls(grid, cfg.scored, w, w_band, truth)

    def mse(self, W_hat: np.ndarray) -> float:
        """MSE ((m/s)^2) over the scored samples of the estimate with spectrum ``W_hat`` (band-limited like the
        truth)."""
        g = self.grid
        return float(np.mean((g.band_limited(W_hat, g.n_samples)[self.scored] - self.truth) ** 2))


@dataclass(frozen=True)
class _Context:
    """What every step of a segment reads: the fleet, the study, the road and the per-vehicle random streams."""

    pipe: FleetPipeline
    config: AttackStudyConfig
    run: int
    key: bytes
    road: _Road
    noise_rng: np.random.Generator
    own_rng: np.random.Generator

    @property
    def physical_fit(self) -> bool:
        """Whether this segment makes the (slow) physical-fit attacks."""
        return self.run < self.config.physical_fit_runs


@dataclass(eq=False)
class _Chains:
    """The relays of every exchange and the message each last sent (the next vehicle's input)."""

    relays: dict[str, Relay]
    dp_relays: dict[float, Relay]
    plain: ExchangeMessage | None = None
    paper: ExchangeMessage | None = None
    hard: InversionMessage | None = None
    dp: dict = field(default_factory=dict)
    own_proxy: np.ndarray | None = None   # vehicle 1's inversion of its own record, (nfft, 2) m/s

    @classmethod
    def open(cls, pipe, config: AttackStudyConfig, sigmas: dict, priv_rng, dp_rng) -> _Chains:
        """Relays of the clear, paper, hardened and DP exchanges (the paper's obfuscators from ``priv_rng``)."""
        ests, cfg = pipe.estimators, config.experiment
        relays = {"none": Relay(ests, "none", unguarded=True),
                  "paper": Relay(ests, Exchange("paper", cfg.obfuscation), rng=priv_rng, unguarded=True),
                  "hardened": Relay(ests, "hardened", unguarded=True)}
        dp_relays = {e: Relay(ests, Exchange("dp", dp_sigma=sigmas[e]), rng=dp_rng, unguarded=True)
                     for e in config.dp_epsilons}
        return cls(relays, dp_relays, dp={e: None for e in config.dp_epsilons})


@dataclass(eq=False)
class _Recorder:
    """Collects a segment's measurements while its vehicles are processed; :meth:`result` freezes them."""

    targets: list[np.ndarray]
    mse: dict[str, np.ndarray]
    errors: list = field(default_factory=list)
    features: dict = field(default_factory=dict)
    exact: dict = field(default_factory=lambda: {m: 0.0 for m in EXACT_MECHANISMS})
    timing: dict = field(default_factory=lambda: {m: [] for m in TIMED_MECHANISMS})
    nbytes: dict = field(default_factory=lambda: {m: [] for m in TIMED_MECHANISMS})
    arx: list = field(default_factory=list)
    examples: list = field(default_factory=list)
    last_z: np.ndarray | None = None

    def attack(self, mechanism: str, attack: str, poles, j: int) -> None:
        """Score an attack's pole estimate (rad/s) against vehicle ``j``'s target."""
        self.errors.append((mechanism, attack, pole_errors(poles, self.targets[j])))

    def timed(self, mechanism: str, send, *args):
        """Call ``send(*args) -> (message, encoded bytes)``, recording its time and size; returns the message."""
        t0 = time.perf_counter()
        msg, data = send(*args)
        self.timing[mechanism].append((time.perf_counter() - t0) * 1e3)
        self.nbytes[mechanism].append(len(data))
        return msg

    def worst_change(self, mechanism: str, estimate: np.ndarray, clear: np.ndarray, scale: float) -> None:
        """Keep the largest change of ``estimate`` from the clear one, relative to ``scale``."""
        self.exact[mechanism] = max(self.exact[mechanism], float(np.max(np.abs(estimate - clear))) / scale)

    def result(self, sigmas: dict[float, float]) -> SegmentAttacks:
        """The frozen record of the segment."""
        return SegmentAttacks(
            pole_errors=tuple(self.errors), features=self.features, max_rel_diff=self.exact, mse=self.mse,
            timing_ms={m: tuple(v) for m, v in self.timing.items()},
            nbytes={m: tuple(v) for m, v in self.nbytes.items()}, arx_poles=tuple(self.arx),
            pole_examples=tuple(self.examples), dp_sigmas=sigmas, last_z=self.last_z)


def _measure(est, w: np.ndarray, noise_std: float, rng) -> np.ndarray:
    """A vehicle's noisy accelerometer record (m/s^2) over the road velocity ``w``."""
    return add_sensor_noise(simulate_response(est.true_plant, w), noise_std, rng=rng)


def _send_encoded(relay: Relay, j: int, result) -> tuple:
    """Vehicle ``j``'s message on ``relay`` and its encoding: what is timed per message."""
    message = relay.send(j, result).message
    return message, protocol.encode(message)


def _send_sealed(relay: Relay, j: int, result, key: bytes) -> tuple:
    """``(None, sealed bytes)``: vehicle ``j``'s encoded message on ``relay`` under ChaCha20-Poly1305."""
    return None, baselines.seal(key, protocol.encode(relay.send(j, result).message))


def _exchanges(ctx: _Context, chains: _Chains, rec: _Recorder, j: int, y: np.ndarray) -> tuple:
    """Vehicle ``j``'s estimates and timed messages on the clear, paper and hardened exchanges, their
    exactness and MSE; returns the three messages."""
    est, relays, road = ctx.pipe.estimators[j], chains.relays, ctx.road
    res = est.estimate(y, chains.plain, unguarded=True)
    scale = max(float(np.max(np.abs(res.estimate))), 1e-300)
    plain = rec.timed("none", _send_encoded, relays["none"], j, res)
    rp = est.estimate(y, chains.paper, unguarded=True)
    paper = rec.timed("paper", _send_encoded, relays["paper"], j, rp)
    if j == 0:
        chains.own_proxy = road.grid.irfft(est.invert(road.grid.rfft(y)))
    rh = est.estimate(y, chains.hard, unguarded=True)
    hard = rec.timed("hardened", _send_encoded, relays["hardened"], j, rh)
    rec.timed("aead", _send_sealed, relays["hardened"], j, rh, ctx.key)
    rec.worst_change("paper", rp.estimate, res.estimate, scale)
    rec.worst_change("hardened", rh.estimate, res.estimate, scale)
    if j < MSE_VEHICLES:
        rec.mse["none"][j], rec.mse["paper"][j], rec.mse["hardened"][j] = (road.mse(res.W_hat), road.mse(rp.W_hat),
                                                                           road.mse(rh.W_hat))
    return plain, paper, hard


def _dp_chains(ctx: _Context, chains: _Chains, rec: _Recorder, j: int, y: np.ndarray) -> None:
    """Differential privacy: the hardened chain with Gaussian noise on every z sent, one chain per epsilon,
    and the strongest signal attack on each noisy z (the privacy/accuracy trade-off)."""
    est, road, config = ctx.pipe.estimators[j], ctx.road, ctx.config
    eps_list = tuple(config.dp_epsilons)
    for e in eps_list:
        rd = est.estimate(y, chains.dp[e], unguarded=True)
        if e == eps_list[0]:
            chains.dp[e] = rec.timed("dp", _send_encoded, chains.dp_relays[e], j, rd)
        else:
            chains.dp[e] = chains.dp_relays[e].send(j, rd).message
        if j < MSE_VEHICLES:
            rec.mse[dp_mse_key(e)][j] = road.mse(rd.W_hat)
        if ctx.physical_fit:
            rec.attack(f"dp(eps={e:g})", "physical_fit",
                       attack_physical_fit(chains.dp[e].z, road.w_band, road.grid, config.experiment.fleet.nominal), j)


def _message_attacks(ctx: _Context, rec: _Recorder, j: int, plain, paper) -> dict[str, np.ndarray]:
    """The attacks on vehicle ``j``'s clear and paper messages; returns their estimates from the paper's."""
    prior = ctx.config.prior
    for mech, msg in (("none", plain), ("paper", paper)):
        est_poles = {"model_reduction": attack_model_reduction(msg),
                     "pole_intersection": attack_pole_intersection(msg, prior),
                     "multiplicity": attack_multiplicity(msg, prior)}
        for attack, poles in est_poles.items():
            rec.attack(mech, attack, poles, j)
    return est_poles


def _hardened_attacks(ctx: _Context, rec: _Recorder, j: int, hard) -> None:
    """Signal attacks on vehicle ``j``'s hardened z (given the true road), and its ARX poles for the
    multiplicity attack across segments."""
    road, prior = ctx.road, ctx.config.prior
    dt = road.grid.dt
    rec.attack("hardened", "model_reduction", attack_signals_reduction(hard.z, road.w_band, dt), j)
    rec.attack("hardened", "pole_intersection", attack_signals_prior(hard.z, road.w_band, dt, prior), j)
    rec.arx.append(arx_poles(hard.z, road.w_band - hard.z, dt, 8, 2))


def _physical_fit_attacks(ctx: _Context, rec: _Recorder, j: int, hard, paper) -> None:
    """The physical-fit attacks on vehicle ``j``'s hardened z (with and without the true road) and on the z
    a receiver recovers from its paper message."""
    cfg, road = ctx.config.experiment, ctx.road
    grid, nominal = road.grid, cfg.fleet.nominal
    rec.attack("hardened", "physical_fit", attack_physical_fit(hard.z, road.w_band, grid, nominal), j)
    # Without the true road: the next vehicle's own inversion stands in for it.
    if j + 1 < cfg.n_vehicles:
        nxt = ctx.pipe.estimators[j + 1]
        y_next = _measure(nxt, road.w, cfg.sensor_noise_std, ctx.own_rng)
        own = grid.irfft(nxt.invert(grid.rfft(y_next)))
        rec.attack("hardened", "physical_fit_own_road", attack_physical_fit(hard.z, own, grid, nominal), j)
    # Any exact mechanism hands the receiver z (Theorem 1): recover it from the
    # obfuscated message and attack it the same way.
    z_paper = grid.irfft(_recover_z(paper, grid))
    rec.attack("paper", "physical_fit", attack_physical_fit(z_paper, road.w_band, grid, nominal), j)


def _record_features(ctx: _Context, chains: _Chains, rec: _Recorder, j: int, plain, paper_poles: np.ndarray,
                     hard) -> None:
    """Vehicle ``j``'s linkability feature on each exchange."""
    grid, w_band = ctx.road.grid, ctx.road.w_band
    rec.features[("none", j)] = _feature_poles(plain.S.continuous_poles())
    rec.features[("paper", j)] = _feature_poles(paper_poles)
    rec.features[("hardened", j)] = _spectral_feature(hard.z, w_band, grid)
    # A receiver without the true road compares with its own inversion (vehicle 1's
    # inversion stands in for a fixed receiver's here).
    if chains.own_proxy is None:         # set on vehicle 1, before any feature is recorded
        raise ParameterError("vehicle 1's own inversion is missing: the segment's vehicles ran out of order")
    rec.features[("hardened_own_road", j)] = _spectral_feature(hard.z, chains.own_proxy, grid)


def _vehicle(ctx: _Context, chains: _Chains, rec: _Recorder, j: int) -> None:
    """Everything vehicle ``j`` contributes: its messages on every exchange and the attacks on them."""
    cfg = ctx.config.experiment
    y = _measure(ctx.pipe.estimators[j], ctx.road.w, cfg.sensor_noise_std, ctx.noise_rng)
    plain, paper, hard = _exchanges(ctx, chains, rec, j, y)
    _dp_chains(ctx, chains, rec, j, y)
    paper_poles = _message_attacks(ctx, rec, j, plain, paper)
    if ctx.run == 0 and j < EXAMPLE_VEHICLES:
        rec.examples.append({"vehicle": j + 1, "true": rec.targets[j], **paper_poles})
    _hardened_attacks(ctx, rec, j, hard)
    if ctx.physical_fit:
        _physical_fit_attacks(ctx, rec, j, hard, paper)
    # Reference: what the attacker knows with no message at all (the fleet's nominal).
    rec.attack("no_message", "prior_guess", _nominal_poles(cfg.fleet.nominal), j)
    _record_features(ctx, chains, rec, j, plain, paper_poles["multiplicity"], hard)
    chains.plain, chains.paper, chains.hard = plain, paper, hard
    if ctx.run == 0 and j == cfg.n_vehicles - 1:
        rec.last_z = hard.z


def attack_segment(pipe, config: AttackStudyConfig, r: int, rs: np.random.SeedSequence, key: bytes
                   ) -> SegmentAttacks:
    """Everything one segment contributes to the security study.

    Parameters
    ----------
    pipe : roadcollab.experiments.reproduction.study.FleetPipeline
        The study's fleet, grid and road model.
    config : AttackStudyConfig
        The study.
    r : int
        Segment number (0-based): segment 0 keeps the pole examples and the z Paillier encrypts, segments
        below ``config.physical_fit_runs`` make the physical-fit attacks.
    rs : numpy.random.SeedSequence
        The segment's seed.
    key : bytes
        ChaCha20-Poly1305 key of the AEAD baseline.

    Returns
    -------
    SegmentAttacks
    """
    cfg = config.experiment
    eps_list = tuple(config.dp_epsilons)
    targets = target_poles(pipe)
    sens = baselines.l2_sensitivity(pipe.estimators[0], config.dp_rho)
    sigmas = {e: baselines.gaussian_sigma(e, config.dp_delta, sens) for e in eps_list}
    road_ss, noise_ss, priv_ss, dp_ss, own_ss = (run_stream(rs, name) for name in RUN_STREAMS)
    road = _Road.of(pipe, cfg, np.random.default_rng(road_ss))
    noise_rng, priv_rng, dp_rng, own_rng = (np.random.default_rng(s) for s in (noise_ss, priv_ss, dp_ss, own_ss))
    ctx = _Context(pipe, config, r, key, road, noise_rng, own_rng)
    chains = _Chains.open(pipe, config, sigmas, priv_rng, dp_rng)
    mse_keys = list(EXACT_MECHANISMS) + [dp_mse_key(e) for e in eps_list]
    rec = _Recorder(targets, {m: np.zeros(MSE_VEHICLES) for m in mse_keys})
    for j in range(len(pipe.estimators)):
        _vehicle(ctx, chains, rec, j)
    return rec.result(sigmas)


def _feature_poles(poles: np.ndarray) -> np.ndarray:
    """(f1, zeta1, f2, zeta2) of the two upper-half-plane poles sorted by frequency."""
    up = sorted([p for p in poles if p.imag > 0], key=abs)[:2]
    if len(up) < 2:
        return np.full(4, np.nan)
    return np.array([v for p in up for v in (np.log(abs(p) / (2 * np.pi)), -p.real / abs(p))])


def _spectral_feature(z: np.ndarray, w_band: np.ndarray, grid, n_bands: int = 12) -> np.ndarray:
    """Log band-averaged |W - Z|^2 / |Z|^2 per track: the vehicle's model-error signature."""
    Z, W = grid.rfft(z), grid.rfft(w_band)
    edges = np.geomspace(0.6, 50.0, n_bands + 1)
    out = []
    for c in range(2):
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = (grid.freqs >= lo) & (grid.freqs < hi)
            num = np.sum(np.abs(W[sel, c] - Z[sel, c]) ** 2)
            den = np.sum(np.abs(Z[sel, c]) ** 2)
            out.append(np.log(max(num, 1e-300) / max(den, 1e-300)))
    return np.array(out)


def _recover_z(message, grid) -> np.ndarray:
    """What a receiver computes from an (obfuscated) exchange message: W T^-1 (e - S w^f)."""
    act = grid.active
    om = grid.omega_dt[act]
    T, S = message.T.frequency_response(om), message.S.frequency_response(om)
    Z = np.zeros((grid.n_bins, 2), complex)
    E, Wf = grid.rfft(message.e)[act], grid.rfft(message.wf)[act]
    Z[act] = receiver_z(T, S, E, Wf, grid.reg_weight[act])
    return Z


def _nominal_poles(nominal) -> np.ndarray:
    """Continuous-time poles (rad/s) of the fleet's nominal half car: the attacker's guess without a message."""
    return half_car_model(nominal).poles()
