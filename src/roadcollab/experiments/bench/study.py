"""``roadcollab bench``: the per-segment cost of one vehicle, as on a car that drives segment
after segment with its models and gains already built.

Per-segment work (timed): the vehicle's own work from the received bytes and its recorded
accelerations to the bytes it sends: decode and validate the previous vehicle's message (the
stability certificate of ``T`` and ``S`` included), the spectrum of its record, estimate
(observer), learn (eqs. 11-12; the receiver's evaluation of the sender's ``T`` and ``S``), build
the outgoing message (obfuscate for ``paper``: two ``Psi`` draws, the realisations, their
certificate) and encode it. Not timed: simulating the vehicle's response to the road and its
sensor noise (on a car the record comes from the accelerometers; the simulation cost 0.4 ms of
the 1.1 ms measured for ``hardened`` before this was separated), and the previous vehicle's work.

Caches are keyed by the exact bytes of the sender's systems and are never cleared: the receiver
decodes with its :class:`~roadcollab.lti.realisation.SystemCache` and evaluates through its
:class:`~roadcollab.lti.response.FrequencyResponseCache`, so where the sender's systems do not
change between segments (``none``, and ``paper_vehicle``, which keeps one obfuscation channel per
vehicle) they are certified and evaluated once, on the first (untimed) segment; ``paper`` sends
new systems every segment, which are evaluated every time.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from ... import __version__
from ...wire import protocol
from ..._validation import check_int
from ...errors import MessageError, ParameterError
from ...wire.fields import Message
from ...wire.message import ExchangeMessage, InversionMessage
from ...experiments.config import ExperimentConfig
from ...experiments.pipeline import FleetPipeline
from ...collaboration.algorithm1 import CollaborativeEstimator
from ...collaboration.relay import Exchange, Relay, simulate_measurements
from .naive import exactness_figures, floor_ms, naive_paper_step
from ...models.simulation import add_sensor_noise, simulate_response
from ...models.vehicle import sample_fleet
from ...lti.kernels import KERNELS, compiled_available, kernel_path, use_kernels

__all__ = ["bench_segment", "bench_kernel_paths", "bench_naive", "bench_exactness", "machine_load", "run_bench"]

MECHANISMS = ("none", "paper", "paper_vehicle", "hardened")


def _config_for(n_samples: int) -> ExperimentConfig:
    """A configuration whose recorded window has ``n_samples`` samples (no margins)."""
    base = ExperimentConfig(n_vehicles=2, n_runs=1, margin=0.0)
    length = n_samples * base.speed / base.sample_rate
    return dataclasses.replace(base, segment_length=length)


def _exchange(message: Message) -> ExchangeMessage | InversionMessage:
    """A decoded relay message (the bench sends only those; a secure-aggregation message is refused)."""
    if not isinstance(message, (ExchangeMessage, InversionMessage)):
        raise MessageError(f"expected a relay message, got {type(message).__name__}")
    return message


def bench_segment(n_samples: int = 4000, *, mechanism: str = "paper", repeats: int = 30, seed: int = 0,
                  kernels: str | None = None) -> dict:
    """Median milliseconds of one vehicle's per-segment work, and of its setup.

    Parameters
    ----------
    n_samples : int
        Samples per segment (4000 = 300 m at 15 m/s sampled at 200 Hz).
    mechanism : {"none", "paper", "paper_vehicle", "hardened"}
    repeats : int
        Timed segments (each on a fresh road, after one untimed segment); the median is reported.
    seed : int
    kernels : {"compiled", "reference"}, optional
        The evaluation path (:mod:`~roadcollab.lti.kernels`); by default the one in effect.

    Returns
    -------
    dict
        ``ms_per_vehicle_segment`` (median), ``ms_min``, ``kernels`` (the path used),
        ``ms_receive_median`` (decode, estimate and learn) and ``ms_send_median`` (build, obfuscate,
        encode), ``ms_per_vehicle_setup``, ``ms_pipeline_setup_2_vehicles`` (ms),
        ``samples_per_segment``, ``nfft``, ``mechanism``, and ``max_rel_privacy_vs_clear``: for
        ``paper`` and ``paper_vehicle`` the largest ``max |W_hat - W_hat_clear| / max |W_hat_clear|``
        over every segment run (the receiver's estimate from the obfuscated message against the one
        from the clear message; 0 otherwise).
    """
    n_samples = check_int("n_samples", n_samples, low=64, high=2**20)
    repeats = check_int("repeats", repeats, low=1)
    if mechanism not in MECHANISMS:
        raise ParameterError(f"mechanism must be one of {MECHANISMS}, got {mechanism!r}")
    if kernels is not None and kernels not in KERNELS:
        raise ParameterError(f"kernels must be one of {KERNELS}, got {kernels!r}")
    with use_kernels(kernels or kernel_path()):
        return _bench_segment(n_samples, mechanism, repeats, seed)


def _bench_segment(n_samples: int, mechanism: str, repeats: int, seed: int) -> dict:
    """:func:`bench_segment` on the kernel path in effect."""
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
    relay = Relay(pipe.estimators, Exchange(mechanism, cfg.obfuscation), rng=rng, unguarded=True)
    if mechanism == "paper_vehicle":     # per-vehicle channels are drawn once, in setup
        relay.channel(0)
        relay.channel(1)
    times, receive, send, worst = [], [], [], 0.0
    for k in range(repeats + 1):
        w = pipe.road(rng).velocity[:grid.n_samples]
        # The previous vehicle's message and this vehicle's record (not timed: the former is the
        # other vehicle's work, the latter comes from the sensors).
        y_prev = add_sensor_noise(simulate_response(prev.true_plant, w), cfg.sensor_noise_std, rng=rng)
        sent = relay.send(0, prev.estimate(y_prev))
        incoming = protocol.encode(sent.message)
        y = add_sensor_noise(simulate_response(car.true_plant, w), cfg.sensor_noise_std, rng=rng)
        # Relay.step, split where the receiver's work ends and the sender's begins (no guard here).
        t0 = time.perf_counter()
        msg_in = _exchange(protocol.decode(incoming, systems=car.system_cache))
        result = car.estimate(y, msg_in, unguarded=True)
        t1 = time.perf_counter()
        protocol.encode(relay.send(1, result, msg_in).message)
        t2 = time.perf_counter()
        if k:                                 # the first segment warms the receiver's caches
            times.append((t2 - t0) * 1e3)
            receive.append((t1 - t0) * 1e3)
            send.append((t2 - t1) * 1e3)
        if sent.clear is not None:            # Theorem 1 on every segment (not timed)
            ref = car.estimate(y, sent.clear, unguarded=True).W_hat
            worst = max(worst, float(np.max(np.abs(result.W_hat - ref)) / np.max(np.abs(ref))))
    return {"mechanism": mechanism, "kernels": kernel_path(), "samples_per_segment": grid.n_samples, "nfft": grid.nfft,
            "ms_per_vehicle_segment": statistics.median(times), "ms_min": min(times),
            "ms_receive_median": statistics.median(receive), "ms_send_median": statistics.median(send),
            "max_rel_privacy_vs_clear": worst, "ms_per_vehicle_setup": statistics.median(setups), "ms_pipeline_setup_2_vehicles": setup_total * 1e3}


def bench_kernel_paths(n_samples: int = 4000, *, mechanism: str = "paper", repeats: int = 30, seed: int = 0,
                       rounds: int = 3) -> dict:
    """:func:`bench_segment` on the compiled and the reference path in one run, alternating: ``rounds``
    rounds of ``repeats // rounds`` segments each (the same seed, so the same segments), the two
    paths in turn (which goes first alternates), so both are timed under the same machine load.

    Parameters
    ----------
    n_samples : int
    mechanism : str
    repeats : int
        Timed segments per path over all rounds.
    seed : int
    rounds : int

    Returns
    -------
    dict
        ``{path: {"ms_min", "ms_median", "ms_receive_median", "ms_send_median"}}`` for the paths
        that ran (``compiled`` only when numba imports), and ``speedup_median`` / ``speedup_min``
        (reference over compiled, the medians of the per-round ratios), when both ran.
    """
    paths = list(KERNELS) if compiled_available() else ["reference"]
    per = max(1, check_int("repeats", repeats, low=1) // check_int("rounds", rounds, low=1))
    rows: dict[str, list[dict]] = {k: [] for k in paths}
    for r in range(rounds):
        for k in (paths if r % 2 == 0 else paths[::-1]):
            rows[k].append(bench_segment(n_samples, mechanism=mechanism, repeats=per, seed=seed, kernels=k))
    out: dict = {}
    for k, rs in rows.items():
        out[k] = {"ms_min": min(x["ms_min"] for x in rs),
                  "ms_median": statistics.median(x["ms_per_vehicle_segment"] for x in rs),
                  "ms_receive_median": statistics.median(x["ms_receive_median"] for x in rs),
                  "ms_send_median": statistics.median(x["ms_send_median"] for x in rs)}
    if len(paths) == 2:
        out["speedup_median"] = statistics.median(a["ms_per_vehicle_segment"] / b["ms_per_vehicle_segment"]
                                                  for a, b in zip(rows["reference"], rows["compiled"]))
        out["speedup_min"] = statistics.median(a["ms_min"] / b["ms_min"] for a, b in zip(rows["reference"], rows["compiled"]))
    return out


def bench_naive(n_samples: int = 4000, *, repeats: int = 30, seed: int = 0) -> dict:
    """Milliseconds of one ``paper`` vehicle-segment by the naive numpy chain
    (:func:`~roadcollab.experiments.bench.naive.naive_paper_step`) and by the library, paired: on
    every segment both run on the same received bytes and record, back to back (alternating which
    goes first), timed like :func:`bench_segment` (decode to encode; the simulated record is not
    timed). Pairing makes the speed-up a ratio of two measurements taken under the same machine
    load: measured separately, minutes apart, on this shared VM it moved between 5.1 and 8.4 (min).

    Parameters
    ----------
    n_samples : int
        Samples per segment.
    repeats : int
        Timed segments.
    seed : int

    Returns
    -------
    dict
        ``ms_min``, ``ms_median`` (naive), ``library_ms_min``, ``library_ms_median`` (the library on
        the same segments), ``speedup_min`` (naive min / library min), ``speedup_median`` (ratio of
        medians), ``speedup_per_segment_median`` (median over segments of naive / library) and
        ``max_rel_vs_library`` (largest ``max |W_hat_naive - W_hat| / max |W_hat|`` over the segments,
        spectra).
    """
    n_samples = check_int("n_samples", n_samples, low=64, high=2**20)
    repeats = check_int("repeats", repeats, low=1)
    cfg = _config_for(n_samples)
    rng = np.random.default_rng(seed)
    pipe = FleetPipeline(cfg, sample_fleet(2, cfg.fleet, rng=rng))
    prev, car = pipe.estimators
    relay = Relay(pipe.estimators, Exchange("paper", cfg.obfuscation), rng=rng, unguarded=True)
    naive, lib, worst = [], [], 0.0
    for k in range(repeats + 1):
        w = pipe.road(rng).velocity[:pipe.grid.n_samples]
        y_prev = add_sensor_noise(simulate_response(prev.true_plant, w), cfg.sensor_noise_std, rng=rng)
        incoming = protocol.encode(relay.send(0, prev.estimate(y_prev)).message)
        y = add_sensor_noise(simulate_response(car.true_plant, w), cfg.sensor_noise_std, rng=rng)
        pair = {}
        for which in (("naive", "library") if k % 2 else ("library", "naive")):
            t0 = time.perf_counter()
            if which == "naive":
                _, W_hat = naive_paper_step(car, incoming, y, cfg.obfuscation, rng)
            else:
                protocol.encode(relay.step(1, y, protocol.decode(incoming, systems=car.system_cache)).message)
            pair[which] = (time.perf_counter() - t0) * 1e3
        if k:                                 # the first segment warms the library receiver's caches
            naive.append(pair["naive"])
            lib.append(pair["library"])
        ref = car.estimate(y, _exchange(protocol.decode(incoming)), unguarded=True).W_hat
        worst = max(worst, float(np.max(np.abs(W_hat - ref)) / np.max(np.abs(ref))))
    return {"ms_min": min(naive), "ms_median": statistics.median(naive), "library_ms_min": min(lib),
            "library_ms_median": statistics.median(lib), "speedup_min": min(naive) / min(lib),
            "speedup_median": statistics.median(naive) / statistics.median(lib),
            "speedup_per_segment_median": statistics.median(a / b for a, b in zip(naive, lib)),
            "max_rel_vs_library": worst}


def bench_exactness(*, segments: int = 10, n_samples: int = 4000, seed: int = 0) -> dict:
    """Theorem 1 on ``segments`` segments of a 3-vehicle fleet (every vehicle's estimate with
    ``paper`` vs ``none``), the largest figures of
    :func:`~roadcollab.experiments.bench.naive.exactness_figures`.

    Parameters
    ----------
    segments : int
        Relayed segments (a new road each).
    n_samples : int
        Samples per segment.
    seed : int

    Returns
    -------
    dict
        The keys of ``exactness_figures``, each its largest value over the segments.
    """
    cfg = dataclasses.replace(_config_for(n_samples), n_vehicles=3)
    rng = np.random.default_rng(seed)
    pipe = FleetPipeline(cfg, sample_fleet(3, cfg.fleet, rng=rng))
    out: dict[str, float] = {}
    for _ in range(check_int("segments", segments, low=1)):
        w = pipe.road(rng).velocity[:pipe.grid.n_samples]
        ys = simulate_measurements(pipe.estimators, w, cfg.sensor_noise_std, rng=rng)
        clear = Relay(pipe.estimators, "none", unguarded=True).run(ys)
        paper = Relay(pipe.estimators, Exchange("paper", cfg.obfuscation), rng=rng, unguarded=True).run(ys)
        for k, v in exactness_figures(pipe.estimators, clear, paper, pipe.grid).items():
            out[k] = max(out.get(k, 0.0), v)
    return out


def _scaling(sizes, repeats: int, seed: int) -> list[dict]:
    """The scaling points of :func:`run_bench`, with the cost per ``N log2 N`` relative to the
    4000-sample point (else the first): flat means ``N log N``."""
    scaling = []
    for n in sizes:
        rec = {"n_samples": int(n)}
        for m in ("paper", "hardened"):
            rec[f"ms_{m}"] = bench_segment(n, mechanism=m, repeats=max(3, repeats // 3), seed=seed)[
                "ms_per_vehicle_segment"]
        scaling.append(rec)
    ref = next((s for s in scaling if s["n_samples"] == 4000), scaling[0])
    for s in scaling:
        for m in ("paper", "hardened"):
            nl = s["n_samples"] * np.log2(s["n_samples"])
            nl0 = ref["n_samples"] * np.log2(ref["n_samples"])
            s[f"{m}_per_nlogn_rel"] = (s[f"ms_{m}"] / nl) / (ref[f"ms_{m}"] / nl0)
    return scaling


def machine_load() -> list[float] | None:
    """The machine's 1-, 5- and 15-minute load averages (``os.getloadavg``): what the speed targets
    are stated against ("on a quiet machine"), recorded beside every benchmark.

    Returns
    -------
    list of float, or None
        Three load averages; None where the system keeps none.
    """
    try:
        return [float(x) for x in os.getloadavg()]
    except (AttributeError, OSError):        # no getloadavg (Windows), or it failed
        return None


def run_bench(*, sizes=(1000, 2000, 4000, 8000, 16000, 32000, 64000), repeats: int = 30, seed: int = 0,
              kernels: str | None = None, exactness_segments: int | None = None) -> dict:
    """The benchmark record printed by ``roadcollab bench --json``.

    Single-threaded (BLAS limited to one thread): :func:`bench_segment` at 4000 samples for every
    mechanism, the naive ``paper`` chain (:func:`bench_naive`), the floor
    (:func:`~roadcollab.experiments.bench.naive.floor_ms`), Theorem 1 measured
    (:func:`bench_exactness`), then the ``paper`` and ``hardened`` mechanisms at every size of ``sizes``.

    Parameters
    ----------
    sizes : sequence of int
        Samples per segment of the scaling points (non-empty, each in [64, 2**20]). The 4000-sample
        point (else the first) is the reference of the normalised costs.
    repeats : int
        Timed segments (>= 1) of the 4000-sample measurements; the scaling points use
        ``max(3, repeats // 3)``.
    seed : int
        Seed of every measurement (fleet, roads, sensor noise, obfuscators).
    kernels : {"compiled", "reference"}, optional
        The evaluation path of every measurement except ``kernel_paths`` (which times both); by
        default the one in effect (:mod:`~roadcollab.lti.kernels`).
    exactness_segments : int, optional
        Segments of :func:`bench_exactness` (default ``repeats``).

    Returns
    -------
    dict
        ``by_mechanism`` (``{mechanism: {"ms_min", "ms_median", "ms_receive_median", "ms_send_median",
        "floor_multiple_min", "floor_multiple_median"}}``), ``floor`` (``fft_pair_ms``, ``matvec_ms``, ``floor_ms``),
        ``naive_paper`` (as :func:`bench_naive`), ``speedup_paper_vs_naive`` (from the paired
        measurement of :func:`bench_naive`: ``min`` naive min / library min, ``median`` the same for
        medians, ``per_segment_median`` the median of the per-segment ratios), ``exactness`` (see
        :func:`bench_exactness`), ``ms_per_vehicle_segment`` (``paper``, median, ms),
        ``ms_per_vehicle_segment_by_mechanism`` (medians), ``ms_per_vehicle_setup`` (ms),
        ``samples_per_segment``, ``nfft``, ``scaling`` (one dict per size: ``n_samples``,
        ``ms_paper``, ``ms_hardened`` (medians, ms), and ``paper_per_nlogn_rel``,
        ``hardened_per_nlogn_rel``: cost per ``N log2 N`` relative to the reference point, 1
        everywhere for ``N log N`` scaling), ``repeats`` and ``threads`` (1), ``kernels`` (the path
        used), ``kernel_paths`` (``paper`` on both paths, :func:`bench_kernel_paths`) and
        ``max_rel_privacy_vs_clear`` (the largest of every mechanism's, over every segment it ran), ``seed``,
        ``roadcollab_version`` and ``load_average`` (:func:`machine_load` at ``"start"`` and ``"end"``).
    """
    if kernels is not None and kernels not in KERNELS:
        raise ParameterError(f"kernels must be one of {KERNELS}, got {kernels!r}")
    load_start = machine_load()
    with threadpool_limits(limits=1), use_kernels(kernels or kernel_path()):
        main = {m: bench_segment(4000, mechanism=m, repeats=repeats, seed=seed) for m in MECHANISMS}
        paths = bench_kernel_paths(4000, repeats=repeats, seed=seed)
        naive = bench_naive(4000, repeats=repeats, seed=seed)
        cfg = _config_for(4000)
        floor = floor_ms(FleetPipeline(cfg, sample_fleet(2, cfg.fleet, rng=seed)).grid)
        exact = bench_exactness(segments=exactness_segments or repeats, seed=seed)
        path = kernel_path()
        scaling = _scaling(sizes, repeats, seed)
    f = floor["floor_ms"]
    by_mech = {m: {"ms_min": r["ms_min"], "ms_median": r["ms_per_vehicle_segment"],
                   "ms_receive_median": r["ms_receive_median"], "ms_send_median": r["ms_send_median"],
                   "floor_multiple_min": r["ms_min"] / f, "floor_multiple_median": r["ms_per_vehicle_segment"] / f}
               for m, r in main.items()}
    return {
        "by_mechanism": by_mech,
        "floor": floor,
        "naive_paper": naive,
        "speedup_paper_vs_naive": {"min": naive["speedup_min"], "median": naive["speedup_median"],
                                   "per_segment_median": naive["speedup_per_segment_median"]},
        "exactness": exact,
        "ms_per_vehicle_segment": main["paper"]["ms_per_vehicle_segment"],
        "ms_per_vehicle_segment_by_mechanism": {m: main[m]["ms_per_vehicle_segment"] for m in MECHANISMS},
        "ms_per_vehicle_setup": main["paper"]["ms_per_vehicle_setup"],
        "samples_per_segment": main["paper"]["samples_per_segment"],
        "nfft": main["paper"]["nfft"],
        "scaling": scaling,
        "repeats": repeats,
        "threads": 1,
        "kernels": path,
        "kernel_paths": paths,
        "max_rel_privacy_vs_clear": max(r["max_rel_privacy_vs_clear"] for r in main.values()),
        "load_average": {"start": load_start, "end": machine_load()}, "seed": seed, "roadcollab_version": __version__,
    }
