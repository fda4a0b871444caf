"""``roadcollab bench``: the per-segment cost of one vehicle, as on a car that drives segment
after segment with its models and gains already built.

Per-segment work (timed): decode the previous vehicle's message, simulate the vehicle's
response to the road (with sensor noise), estimate (observer), learn (eqs. 11-12), build the
outgoing message (obfuscate for ``paper``), encode it. The frequency-response memo is cleared
before every repeat, so the receiver's evaluation of the sender's systems is counted; where the
sender's systems do not change between segments (``none``, and ``paper_vehicle``, which keeps
one obfuscation channel per vehicle instead of redrawing ``Psi`` per message), the receiver's
responses are warmed once, untimed, as a receiver caching them by content would have them.
"""

from __future__ import annotations

import dataclasses
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from ..wire import protocol
from .._validation import check_int
from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..experiments.pipeline import FleetPipeline
from ..collaboration.algorithm1 import CollaborativeEstimator
from ..collaboration.relay import Exchange, Relay
from ..models.simulation import add_sensor_noise, simulate_response
from ..models.vehicle import sample_fleet

__all__ = ["bench_segment", "run_bench"]

MECHANISMS = ("none", "paper", "paper_vehicle", "hardened")


def _config_for(n_samples: int) -> ExperimentConfig:
    """A configuration whose recorded window has ``n_samples`` samples (no margins)."""
    base = ExperimentConfig(n_vehicles=2, n_runs=1, margin=0.0)
    length = n_samples * base.speed / base.sample_rate
    return dataclasses.replace(base, segment_length=length)


def bench_segment(n_samples: int = 4000, *, mechanism: str = "paper", repeats: int = 30, seed: int = 0) -> dict:
    """Median milliseconds of one vehicle's per-segment work, and of its setup.

    Parameters
    ----------
    n_samples : int
        Samples per segment (4000 = 300 m at 15 m/s sampled at 200 Hz).
    mechanism : {"none", "paper", "paper_vehicle", "hardened"}
    repeats : int
        Timed segments (each on a fresh road); the median is reported.
    seed : int
    """
    n_samples = check_int("n_samples", n_samples, low=64, high=2**20)
    repeats = check_int("repeats", repeats, low=1)
    if mechanism not in MECHANISMS:
        raise ParameterError(f"mechanism must be one of {MECHANISMS}, got {mechanism!r}")
    cfg = _config_for(n_samples)
    rng = np.random.default_rng(seed)
    fleet = sample_fleet(2, cfg.fleet, rng=rng)
    t0 = time.perf_counter()
    pipe = FleetPipeline(cfg, fleet)     # the linear MMSE statistics are lazy: not built here
    setup_total = time.perf_counter() - t0
    setups = []
    for _ in range(3):
        t0 = time.perf_counter()
        CollaborativeEstimator(fleet[1], cfg.noise_model(), pipe.grid, gamma=cfg.gamma)
        setups.append((time.perf_counter() - t0) * 1e3)
    prev, car = pipe.estimators
    grid = pipe.grid
    relay = Relay(pipe.estimators, Exchange(mechanism, cfg.obfuscation), rng=rng)
    if mechanism == "paper_vehicle":     # per-vehicle channels are drawn once, in setup
        relay.channel(0)
        relay.channel(1)
    persistent = mechanism in ("none", "paper_vehicle")
    times = []
    for _ in range(repeats):
        road = pipe.road(rng)
        w = road.velocity[:grid.n_samples]
        # The previous vehicle's message (not timed: that is its own work).
        y_prev = add_sensor_noise(simulate_response(prev.true_plant, w), cfg.sensor_noise_std, rng=rng)
        incoming = protocol.encode(relay.send(0, prev.estimate(y_prev)).message)
        car.response_cache.clear()
        if persistent:   # a receiver that cached the unchanged sender systems (untimed)
            warm = protocol.decode(incoming)
            om = grid.omega_dt[grid.active]
            car.response_cache.response(warm.T, om)
            car.response_cache.response(warm.S, om)
        t0 = time.perf_counter()
        msg_in = protocol.decode(incoming)
        y = add_sensor_noise(simulate_response(car.true_plant, w), cfg.sensor_noise_std, rng=rng)
        protocol.encode(relay.step(1, y, msg_in).message)
        times.append((time.perf_counter() - t0) * 1e3)
    return {"mechanism": mechanism, "samples_per_segment": grid.n_samples, "nfft": grid.nfft,
            "ms_per_vehicle_segment": statistics.median(times), "ms_per_vehicle_setup": statistics.median(setups),
            "ms_pipeline_setup_2_vehicles": setup_total * 1e3}


def run_bench(*, sizes=(1000, 2000, 4000, 8000, 16000, 32000, 64000), repeats: int = 30, seed: int = 0) -> dict:
    """The benchmark record printed by ``roadcollab bench --json``.

    Single-threaded (BLAS limited to one thread): :func:`bench_segment` at 4000 samples for every
    mechanism, then the ``paper`` and ``hardened`` mechanisms at every size of ``sizes``.

    Parameters
    ----------
    sizes : sequence of int
        Samples per segment of the scaling points (non-empty, each in [64, 2**20]). The 4000-sample
        point (else the first) is the reference of the normalised costs.
    repeats : int
        Timed segments (>= 1) of the 4000-sample measurement; the scaling points use
        ``max(3, repeats // 3)``.
    seed : int
        Seed of every :func:`bench_segment` call (fleet, roads, sensor noise, obfuscators).

    Returns
    -------
    dict
        ``ms_per_vehicle_segment`` (``paper`` mechanism, ms), ``ms_per_vehicle_segment_by_mechanism``
        (``{mechanism: ms}``), ``ms_per_vehicle_setup`` (ms), ``samples_per_segment``, ``nfft``,
        ``scaling`` (one dict per size: ``n_samples``, ``ms_paper``, ``ms_hardened`` in ms, and
        ``paper_per_nlogn_rel``, ``hardened_per_nlogn_rel``: cost per ``N log2 N`` relative to the
        reference point, 1 everywhere for ``N log N`` scaling) and ``threads`` (1).
    """
    with threadpool_limits(limits=1):
        main = {m: bench_segment(4000, mechanism=m, repeats=repeats, seed=seed) for m in MECHANISMS}
        scaling = []
        for n in sizes:
            rec = {"n_samples": int(n)}
            for m in ("paper", "hardened"):
                rec[f"ms_{m}"] = bench_segment(n, mechanism=m, repeats=max(3, repeats // 3), seed=seed)[
                    "ms_per_vehicle_segment"]
            scaling.append(rec)
    # Normalised cost per N log2 N, relative to the 4000-sample point: flat means N log N.
    ref = next((s for s in scaling if s["n_samples"] == 4000), scaling[0])
    for s in scaling:
        for m in ("paper", "hardened"):
            nl = s["n_samples"] * np.log2(s["n_samples"])
            nl0 = ref["n_samples"] * np.log2(ref["n_samples"])
            s[f"{m}_per_nlogn_rel"] = (s[f"ms_{m}"] / nl) / (ref[f"ms_{m}"] / nl0)
    return {
        "ms_per_vehicle_segment": main["paper"]["ms_per_vehicle_segment"],
        "ms_per_vehicle_segment_by_mechanism": {m: main[m]["ms_per_vehicle_segment"] for m in MECHANISMS},
        "ms_per_vehicle_setup": main["paper"]["ms_per_vehicle_setup"],
        "samples_per_segment": main["paper"]["samples_per_segment"],
        "nfft": main["paper"]["nfft"],
        "scaling": scaling,
        "threads": 1,
    }
