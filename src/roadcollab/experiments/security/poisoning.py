"""Hostile-but-well-formed messages against one receiver, with and without the receiver guard.

For one receiver (vehicle ``receiver`` of the fleet, 0-based) and several runs, the honest message
of the vehicle before it is replaced by a hostile construction that still has the right types,
shapes and limits (issue 9, section 1):

======================= ============================================================================
``honest``              the message as sent (the baseline: the guard must not refuse it)
``scale_z_10/1e3``      ``z`` scaled (``e`` and ``w^f`` scaled for an exchange message)
``scale_e_10/1e3``      ``e`` alone scaled (exchange only)
``tone``                an in-band 2 Hz tone of three times ``z``'s RMS added to ``z``
``zero_z``              ``z = 0`` (the road erased)
``near_singular_T``     the sender's ``T`` with its second output scaled by 1e-9 (exchange only)
``static_T``            ``T = 1e-3 I``, order 0 (exchange only)
``static_T_tiny``       ``T = 1e-300 I``: ``z`` overflows (exchange only)
``jordan_trap``         ``T.A`` a 64x64 Jordan block, eigenvalue 0.99, corner 1e-16 (true radius 1.55;
                        exchange only): must be refused at decode
``extreme``             every 50th sample of ``e`` (or ``z``) set to 1e300
``fake_pothole``        ``(I - D P_hat)^-1 W p`` added to ``z``: a 5 cm x 0.5 m pothole signature ``p`` in
                        the middle of the segment, with the fleet's nominal model (the attacker's
                        knowledge), so that the receiver's estimate shows it at full depth
``fake_pothole_direct`` ``W p`` added to ``z`` (small enough to pass as plausible)
``subtle``              band-limited noise added to ``z``, scaled per guard band to 0.8 x the guard's
                        threshold of that band's expected honest discrepancy: the largest change the
                        guard lets through unnoticed (built with the receiver's own guard statistics,
                        i.e. an attacker who knows them exactly)
======================= ============================================================================

Each row gives the receiver's MSE over its own observer-only MSE (target <= 2) with the guard and
without it, whether the hostile message was refused at decode (``MessageError`` on construction
or decode), refused by the guard (in bands or entirely) or accepted, and whether the receiver's
next message encodes and decodes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...collaboration.algorithm1 import CollaborativeEstimator
from ...collaboration.guard import ReceiverGuard
from ...collaboration.relay import Exchange, Relay
from ...detection.corroboration import confirmed_by_own
from ...detection.detector import MAX_ROAD_VELOCITY, detect_anomalies
from ...detection.scoring import lost_anomalies, new_false_detections
from ...errors import MessageError, ParameterError
from ...lti.batch2x2 import inv2x2, matmul, matvec
from ...lti.realisation import StateSpaceData
from ...models.vehicle import Vehicle
from ...wire.message import ExchangeMessage, InversionMessage
from ...wire.protocol import decode, encode
from ..config import ExperimentConfig
from .fusion_poisoning import PoisoningSummary
from ..pipeline import PipelineCache, record_run
from ..seeds import SeedPlan, run_stream

__all__ = ["CONSTRUCTIONS", "PoisoningRow", "PoisoningResult", "hostile_message", "poisoning_rows", "summarize"]

#: Hostile constructions per mechanism.
CONSTRUCTIONS = {
    "none": ("honest", "scale_z_10", "scale_z_1e3", "scale_e_10", "scale_e_1e3", "tone", "zero_z",
             "near_singular_T", "static_T", "static_T_tiny", "jordan_trap", "extreme", "fake_pothole",
             "fake_pothole_direct", "subtle"),
    "hardened": ("honest", "scale_z_10", "scale_z_1e3", "tone", "zero_z", "extreme", "fake_pothole",
                 "fake_pothole_direct", "subtle"),
}


@dataclass(frozen=True)
class PoisoningRow:
    """One hostile construction on one run.

    Attributes
    ----------
    mechanism : str
        ``"none"`` (ExchangeMessage) or ``"hardened"`` (InversionMessage).
    construction : str
        A name of :data:`CONSTRUCTIONS`.
    run : int
        Run index.
    outcome : str
        ``"decode_refused"``, ``"guard_refused"`` (whole message), ``"guard_partial"`` (some bands)
        or ``"accepted"``.
    refused_bands : int
        Bands the guard refused.
    mse : float
        Receiver MSE with the guard, (m/s)^2.
    observer_mse : float
        Its observer-only MSE, (m/s)^2.
    ratio : float
        Receiver MSE with the guard over its observer-only MSE.
    ratio_unguarded : float
        The same without the guard (NaN if the estimate is not finite).
    finite : bool
        The guarded estimate is finite.
    next_message_encodes : bool
        The receiver's next message encodes and decodes.
    reason : str
        The decode error or the guard's first reason ("" if accepted).
    fake_anomalies : int
        Reported detections of the receiver's estimate (those its own data confirms,
        :func:`~roadcollab.detection.corroboration.confirmed_by_own`) that match neither a true anomaly
        nor a reported detection with the honest message.
    lost_anomalies : int
        True anomalies detected with the honest message and not with this one.
    """

    mechanism: str
    construction: str
    run: int
    outcome: str
    refused_bands: int
    mse: float
    observer_mse: float
    ratio: float
    ratio_unguarded: float
    finite: bool
    next_message_encodes: bool
    reason: str
    fake_anomalies: int
    lost_anomalies: int


@dataclass(frozen=True)
class PoisoningResult:
    """Rows of a poisoning measurement.

    Attributes
    ----------
    rows : tuple of PoisoningRow
    """

    rows: tuple[PoisoningRow, ...]

    def to_rows(self) -> list[PoisoningRow]:
        """The measurement's rows (the fields of :class:`PoisoningRow` are a CSV's columns, in order).

        Returns
        -------
        list of PoisoningRow
            One per mechanism, construction and run.
        """
        return list(self.rows)


def _with(message, **changes):
    """A copy of a message with fields replaced (validated again on construction)."""
    return dataclasses.replace(message, **changes)


def _add_to_z(message, dz: np.ndarray, sender: CollaborativeEstimator):
    """The message with ``dz`` (time signal on the padded grid) added to the ``z`` it implies."""
    if isinstance(message, InversionMessage):
        return _with(message, z=message.z + dz)
    g = sender.grid
    dE = np.zeros((g.n_bins, 2), complex)
    dE[g.active] = matvec(sender.T_ss_f, g.rfft(dz)[g.active])     # z = W T^-1 e: add T dz to e
    return _with(message, e=message.e + g.irfft(dE))


def _static(gain: float, dt: float) -> StateSpaceData:
    return StateSpaceData(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), gain * np.eye(2), dt)


def _jordan_trap(dt: float) -> StateSpaceData:
    """64x64 Jordan block, eigenvalue 0.99, corner 1e-16: computes as radius 0.99, is 1.55."""
    n = 64
    A = 0.99 * np.eye(n) + np.diag(np.ones(n - 1), 1)
    A[-1, 0] = 1e-16
    B = np.zeros((n, 2))
    B[-1] = 1.0
    C = np.zeros((2, n))
    C[:, 0] = 1.0
    return StateSpaceData(A, B, C, np.eye(2), dt)


def _pothole_dz(nominal: CollaborativeEstimator, config: ExperimentConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(I - D P_hat)^-1 W p`` (what adds a pothole's velocity signature ``p`` to the estimate) and
    ``W p`` (the signature itself in ``z``), on the padded grid, m/s."""
    g = nominal.grid
    fs, v = config.sample_rate, config.speed
    x = np.arange(g.nfft) * v / fs
    centre = (config.margin + config.segment_length / 2)
    h = np.where(np.abs(x - centre) <= 0.25, -0.05, 0.0)          # 5 cm deep, 0.5 m long
    k = max(1, int(round(0.25 / (v / fs))))
    h = np.convolve(h, np.ones(k) / k, mode="same")                # tyre enveloping, 0.25 m
    p = np.zeros((g.nfft, 2))
    p[:, 0] = np.gradient(h, 1.0 / fs)                             # left track, m/s
    act = g.active
    M = np.eye(2) - matmul(nominal.D_f[act], nominal.P_f[act])
    Wp = g.reg_weight[act][:, None] * g.rfft(p)[act]
    dZ = np.zeros((g.n_bins, 2), complex)
    dZ[act] = matvec(inv2x2(M), Wp)
    direct = np.zeros((g.n_bins, 2), complex)
    direct[act] = Wp
    return g.irfft(dZ), g.irfft(direct)


def _subtle_dz(guard: ReceiverGuard, rng: np.random.Generator, fraction: float = 0.8) -> np.ndarray:
    """Noise in ``z`` whose power per guard band is ``fraction`` x threshold x the band's expected
    honest discrepancy: the largest change the guard accepts (m/s, padded grid)."""
    g = guard.estimator.grid
    act_idx = np.flatnonzero(g.active)
    dZ = np.zeros((g.n_bins, 2), complex)
    for b, expected in zip(guard.bands, guard.band_expected):
        noise = rng.standard_normal((b.size, 2)) + 1j * rng.standard_normal((b.size, 2))
        dZ[act_idx[b]] = noise * np.sqrt(fraction * guard.threshold * expected / np.sum(np.abs(noise) ** 2))
    return g.irfft(dZ)


def hostile_message(name: str, honest, sender: CollaborativeEstimator, pothole_dz: np.ndarray, z_rms: float,
                    extra_dz: np.ndarray | None = None):
    """Build one hostile construction from an honest message.

    Parameters
    ----------
    name : str
        A name of :data:`CONSTRUCTIONS` for the message's mechanism.
    honest : ExchangeMessage | InversionMessage
        The sender's honest message.
    sender : CollaborativeEstimator
        The sender (its ``T`` response, for adding to ``z`` through ``e``).
    pothole_dz : (nfft, 2) ndarray
        The fake pothole's ``z`` perturbation (m/s).
    z_rms : float
        RMS of the honest ``z`` (m/s); the tone has three times this amplitude.
    extra_dz : (nfft, 2) ndarray, optional
        The perturbation of ``z`` (m/s) for ``fake_pothole_direct`` and ``subtle``.

    Returns
    -------
    ExchangeMessage | InversionMessage

    Raises
    ------
    MessageError
        If the construction is not a valid message (the Jordan trap must be).
    """
    g = sender.grid
    exch = isinstance(honest, ExchangeMessage)
    if name == "honest":
        return honest
    if name.startswith("scale_z_"):
        k = float(name.rsplit("_", 1)[1])
        return _with(honest, e=k * honest.e, wf=k * honest.wf) if exch else _with(honest, z=k * honest.z)
    if name.startswith("scale_e_"):
        return _with(honest, e=float(name.rsplit("_", 1)[1]) * honest.e)
    if name == "zero_z":
        return _with(honest, e=0 * honest.e, wf=0 * honest.wf) if exch else _with(honest, z=0 * honest.z)
    if name == "tone":
        t = np.arange(g.nfft) / g.sample_rate
        return _add_to_z(honest, 3.0 * z_rms * np.sin(2 * np.pi * 2.0 * t)[:, None] * np.ones(2), sender)
    if name == "extreme":
        field = "e" if exch else "z"
        arr = getattr(honest, field).copy()
        arr[::50] = 1e300
        return _with(honest, **{field: arr})
    if name == "fake_pothole":
        return _add_to_z(honest, pothole_dz, sender)
    if name in ("fake_pothole_direct", "subtle"):
        if extra_dz is None:
            raise ParameterError(f"{name} needs extra_dz (the perturbation of z)")
        return _add_to_z(honest, extra_dz, sender)
    dt = g.dt
    if name == "near_singular_T":
        T = honest.T
        C, D = T.C.copy(), T.D.copy()
        C[1] *= 1e-9
        D[1] *= 1e-9
        return _with(honest, T=StateSpaceData(T.A, T.B, C, D, dt))
    if name in ("static_T", "static_T_tiny"):
        return _with(honest, T=_static(1e-3 if name == "static_T" else 1e-300, dt))
    if name == "jordan_trap":
        return _with(honest, T=_jordan_trap(dt))
    raise ParameterError(f"name must be one of {CONSTRUCTIONS['none']}, got {name!r}")


def _nominal_estimator(config: ExperimentConfig, grid) -> CollaborativeEstimator:
    """The fleet's nominal vehicle, as an attacker who knows only the public fleet model builds it."""
    nom = config.fleet.nominal
    return CollaborativeEstimator(Vehicle(-1, nom, nom), config.noise_model(), grid, gamma=config.gamma)


def _attempt(name, honest, sender, dz, z_rms, extra):
    """(message as the receiver decodes it, None) or (None, the decode error)."""
    try:
        return decode(encode(hostile_message(name, honest, sender, dz, z_rms, extra.get(name)))), ""
    except MessageError as err:
        return None, str(err)


def _encodes(message) -> bool:
    try:
        decode(encode(message))
    except MessageError:
        return False
    return True


# Long: one receiver's reaction to every construction, with and without the guard, scored alike.
def _run_constructions(pipe, guard, mech, run, ys, Ys, score, dz, anomalies) -> list[PoisoningRow]:
    """Every construction of ``mech`` against the guard's receiver on one run's records
    (``score(W) -> (mse, detections)``; ``dz``: the amplified and the direct fake pothole)."""
    j = pipe.estimators.index(guard.estimator)
    sender = pipe.estimators[j - 1]
    honest = Relay(pipe.estimators[j - 1:j], Exchange(mech)).step(0, ys[j - 1], Y=Ys[j - 1]).message
    z_rms = float(np.sqrt(np.mean(pipe.grid.irfft(sender.invert(Ys[j - 1])) ** 2)))
    extra = {"fake_pothole_direct": dz[1], "subtle": _subtle_dz(guard, np.random.default_rng([run, j]))}
    plain = Relay([guard.estimator], Exchange(mech))
    guarded = Relay([guard.estimator], Exchange(mech), guard=[guard])
    obs, _ = score(plain.step(0, ys[j], None, Y=Ys[j]).result.W_obs)
    rows, honest_dets = [], None
    for name in CONSTRUCTIONS[mech]:
        msg, err = _attempt(name, honest, sender, dz[0], z_rms, extra)
        if msg is None:           # refused at decode: the receiver runs on its own (w^f = 0)
            step, ratio_u, outcome = plain.step(0, ys[j], None, Y=Ys[j]), 1.0, "decode_refused"
        else:
            step = guarded.step(0, ys[j], msg, Y=Ys[j])
            with np.errstate(all="ignore"):     # unguarded: Algorithm 1 as it is (may be NaN)
                ratio_u = score(guard.estimator.estimate(None, msg, Y=Ys[j], unguarded=True).W_hat)[0] / obs
            rep = step.guard
            if rep is None:                     # a Relay built with a guard reports on every step
                raise ParameterError("the guarded relay step carries no guard report")
            outcome = ("guard_refused" if rep.whole_message_refused else
                       "guard_partial" if rep.refused_bands else "accepted")
            err = rep.reasons[0] if rep.reasons else ""
        est = step.result.W_hat
        m, dets = score(est)
        honest_dets = dets if name == "honest" else honest_dets
        rows.append(PoisoningRow(
            mechanism=mech, construction=name, run=run, outcome=outcome,
            refused_bands=0 if step.guard is None else len(step.guard.refused_bands), mse=m, observer_mse=obs,
            ratio=m / obs, ratio_unguarded=float(ratio_u) if np.isfinite(ratio_u) else float("nan"),
            finite=bool(np.isfinite(est).all()), next_message_encodes=_encodes(step.message), reason=err,
            fake_anomalies=new_false_detections(dets, honest_dets, anomalies),
            lost_anomalies=lost_anomalies(dets, honest_dets, anomalies)))
    return rows


def _scorer(pipe, config, road, est=None, Y=None):
    """``score(X) -> (mse, reported anomalies)``; with the receiver ``est`` and its record ``Y``, reported
    anomalies are those its own data confirms (:func:`~roadcollab.detection.corroboration.confirmed_by_own`)."""
    grid, n, sl = pipe.grid, pipe.grid.n_samples, config.scored
    truth = grid.band_limited(grid.rfft(road.velocity), n)[sl]

    def detect(X):
        w = grid.band_limited(X, n)
        with np.errstate(all="ignore"):
            m = float(np.mean((w[sl] - truth) ** 2))
        if not np.all(np.abs(w) < MAX_ROAD_VELOCITY):
            return m, []
        return m, detect_anomalies(w, positions=road.positions[:n], speed=config.speed, sample_rate=config.sample_rate)
    if est is None:
        return detect
    own = detect(est.estimate(None, Y=Y).W_obs)[1] + detect(est.invert(Y))[1]

    def score(X):
        """MSE on the scored stretch and the confirmed anomaly detections of a spectrum."""
        m, dets = detect(X)
        return m, confirmed_by_own(dets, own)
    return score


def poisoning_rows(config: ExperimentConfig | None = None, *, seed: int = 0, n_runs: int = 2, receiver: int = 1,
                   mechanisms=("none", "hardened"), guard_options: dict | None = None, pipe=None) -> PoisoningResult:
    """Measure every hostile construction against one receiver, with and without its guard.

    Parameters
    ----------
    config : ExperimentConfig, optional
        Default ``ExperimentConfig()`` (10 vehicles; only the sender and the receiver drive).
    seed : int
        Root seed (fleet and runs, :class:`~roadcollab.experiments.seeds.SeedPlan`).
    n_runs : int
        Runs (roads and sensor noise) per construction.
    receiver : int
        0-based index of the receiving vehicle (>= 1); vehicle ``receiver - 1`` is the attacker.
    mechanisms : sequence of str
        Keys of :data:`CONSTRUCTIONS`.
    guard_options : dict, optional
        Keyword options of :class:`~roadcollab.collaboration.guard.ReceiverGuard`.
    pipe : FleetPipeline, optional
        The pipeline of ``config`` and ``seed`` if already built.

    Returns
    -------
    PoisoningResult
        One row per mechanism, construction and run.
    """
    config = ExperimentConfig() if config is None else config
    if not 1 <= int(receiver) < config.n_vehicles:
        raise ParameterError(f"receiver must be in [1, {config.n_vehicles - 1}], got {receiver}")
    bad = [m for m in mechanisms if m not in CONSTRUCTIONS]
    if bad:
        raise ParameterError(f"mechanisms must be among {sorted(CONSTRUCTIONS)}, got {bad}")
    pipe = PipelineCache().pipeline(config, seed) if pipe is None else pipe
    guard = ReceiverGuard(pipe.estimators[receiver], pipe.road_moment, config.sensor_noise_std,
                          **(guard_options or {}))
    dz = _pothole_dz(_nominal_estimator(config, pipe.grid), config)
    rows: list[PoisoningRow] = []
    for run, ss in enumerate(SeedPlan(seed).runs(n_runs)):
        road, ys, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), config.sensor_noise_std)

        # Reported anomalies: those the receiver's own data confirms (confirmed_by_own, issue 20).
        score = _scorer(pipe, config, road, guard.estimator, Ys[receiver])

        for mech in mechanisms:
            rows.extend(_run_constructions(pipe, guard, mech, run, ys, Ys, score, dz, road.anomalies))
    return PoisoningResult(tuple(rows))


def summarize(result: PoisoningResult) -> list[PoisoningSummary]:
    """``poisoning.csv`` rows of a receiver measurement: one per mechanism and construction.

    Parameters
    ----------
    result : PoisoningResult

    Returns
    -------
    list of PoisoningSummary
        Target ``receiver_{mechanism}``; ``honest_mse`` is the receiver's MSE with the honest
        message, ``refused`` counts runs whose message was refused (at decode or by the guard).
    """
    out = []
    keys = list(dict.fromkeys((r.mechanism, r.construction) for r in result.rows))
    for mech, name in keys:
        rows = [r for r in result.rows if r.mechanism == mech and r.construction == name]
        honest = {r.run: r.mse for r in result.rows if r.mechanism == mech and r.construction == "honest"}
        h = np.array([honest[r.run] for r in rows])
        a = np.array([r.mse for r in rows])
        out.append(PoisoningSummary(
            strategy=name, target=f"receiver_{mech}", honest_mse=float(h.mean()), attacked_mse=float(a.mean()),
            ratio=float(np.mean(a / h)), max_ratio_to_observer=float(max(r.ratio for r in rows)),
            fake_anomalies_reported=sum(r.fake_anomalies for r in rows),
            real_anomalies_lost=sum(r.lost_anomalies for r in rows),
            refused=sum(r.outcome in ("decode_refused", "guard_refused") for r in rows), runs=len(rows)))
    return out

