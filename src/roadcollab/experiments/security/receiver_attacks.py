"""Coherent, guard-aware lies against one receiver (issue 20, section 4).

The constructions of :mod:`.poisoning` are blind to the guard except ``subtle`` (noise). These are
built by a sender that knows the receiver's guard exactly (its bands, ``v_b`` and threshold) and the
road (its own ``z_s``, a good estimate of it), and lies *coherently* with the road:

==================== ==============================================================================
``coherent_up``      ``z_s`` plus ``a_b z_s`` per guard band, ``a_b`` chosen so that the expected band
                     statistic is ``0.8 x threshold``: the road exaggerated as far as the guard allows
``coherent_down``    the same with ``- a_b z_s``: the road flattened (the direction of the receiver's
                     observer error, so the two add up: the strongest of the family)
``fake_pothole_09``  ``(I - D P_hat)^-1 W p`` (a 5 cm pothole at full depth in the receiver's estimate,
                     :func:`~roadcollab.experiments.security.poisoning._pothole_dz`) scaled per band to expected
                     statistic ``0.9 x threshold`` and added to ``z_s``
``slow_drift``       ``coherent_down`` over ``drift_segments`` consecutive segments from the same sender,
                     its band statistic ramping from 1.5 to ``0.8 x threshold``: each segment alone is
                     plausible; the receiver's per-sender record judges the sequence
==================== ==============================================================================

Rows are :class:`~roadcollab.experiments.security.fusion_poisoning.PoisoningSummary` with target
``receiver_hardened`` (the lie in an ``InversionMessage``) or ``receiver_none`` (the same ``z`` through
``e`` of an ``ExchangeMessage``); ``max_ratio_to_observer`` is the target (<= 2), fake and lost anomalies
are counted against the receiver's detections with the honest message, each confirmed by its own data
(:func:`~roadcollab.detection.corroboration.confirmed_by_own`: a detection in the message-aided estimate
is reported only if the receiver's observer or own inversion shows it too).
"""

from __future__ import annotations

import numpy as np

from ..._validation import check_int
from ...collaboration.guard import ReceiverGuard
from ...collaboration.relay import Exchange, Relay
from ...detection.scoring import lost_anomalies, new_false_detections
from ...errors import ParameterError
from ..config import ExperimentConfig
from .fusion_poisoning import PoisoningSummary
from ..pipeline import PipelineCache, record_run
from .poisoning import _add_to_z, _nominal_estimator, _pothole_dz, _scorer
from ..seeds import SeedPlan, run_stream

__all__ = ["RECEIVER_ATTACKS", "coherent_dz", "receiver_attack_rows"]

RECEIVER_ATTACKS = ("coherent_up", "coherent_down", "fake_pothole_09", "slow_drift")
_DRIFT_START = 1.5


def coherent_dz(guard: ReceiverGuard, shape: np.ndarray, statistic: float, *, cap: float | None = None) -> np.ndarray:
    """``shape`` (active-bin spectrum) scaled per guard band to an expected band statistic ``statistic``.

    For an honest sender ``E r_b = 1``; adding ``dZ`` independent of the honest discrepancy makes it
    ``1 + sum_b |dZ|^2 / v_b``, so ``|dZ|^2_b = (statistic - 1) v_b``.

    Parameters
    ----------
    guard : ReceiverGuard
        The receiver's guard (the attacker knows it).
    shape : (K_active, 2) complex ndarray
        Direction of the lie per bin (e.g. the sender's own ``z``), m/s.
    statistic : float
        Target ``r_b`` (> 1).
    cap : float, optional
        Largest per-band scale factor (e.g. 1: a pothole no deeper than the real one).

    Returns
    -------
    (nfft, 2) ndarray
        The perturbation of ``z`` on the padded grid, m/s.
    """
    g = guard.estimator.grid
    act_idx = np.flatnonzero(g.active)
    dZ = np.zeros((g.n_bins, 2), complex)
    for b, v in zip(guard.bands, guard.band_expected):
        power = float(np.sum(np.abs(shape[b]) ** 2))
        if power > 0:
            a = np.sqrt(max(statistic - 1.0, 0.0) * v / power)
            dZ[act_idx[b]] = (a if cap is None else min(a, cap)) * shape[b]
    return g.irfft(dZ)


def _segment(pipe, config, guard, j, ss, mech, pothole, attack, statistic, sender, confirm):
    """One segment: (observer MSE, honest MSE, attacked MSE, fake, lost, refused) at receiver ``j``."""
    road, ys, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), config.sensor_noise_std)
    est, sender_est = pipe.estimators[j], pipe.estimators[j - 1]
    score = _scorer(pipe, config, road, est, Ys[j]) if confirm else _scorer(pipe, config, road)
    honest = Relay([sender_est], Exchange(mech)).step(0, ys[j - 1], Y=Ys[j - 1]).message
    z_s = sender_est.invert(Ys[j - 1])[pipe.grid.active]
    if attack == "fake_pothole_09":
        shape = pipe.grid.rfft(pothole)[pipe.grid.active]
        dz = coherent_dz(guard, shape, statistic, cap=1.0)
    else:
        dz = (1.0 if attack == "coherent_up" else -1.0) * coherent_dz(guard, z_s, statistic)
    hostile = _add_to_z(honest, dz, sender_est)
    obs, _ = score(est.estimate(None, Y=Ys[j]).W_obs)
    # The honest reference goes through a fresh record (its own key) so it does not feed the attacker's.
    Wf_h, _ = guard.feedforward(honest, Ys[j], sender=("honest", sender))
    m_h, dets_h = score(est.estimate(None, Wf=Wf_h, Y=Ys[j]).W_hat)
    Wf, rep = guard.feedforward(hostile, Ys[j], sender=sender)
    m, dets = score(est.estimate(None, Wf=Wf, Y=Ys[j]).W_hat)
    return (obs, m_h, m, new_false_detections(dets, dets_h, road.anomalies),
            lost_anomalies(dets, dets_h, road.anomalies), int(rep.whole_message_refused))


def receiver_attack_rows(config: ExperimentConfig | None = None, *, seed: int = 0, n_runs: int = 2, receiver: int = 1,
                         mechanisms=("none", "hardened"), attacks=RECEIVER_ATTACKS, drift_segments: int = 8,
                         guard_options: dict | None = None, confirm: bool = True, pipe=None) -> list[PoisoningSummary]:
    """Measure the guard-aware coherent lies against one receiver.

    Parameters
    ----------
    config : ExperimentConfig, optional
        Default ``ExperimentConfig()``.
    seed : int
        Root seed (fleet and runs).
    n_runs : int
        Segments per construction other than ``slow_drift``.
    receiver : int
        0-based index of the receiver (>= 1); vehicle ``receiver - 1`` lies.
    mechanisms : sequence of str
        ``"none"`` and/or ``"hardened"``.
    attacks : sequence of str
        Subset of :data:`RECEIVER_ATTACKS`.
    drift_segments : int
        Consecutive segments of ``slow_drift``.
    guard_options : dict, optional
        Keyword options of :class:`~roadcollab.collaboration.guard.ReceiverGuard` (e.g.
        ``{"bounded": False}`` for the guard before issue 20).
    confirm : bool
        Report only anomalies the receiver's own data confirms (False: every detection of its estimate).
    pipe : FleetPipeline, optional
        The pipeline of ``config`` and ``seed`` if already built.

    Returns
    -------
    list of PoisoningSummary
        One row per mechanism and attack.
    """
    config = ExperimentConfig() if config is None else config
    n_runs = check_int("n_runs", n_runs, low=1)
    drift_segments = check_int("drift_segments", drift_segments, low=2)
    j = check_int("receiver", receiver, low=1, high=config.n_vehicles - 1)
    bad = [a for a in attacks if a not in RECEIVER_ATTACKS] + [m for m in mechanisms if m not in ("none", "hardened")]
    if bad:
        raise ParameterError(f"attacks must be among {RECEIVER_ATTACKS} and mechanisms among ('none', 'hardened'), "
                             f"got {bad}")
    pipe = PipelineCache().pipeline(config, seed) if pipe is None else pipe
    pothole = _pothole_dz(_nominal_estimator(config, pipe.grid), config)[0]
    out = []
    for mech in mechanisms:
        for attack in attacks:
            # A fresh guard per construction: its per-sender record starts empty.
            guard = ReceiverGuard(pipe.estimators[j], pipe.road_moment, config.sensor_noise_std, **(guard_options or {}))
            thr = guard.threshold
            drift = attack == "slow_drift"
            seeds = SeedPlan(seed).runs(drift_segments if drift else n_runs)
            vals = []
            for s, ss in enumerate(seeds):
                if drift:
                    statistic = _DRIFT_START + (0.8 * thr - _DRIFT_START) * s / (len(seeds) - 1)
                else:
                    statistic = (0.9 if attack == "fake_pothole_09" else 0.8) * thr
                vals.append(_segment(pipe, config, guard, j, ss, mech, pothole,
                                     "coherent_down" if drift else attack, statistic, j - 1, confirm))
            a = np.array([v[:3] for v in vals])
            out.append(PoisoningSummary(
                strategy=attack, target=f"receiver_{mech}", honest_mse=float(a[:, 1].mean()),
                attacked_mse=float(a[:, 2].mean()), ratio=float(np.mean(a[:, 2] / a[:, 1])),
                max_ratio_to_observer=float(np.max(a[:, 2] / a[:, 0])),
                fake_anomalies_reported=int(sum(v[3] for v in vals)), real_anomalies_lost=int(sum(v[4] for v in vals)),
                refused=int(sum(v[5] for v in vals)), runs=len(vals)))
    return out
