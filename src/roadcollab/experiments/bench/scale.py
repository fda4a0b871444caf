"""Fleet-scale runs: many road segments x a fleet on a Dask cluster, timed (``roadcollab bench --scale``).

One *segment* is one road window driven by the whole fleet: its road and sensor noise are drawn from
the segment's own :class:`numpy.random.SeedSequence` child, every vehicle records it, and Algorithm 1 is
relayed down the fleet under one exchange mechanism (by default the paper's Algorithm 2, a fresh ``Psi``
per message). Each vehicle-segment is one vehicle's whole per-segment work: simulate its record, take its
spectrum, receive and evaluate the previous vehicle's message, estimate, learn, build and encode its own
message. The result of a segment is the MSE of every vehicle's estimate (the reproduction's band and
scored window), so a cluster run can be compared with a serial one number for number.

Segments are independent, so they are spread over the cluster's workers in chunks
(:func:`~roadcollab.experiments.runner.map_runs`); the fleet's setup (its estimators) is built once per
worker process from the shared :class:`~roadcollab.experiments.pipeline.PipelineCache`. Each segment also
reports the process that ran it and that process's peak resident memory, which gives the peak memory per
worker.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..._validation import check_int
from ...collaboration.relay import MECHANISMS, Exchange, Relay
from ...errors import ParameterError
from ..config import ExperimentConfig
from ..pipeline import PipelineCache, record_run
from ..runner import local_dask_cluster, map_runs
from ..seeds import SeedPlan, run_stream

__all__ = ["SegmentOutcome", "ScalePoint", "ScaleResult", "run_segments", "run_scale"]


@dataclass(frozen=True, eq=False)
class SegmentOutcome:
    """One segment driven by the whole fleet.

    Attributes
    ----------
    index : int
        Segment number (its seed is the root seed's ``index``-th run child).
    mse : (n_vehicles,) ndarray
        MSE of each vehicle's Algorithm-1 estimate, (m/s)^2, band-limited over the scored window.
    pid : int
        Process that ran it.
    peak_rss_mb : float
        That process's peak resident memory after the segment, MB (``ru_maxrss``).
    """

    index: int
    mse: np.ndarray
    pid: int
    peak_rss_mb: float


@dataclass(frozen=True)
class _SegmentTask:
    """Picklable task: segments ``indices`` of one fleet under one mechanism (setup from the cache)."""

    config: ExperimentConfig
    seed: int
    mechanism: str

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[SegmentOutcome]:
        pipe = cache.pipeline(self.config, self.seed)
        grid, n, sl = pipe.grid, pipe.grid.n_samples, self.config.scored
        plan = SeedPlan(self.seed)
        out = []
        for i in indices:
            ss = plan.run(i)
            road_ss, noise_ss, priv_ss = (run_stream(ss, name) for name in ("road", "noise", "privacy"))
            road, ys, Ys = record_run(pipe, road_ss, noise_ss, self.config.sensor_noise_std)
            truth = grid.band_limited(grid.rfft(road.velocity), n)[sl]
            steps = Relay(pipe.estimators, Exchange(self.mechanism, self.config.obfuscation),
                          rng=np.random.default_rng(priv_ss), unguarded=True).run(ys, spectra=Ys)
            mse = np.array([np.mean((grid.band_limited(s.result.W_hat, n)[sl] - truth) ** 2) for s in steps])
            out.append(SegmentOutcome(i, mse, os.getpid(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))
        return out


def run_segments(config: ExperimentConfig, seed: int, n_segments: int, *, mechanism: str = "paper",
                 workers: int | None = None, scheduler: str | None = None,
                 progress: Callable[[int], None] | None = None) -> list[SegmentOutcome]:
    """Drive ``n_segments`` segments with the fleet of ``config`` and ``seed``, serially or in parallel.

    Parameters
    ----------
    config : ExperimentConfig
        Fleet size, segment window, road and noise (``n_runs`` is ignored).
    seed : int
        Root seed: the fleet and each segment's road, noise and obfuscators (segment ``i`` is the same
        whatever ``n_segments`` and wherever it runs).
    n_segments : int
    mechanism : str
        Exchange mechanism (:data:`~roadcollab.collaboration.relay.MECHANISMS`; default Algorithm 2).
    workers : int, optional
        Local process pool with this many workers.
    scheduler : str, optional
        Address of a Dask scheduler (e.g. from :func:`~roadcollab.experiments.runner.local_dask_cluster`).
    progress : callable, optional
        Called with the number of finished segments.

    Returns
    -------
    list of SegmentOutcome
        In segment order.

    Examples
    --------
    >>> import roadcollab as rc
    >>> cfg = rc.ExperimentConfig(n_vehicles=2, segment_length=60.0)
    >>> [s.mse.shape for s in run_segments(cfg, 0, 2)]
    [(2,), (2,)]
    """
    if not isinstance(config, ExperimentConfig):
        raise ParameterError(f"config must be an ExperimentConfig, got {type(config).__name__}")
    if mechanism not in MECHANISMS:
        raise ParameterError(f"mechanism must be one of {MECHANISMS}, got {mechanism!r}")
    n_segments = check_int("n_segments", n_segments, low=1)
    return map_runs(_SegmentTask(config, check_int("seed", seed, low=0), mechanism), n_segments, workers=workers,
                    scheduler=scheduler, progress=progress, shared=PipelineCache())


@dataclass(frozen=True)
class ScalePoint:
    """One timed fleet-scale run.

    Attributes
    ----------
    segments, vehicles, workers : int
        Road segments, fleet size and Dask worker processes.
    wall_s : float
        Wall time of the run on the (already started) cluster, s.
    vehicle_segments_per_s : float
        ``segments * vehicles / wall_s``.
    s_per_segment : float
        ``wall_s / segments``.
    peak_rss_mb_per_worker : float
        Largest peak resident memory of any worker process, MB.
    worker_processes : int
        Worker processes that ran segments.
    """

    segments: int
    vehicles: int
    workers: int
    wall_s: float
    vehicle_segments_per_s: float
    s_per_segment: float
    peak_rss_mb_per_worker: float
    worker_processes: int


@dataclass(frozen=True)
class ScaleResult:
    """Fleet-scale runs at several sizes on one cluster, with a linear fit and a serial check.

    Attributes
    ----------
    points : list of ScalePoint
        One per size, in the order run.
    fixed_s, per_segment_s : float
        Least-squares fit ``wall_s = fixed_s + per_segment_s * segments`` over the points.
    max_fit_residual : float
        Largest ``|wall_s - fit| / wall_s`` over the points (small: the cost is linear in segments).
    cluster_start_s : float
        Time to start the local cluster, s (not in ``wall_s``).
    warmup_s : float
        A first run of one segment per worker before the timed ones (the workers import the package), s.
    serial_check_segments : int
        Segments also run serially for the comparison (0: not checked).
    identical_to_serial : bool or None
        Every checked segment's MSEs equal bit for bit on the cluster and serially.
    samples_per_segment : int
    mechanism : str
    """

    points: list[ScalePoint]
    fixed_s: float
    per_segment_s: float
    max_fit_residual: float
    cluster_start_s: float
    warmup_s: float
    serial_check_segments: int
    identical_to_serial: bool | None
    samples_per_segment: int
    mechanism: str

    def to_dict(self) -> dict:
        """JSON-ready record (``points`` as a list of dicts).

        Returns
        -------
        dict
        """
        return dataclasses.asdict(self)


def _point(outcomes: Sequence[SegmentOutcome], vehicles: int, workers: int, wall: float) -> ScalePoint:
    """The timing record of one run from its segments' outcomes."""
    peak: dict[int, float] = {}
    for o in outcomes:
        peak[o.pid] = max(peak.get(o.pid, 0.0), o.peak_rss_mb)
    n = len(outcomes)
    return ScalePoint(n, vehicles, workers, wall, n * vehicles / wall, wall / n, max(peak.values()), len(peak))


def _linear_fit(points: Sequence[ScalePoint]) -> tuple[float, float, float]:
    """``wall = a + b segments`` by least squares (through the one point if only one), and the worst residual."""
    n = np.array([p.segments for p in points], dtype=float)
    t = np.array([p.wall_s for p in points])
    if len(points) < 2 or np.ptp(n) == 0:
        return 0.0, float(t.mean() / n.mean()), 0.0
    b, a = np.polyfit(n, t, 1)
    return float(a), float(b), float(np.max(np.abs(t - (a + b * n)) / t))


def run_scale(sizes: Sequence[int], *, n_vehicles: int = 20, workers: int = 2, seed: int = 0,
              mechanism: str = "paper", segment_length: float = 300.0, check_segments: int = 4,
              progress: Callable[[str, int, int], None] | None = None) -> ScaleResult:
    """Time fleet-scale runs of each size on one local Dask cluster and check them against serial.

    Parameters
    ----------
    sizes : sequence of int
        Segments per run (e.g. ``(100, 300, 1000)``), run in this order on the same cluster.
    n_vehicles : int
        Fleet size.
    workers : int
        Dask worker processes (one thread each).
    seed : int
        Root seed.
    mechanism : str
        Exchange mechanism (default Algorithm 2).
    segment_length : float
        Scored metres per segment (plus 15 m lead-in and lead-out; 300 m at 15 m/s is 4000 samples).
    check_segments : int
        The first segments of the smallest run are also run serially and compared bit for bit (0: skip).
    progress : callable, optional
        ``progress(label, done, total)`` as segments finish.

    Returns
    -------
    ScaleResult
    """
    sizes = [check_int("sizes", s, low=1) for s in sizes]
    if not sizes:
        raise ParameterError("sizes must hold at least one number of segments")
    check_segments = check_int("check_segments", check_segments, low=0)
    config = ExperimentConfig(n_vehicles=n_vehicles, n_runs=1, segment_length=segment_length)
    t0 = time.perf_counter()
    points, first = [], None
    with local_dask_cluster(workers) as address:
        started = time.perf_counter() - t0
        t = time.perf_counter()
        run_segments(config, seed, workers, mechanism=mechanism, scheduler=address)
        warmup = time.perf_counter() - t
        for n in sizes:
            cb = None if progress is None else (lambda done, n=n: progress(f"{n} segments", done, n))
            t = time.perf_counter()
            outcomes = run_segments(config, seed, n, mechanism=mechanism, scheduler=address, progress=cb)
            points.append(_point(outcomes, n_vehicles, workers, time.perf_counter() - t))
            first = outcomes if first is None or len(outcomes) < len(first) else first
    same, k = None, 0
    if first and check_segments:
        k = min(check_segments, len(first))
        serial = run_segments(config, seed, k, mechanism=mechanism)
        same = all(np.array_equal(a.mse, b.mse) for a, b in zip(serial, first[:k]))
    a, b, worst = _linear_fit(points)
    return ScaleResult(points, a, b, worst, started, warmup, k, same, config.n_samples, mechanism)
