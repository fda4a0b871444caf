"""One malicious vehicle against the fleet's fused estimate and anomaly map.

Per run, every vehicle of the fleet sends its own posterior inversion
``z_i = W E[P_i | theta_hat_i]^-1 y_i`` (a ``hardened`` message, as the ``fused_posterior``
contributions) to a fusion node; vehicle ``malicious`` (0-based) sends something else instead.
Two fusion nodes are compared on the same messages:

- ``mean``: the plain average, weighted by each message's ``count`` (what the relayed
  ``fused_posterior`` average does), anomalies detected in it and reported as they are;
- ``robust``: :class:`~roadcollab.collaboration.robust_fusion.RobustFusion` (its default rule) over the
  messages it accepts, anomalies reported only when corroborated by
  :func:`~roadcollab.detection.corroboration.min_votes_for` ``(n)`` vehicles' own detections (pooling
  colluders: :mod:`.collusion`).

- ``secagg_guarded``: secure aggregation (:mod:`roadcollab.privacy.secure_aggregation`): nobody sees
  an individual input, so no robust combination is possible; what is kept is the clipping of every
  input at the source (``SecAggSpec.clip``) and each receiver's guard on the aggregate
  (:meth:`~roadcollab.collaboration.guard.ReceiverGuard.substitute`: implausible bands are replaced by
  its own inversion), measured at vehicle 1; anomalies as for ``robust`` (vehicles may still report
  their own detections for corroboration).
- ``secagg_valid``: as ``secagg_guarded``, but every input is proven inside a public box per band
  (:mod:`roadcollab.privacy.secagg_validity`, :class:`~roadcollab.privacy.secagg_bands.SpectralBox`:
  ``kappa`` x the honest message's standard deviation from the road prior and the public inversion error),
  so the malicious vehicle sends its strategy clipped into the box (unclipped it is refused). The node
  computes what the protocol reveals (the sum of the quantised accepted inputs; the proofs themselves are
  exercised in tests/test_secagg_validity.py); ``refused`` counts inputs that were outside the box.
- ``secagg_bounded``: ``secagg_valid`` as the first of ``K`` sessions (:func:`~roadcollab.privacy.secagg_phased.public_schedule`) over
  the same vehicles, each later one on deviations from the last result proven inside a public l2 ball
  (:mod:`.secagg_bounded`); ``refused`` counts inputs scaled onto the ball over the phases. Its rows include
  the adaptive strategies :data:`~.secagg_bounded.ADAPTIVE_STRATEGIES`.

Strategies (the attacker knows its own honest ``z``, the true anomalies and the fleet size ``n``):
``scale_10``, ``scale_1e3`` (``z`` times a factor), ``negate``, ``tone`` (a 2 Hz sine of 10 x the
rms of ``z``), ``noise_3x`` (band-limited noise of 3 x the rms), ``extreme`` (1e300 on 100 samples),
``count`` (``2 z`` claiming to average 999,999 vehicles), ``fake_pothole`` (``n`` times the
band-limited signature of a 5 cm pothole where there is none, so that the mean shows it at full
depth) and ``erase_potholes`` (minus ``n`` times the signature of every true anomaly).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..._validation import check_int
from ...collaboration.guard import ReceiverGuard
from ...collaboration.robust_fusion import RobustFusion, fuse_inversions
from ...privacy.secagg_bands import SpectralBox
from ...privacy.secagg_messages import SecAggSpec
from ...detection.corroboration import DEFAULT_MIN_VOTES, corroborate, min_votes_for
from ...detection.detector import MAX_ROAD_VELOCITY, Detection, detect_anomalies
from ...detection.scoring import lost_anomalies, new_false_detections
from ...errors import ParameterError
from ...models.anomaly import Anomaly
from ...models.profile import TimeRoad
from ...privacy.secagg_flp import ValidityEncoding
from ...wire.message import InversionMessage
from ..anomalies.config import AnomalyStudyConfig
from ..pipeline import FleetPipeline, fleet_and_run_seeds, record_run
from ..seeds import SeedPlan, run_stream
from ...privacy.secagg_phased import public_schedule
from .secagg_bounded import ADAPTIVE_STRATEGIES, BOUNDED_FINAL, ball_radius, bounded_inputs, centred_clipping

__all__ = ["FUSION_STRATEGIES", "FUSION_TARGETS", "PoisoningSummary", "fusion_poisoning_rows", "through_guard"]

FUSION_STRATEGIES = ("scale_10", "scale_1e3", "negate", "tone", "noise_3x", "extreme", "count", "fake_pothole",
                     "erase_potholes")
FUSION_TARGETS = ("mean", "robust", "secagg_guarded", "secagg_valid", "secagg_bounded")
_FAKE_DEPTH = 0.05       # m
_FAKE_LENGTH = 0.5       # m
_TOLERANCE = 1.0         # m, as the anomaly study


@dataclass(frozen=True)
class PoisoningSummary:
    """One row of ``poisoning.csv``: an attack strategy against one target, over the runs (fusion
    nodes here; receivers from :func:`roadcollab.experiments.security.poisoning.summarize`).

    Attributes
    ----------
    strategy : str
    target : str
        What was attacked (e.g. ``fused_mean``, ``fused_robust``, ``receiver_none``).
    honest_mse, attacked_mse : float
        Mean over runs of the target's MSE, (m/s)^2.
    ratio : float
        Mean over runs of attacked / honest MSE.
    max_ratio_to_observer : float
        Receiver targets: largest over runs of the receiver's MSE over its own observer-only MSE
        (the target is <= 2); NaN for fusion targets.
    fake_anomalies_reported : int
        Reported anomalies under attack that match neither a true anomaly nor an honest report.
    real_anomalies_lost : int
        True anomalies reported honestly but not under attack.
    refused : int
        Malicious messages refused by the target.
    runs : int
    """

    strategy: str
    target: str
    honest_mse: float
    attacked_mse: float
    ratio: float
    max_ratio_to_observer: float
    fake_anomalies_reported: int
    real_anomalies_lost: int
    refused: int
    runs: int


@dataclass(frozen=True, eq=False)
class _Run:
    pipe: FleetPipeline
    road: TimeRoad
    z: np.ndarray              # (V, nfft, 2) honest inversions
    truth: np.ndarray          # (N, 2) band-limited true road velocity
    own: list[list[Detection]]  # each vehicle's own detections (honest)
    Ys: list[np.ndarray]                  # each vehicle's record spectrum
    guard: ReceiverGuard | None  # vehicle 1's guard (the receiver of the aggregate); None: not needed
    box: tuple[SpectralBox, ValidityEncoding] | None = None   # of the secagg_valid node
    radius: float = 0.0        # the l2 ball of the secagg_bounded node's last phases
    schedule: tuple = (1, 1.0)  # its (phases, grow)

    @property
    def grid(self):
        return self.pipe.grid

    @property
    def validity(self) -> tuple[SpectralBox, ValidityEncoding]:
        """``box``, which the validated targets need."""
        if self.box is None:
            raise ParameterError("the validated targets need the run's validity box")
        return self.box

    def receiver_guard(self) -> ReceiverGuard:
        if self.guard is None:
            raise ParameterError("this honest run was recorded without vehicle 1's receiver guard")
        return self.guard

    def message(self, z, count: int = 1) -> InversionMessage:
        g = self.grid
        return InversionMessage(mechanism="hardened" if count == 1 else "fused", sample_rate=g.sample_rate,
                                n_samples=g.n_samples, z=z, count=count)

    def detect(self, z) -> list[Detection]:
        """Detections in a fused or claimed estimate; none where it is no road (non-finite or huge)."""
        cfg = self.pipe.config
        n = self.grid.n_samples
        if not np.all(np.abs(z[:n]) < MAX_ROAD_VELOCITY):
            return []
        return detect_anomalies(z[:n], positions=self.road.positions[:n], speed=cfg.speed,
                                sample_rate=cfg.sample_rate)

    def signature(self, anomaly: Anomaly) -> np.ndarray:
        """Band-limited road velocity of one anomaly on the padded grid, (nfft, 2), m/s."""
        g = self.grid
        elev = np.zeros((g.n_samples + 1, 2))
        elev[:, list(anomaly.tracks)] = anomaly.elevation(self.road.positions[:g.n_samples + 1])[:, None]
        return g.band_limited(g.rfft(np.diff(elev, axis=0) * g.sample_rate))


def _honest_run(pipe: FleetPipeline, ss, road_spec, guard: ReceiverGuard | None) -> _Run:
    g, cfg = pipe.grid, pipe.config
    road, _, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), cfg.sensor_noise_std, road_spec)
    z = np.array([g.irfft(e.invert(Y, posterior=True)) for e, Y in zip(pipe.estimators, Ys)])
    truth = g.band_limited(g.rfft(road.velocity), g.n_samples)
    run = _Run(pipe, road, z, truth, [], Ys, guard)
    run.own.extend(run.detect(zi) for zi in z)
    return run


def _fake_site(run: _Run) -> Anomaly:
    """A 5 cm pothole in the scored stretch, at least 5 m from every true anomaly."""
    cfg = run.pipe.config
    pos = run.road.positions
    lo, hi = float(pos[cfg.scored.start]) + 2.0, float(pos[cfg.scored.stop - 1]) - 2.0
    for p in np.linspace(lo, hi, 200):
        if all(abs(p - a.center) > 5.0 for a in run.road.anomalies):
            return Anomaly(position=float(p), side="both", kind="pothole", depth=_FAKE_DEPTH, length=_FAKE_LENGTH)
    raise ParameterError("the scored stretch has no room for a fake anomaly 5 m from the true ones")


def _attack(strategy: str, run: _Run, j: int, rng: np.random.Generator) -> tuple[np.ndarray, int, Anomaly | None]:
    """The malicious ``z``, its claimed count and the fake anomaly (if any)."""
    z = run.z[j].copy()
    n = run.z.shape[0]
    rms = float(np.sqrt(np.mean(z ** 2)))
    g = run.grid
    if strategy in ("scale_10", "scale_1e3"):
        return z * (10.0 if strategy == "scale_10" else 1e3), 1, None
    if strategy == "negate":
        return -z, 1, None
    if strategy == "tone":
        t = np.arange(g.nfft) / g.sample_rate
        return z + 10 * rms * np.sqrt(2) * np.sin(2 * np.pi * 2.0 * t)[:, None], 1, None
    if strategy == "noise_3x":
        e = g.band_limited(g.rfft(rng.standard_normal((g.nfft, 2))))
        return z + 3 * rms * e / np.sqrt(np.mean(e ** 2)), 1, None
    if strategy == "extreme":
        z[1000:1100] = 1e300
        return z, 1, None
    if strategy == "count":
        return 2 * z, 999_999, None
    if strategy == "fake_pothole":
        fake = _fake_site(run)
        return z + n * run.signature(fake), 1, fake
    if strategy == "erase_potholes":
        return z - n * sum((run.signature(a) for a in run.road.anomalies), np.zeros_like(z)), 1, None
    raise ParameterError(f"strategy must be one of {FUSION_STRATEGIES}, got {strategy!r}")


def _mean_node(run: _Run, msgs: list[InversionMessage]) -> tuple[np.ndarray, int]:
    counts = np.array([m.count for m in msgs], float)
    # Weights in float: 999,999 x 1e300 overflows, the plain average then is not finite.
    with np.errstate(over="ignore", invalid="ignore"):
        z = sum(c * m.z for c, m in zip(counts, msgs)) / counts.sum()
    return z, 0


def _robust_node(run: _Run, msgs: list[InversionMessage]) -> tuple[np.ndarray, int]:
    out = fuse_inversions(msgs, run.grid, RobustFusion())
    return out.z, len(out.refused)


def _secagg_node(run: _Run, msgs: list[InversionMessage]) -> tuple[np.ndarray, int]:
    """Secure aggregation as vehicle 1 uses it: the average of the clipped inputs (what the protocol
    reveals; ``count`` does not exist there), checked by vehicle 1's guard against its own posterior
    inversion, which replaces the refused bands."""
    clip = SecAggSpec().clip
    agg = np.mean([np.clip(m.z, -clip, clip) for m in msgs], axis=0)
    est = run.pipe.estimators[0]
    Z, report = run.receiver_guard().substitute(run.message(agg, len(msgs)), run.Ys[0], est.invert(run.Ys[0], posterior=True))
    return run.grid.irfft(Z), int(report.refused)


def public_error(pipe: FleetPipeline, guard: ReceiverGuard) -> np.ndarray:
    """``C``: the public expected inversion error per active bin and track, the largest over the fleet.

    Parameters
    ----------
    pipe : FleetPipeline
    guard : ReceiverGuard
        Vehicle 1's guard (the others are built from the pipeline).

    Returns
    -------
    (K_active, 2) ndarray
        (m/s)^2, spectrum units.
    """
    guards = [guard] + [ReceiverGuard(e, pipe.road_moment, pipe.config.sensor_noise_std) for e in pipe.estimators[1:]]
    out: np.ndarray = np.max([np.real(np.einsum("ktt->kt", gd._inversion_error(pipe.road_moment)))
                              for gd in guards], axis=0)
    return out


def validity_box(pipe: FleetPipeline, guard: ReceiverGuard, kappa: float = 6.0):
    """The public box of the ``secagg_valid`` node: ``(SpectralBox, ValidityEncoding)`` (module docstring)."""
    g = pipe.grid
    S = np.real(np.einsum("ktt->kt", pipe.road_moment))
    C = public_error(pipe, guard)
    box = SpectralBox(g.active, np.sqrt((g.weight[g.active, None] ** 2 * S + C) / 2), tuple(guard.bands), kappa=kappa)
    return box, box.encoding()


def _secagg_valid_node(run: _Run, msgs: list[InversionMessage]) -> tuple[np.ndarray, int]:
    """The validated secure aggregate (module docstring), then vehicle 1's guard as ``_secagg_node``."""
    box, enc = run.validity
    us, outside = [], 0
    for m in msgs:
        with np.errstate(over="ignore", invalid="ignore"):
            u = box.to_vector(run.grid.rfft(m.z))
        if not np.all(np.isfinite(u)):      # cannot be encoded at all: not counted
            outside += 1
            continue
        u, out = enc.clip(u)
        outside += out > 0
        us.append(enc.quantize(u))
    return through_guard(run, np.mean(us, axis=0), len(us)), int(outside)


def through_guard(run: _Run, m: np.ndarray, n_inputs: int) -> np.ndarray:
    """A validated aggregate ``m`` (the box's vector of ``n_inputs`` inputs) as vehicle 1 uses it: the
    fused message through its receiver guard (refused bands replaced by its own posterior inversion), in time.

    Parameters
    ----------
    run : _Run
        With ``box`` set.
    m : (L,) ndarray
        The revealed average in the box's coordinates.
    n_inputs : int
        Inputs averaged (the message's ``count``).

    Returns
    -------
    ndarray
        The time signal of the guarded estimate.
    """
    box, _ = run.validity
    est = run.pipe.estimators[0]
    agg = run.grid.irfft(box.from_vector(m))
    Z, _ = run.receiver_guard().substitute(run.message(agg, n_inputs), run.Ys[0], est.invert(run.Ys[0], posterior=True))
    return run.grid.irfft(Z)


def _secagg_bounded_node(run: _Run, msgs: list[InversionMessage],
                         adaptive: tuple[int, np.ndarray] | None = None) -> tuple[np.ndarray, int]:
    """The phased, centred-clipping secure aggregate (:mod:`.secagg_bounded`), then vehicle 1's guard."""
    first, raw = bounded_inputs(run, msgs)
    phases, grow = run.schedule
    m, clipped = centred_clipping(first, raw, run.radius, phases, adaptive=adaptive, grow=grow)
    return through_guard(run, m, len(first)), clipped


def _adaptive(strategy: str, run: _Run, j: int) -> tuple[np.ndarray, np.ndarray]:
    """An adaptive attacker's phase-1 lie and its direction in the validated space (:mod:`.secagg_bounded`)."""
    box, _ = run.validity
    z, n = run.z[j], run.z.shape[0]
    if strategy == "adaptive_anti_road":
        return -10 * z, -box.to_vector(run.grid.rfft(z))
    sig = (run.signature(_fake_site(run)) if strategy == "adaptive_fake"
           else -sum((run.signature(a) for a in run.road.anomalies), np.zeros_like(z)))
    return z + n * sig, box.to_vector(run.grid.rfft(sig))


def _reported(target: str, run: _Run, zf: np.ndarray, own: list) -> list[Detection]:
    dets = run.detect(zf)
    if target == "mean":
        return dets
    # The robust node's map needs f + 1 of n votes (f = its breakdown), so a silent coalition it withstands
    # cannot erase what the honest vehicles see (min_votes_for); secure aggregation keeps the fixed default.
    votes = min_votes_for(len(own)) if target == "robust" else DEFAULT_MIN_VOTES      # both secagg targets
    return corroborate(dets, own, min_votes=votes, tolerance=_TOLERANCE)


def _score(run: _Run, zf: np.ndarray) -> float:
    cfg = run.pipe.config
    n = run.grid.n_samples
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.mean((zf[:n][cfg.scored] - run.truth[cfg.scored]) ** 2))


def fusion_poisoning_rows(config: AnomalyStudyConfig, seed: int, *, n_runs: int = 4, malicious: int = 4,
                          strategies=FUSION_STRATEGIES, pipe=None, targets=FUSION_TARGETS) -> list[PoisoningSummary]:
    """Measure every strategy of one malicious vehicle against both fusion nodes.

    Parameters
    ----------
    config : AnomalyStudyConfig
        Fleet, road (with anomalies) and detector of the anomaly study.
    seed : int
        Root seed (fleet and runs as :func:`~roadcollab.experiments.pipeline.fleet_and_run_seeds`).
    n_runs : int
        Road segments.
    malicious : int
        0-based index of the malicious vehicle.
    strategies : sequence of str
        Subset of :data:`FUSION_STRATEGIES`.
    pipe : FleetPipeline, optional
        The pipeline of ``config.experiment`` and ``seed`` if already built.
    targets : sequence of str
        Subset of :data:`FUSION_TARGETS`.

    Returns
    -------
    list of PoisoningSummary
        Targets ``fused_{target}`` per strategy.
    """
    n_runs = check_int("n_runs", n_runs, low=1)
    exp = config.experiment
    malicious = check_int("malicious", malicious, low=0, high=exp.n_vehicles - 1)
    bad = [t for t in targets if t not in FUSION_TARGETS] + [s for s in strategies if s not in FUSION_STRATEGIES]
    if bad:
        raise ParameterError(f"strategies must be among {FUSION_STRATEGIES} and targets among {FUSION_TARGETS}, "
                             f"got {bad}")
    pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, seed)[0]) if pipe is None else pipe
    run_seeds = SeedPlan(seed).runs(n_runs)
    road_spec = config.road_spec()
    # Vehicle 1's guard is per-vehicle setup (posterior plants, expected discrepancy): built once.
    guard = ReceiverGuard(pipe.estimators[0], pipe.road_moment, exp.sensor_noise_std)
    acc: dict[tuple[str, str], list[tuple]] = {(s, t): [] for s in strategies for t in targets}
    box = validity_box(pipe, guard) if {"secagg_valid", "secagg_bounded"} & set(targets) else None
    radius = ball_radius(public_error(pipe, guard), exp.n_vehicles) if "secagg_bounded" in targets else 0.0
    schedule = (public_schedule(2 * float(np.linalg.norm(box[1].bounds)) / exp.n_vehicles, radius, BOUNDED_FINAL)
                if box is not None and radius > 0 else (1, 1.0))
    nodes = {"mean": _mean_node, "robust": _robust_node, "secagg_guarded": _secagg_node,
             "secagg_valid": _secagg_valid_node, "secagg_bounded": _secagg_bounded_node}
    for r in range(n_runs):
        run = dataclasses.replace(_honest_run(pipe, run_seeds[r], road_spec, guard), box=box, radius=radius,
                                  schedule=schedule)
        rng = np.random.default_rng(run_stream(run_seeds[r], "privacy"))
        honest = [run.message(z) for z in run.z]
        for target in targets:
            node = nodes[target]
            zf_h, _ = node(run, honest)
            rep_h = _reported(target, run, zf_h, run.own)
            mse_h = _score(run, zf_h)
            for s in strategies:
                z_m, count, _fake = _attack(s, run, malicious, rng)
                msgs = honest[:malicious] + [run.message(z_m, count)] + honest[malicious + 1:]
                own = run.own[:malicious] + [run.detect(z_m)] + run.own[malicious + 1:]
                zf, refused = node(run, msgs)
                rep = _reported(target, run, zf, own)
                acc[s, target].append(_scored(run, mse_h, zf, rep, rep_h, refused))
            for s in ADAPTIVE_STRATEGIES if target == "secagg_bounded" else ():
                z_m, direction = _adaptive(s, run, malicious)
                msgs = honest[:malicious] + [run.message(z_m)] + honest[malicious + 1:]
                own = run.own[:malicious] + [run.detect(z_m)] + run.own[malicious + 1:]
                zf, refused = _secagg_bounded_node(run, msgs, adaptive=(malicious, direction))
                acc.setdefault((s, target), []).append(_scored(run, mse_h, zf, _reported(target, run, zf, own), rep_h,
                                                               refused))
    return [_row(s, t, v) for (s, t), v in acc.items()]


def _scored(run: _Run, mse_h: float, zf: np.ndarray, rep: list, rep_h: list, refused: int) -> tuple:
    anomalies = run.road.anomalies
    return (mse_h, _score(run, zf), new_false_detections(rep, rep_h, anomalies, tolerance=_TOLERANCE),
            lost_anomalies(rep, rep_h, anomalies, tolerance=_TOLERANCE), refused)


def _row(strategy: str, target: str, vals: list[tuple]) -> PoisoningSummary:
    a = np.array([v[:2] for v in vals], float)
    with np.errstate(over="ignore", invalid="ignore"):
        ratio = float(np.mean(a[:, 1] / a[:, 0]))
    return PoisoningSummary(strategy=strategy, target=f"fused_{target}", honest_mse=float(a[:, 0].mean()),
                        attacked_mse=float(np.mean(a[:, 1])), ratio=ratio, max_ratio_to_observer=float("nan"),
                        fake_anomalies_reported=int(sum(v[2] for v in vals)),
                        real_anomalies_lost=int(sum(v[3] for v in vals)), refused=int(sum(v[4] for v in vals)),
                        runs=len(vals))
