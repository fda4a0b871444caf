"""Monte Carlo reproduction of the paper's simulations (Figs. 4-7).

One *run* draws a road (and, for a measured profile, its second track), the sensor noise of
every vehicle and the obfuscators, and relays Algorithm 1 down the fleet twice on the same
measurements: in the clear (``none``) and with Algorithm 2 (``paper``). The fleet (true and
estimated parameters) is drawn once per reproduction, so "vehicle j" means the same car in
every run. Every run gets its own :class:`numpy.random.SeedSequence` child, so results do not
depend on how runs are scheduled.

MSE (the same for every estimator): the mean over the scored segment (the window minus the
lead-in and lead-out margins) and both tracks of the squared difference between the
band-limited true road velocity and the band-limited estimate, (m/s)^2; the band is the
weight ``W`` of :class:`~roadcollab.estimation.grid.SegmentGrid` (DC and the lowest frequencies are
invisible to accelerometers). NMSE divides by the band-limited truth's mean square.

The configuration is :class:`~roadcollab.experiments.config.ExperimentConfig`, the per-fleet
setup and the seeds are in :mod:`roadcollab.experiments.pipeline`, and the estimates that
applications (anomaly detection) use are :func:`roadcollab.experiments.anomalies.estimates.run_estimates`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from ..._validation import check_int, check_positive
from ...collaboration.relay import Exchange, Relay, RelayStep
from ...estimation.grid import SegmentGrid
from ...errors import ParameterError
from ...models.vehicle import Vehicle, sample_fleet
from ...privacy.obfuscation import theorem1_errors
from ...wire.message import ExchangeMessage
from ..config import ExperimentConfig
from ..pipeline import FleetPipeline, PipelineCache, fleet_and_run_seeds, record_run
from .iri import RunIri, iri_rows, run_iri
from .rows import WINDOWED_CONTROL, BoundRow, FleetRow, FusionRow, IriRow, MseRow, RunTraces
from ..seeds import SeedPlan, as_seed_sequence, run_stream
from ..runner import Job, map_jobs

__all__ = ["ESTIMATORS", "WINDOWED_CONTROL", "RunResult", "ReproductionResult", "run_reproduction", "run_reproductions",
           "simulate_run"]


#: Estimators scored by the reproduction, in the order of ``mse.csv`` and Fig. 4.
ESTIMATORS = ("observer_only", "own_inversion", "own_posterior_inversion", "algorithm1", "algorithm1_private", "fused",
              "fused_posterior", "centralized", "oracle_per_bin")


@dataclass(frozen=True, eq=False)
class RunResult:
    """Per-vehicle metrics of one run.

    Attributes
    ----------
    mse : dict of str to (n_vehicles,) ndarray
        MSE of every estimator in :data:`ESTIMATORS` and of :data:`WINDOWED_CONTROL`, (m/s)^2. ``fused``,
        ``centralized`` and ``oracle_per_bin`` at vehicle ``j`` use the records of vehicles ``1..j``.
    max_rel_diff : (n_vehicles,) ndarray
        ``max |w_hat_private - w_hat| / max |w_hat|`` over the record (Theorem 1, estimates).
    max_rel_diff_hardened : (n_vehicles,) ndarray
        The same for the hardened exchange.
    theorem1_e, theorem1_wf : (n_vehicles,) ndarray
        Largest per-bin relative error of the sent ``e~`` against ``Psi1 e`` and of ``w~f``
        against ``Psi2^-1 w^f`` in band (:func:`~roadcollab.privacy.obfuscation.theorem1_errors`).
    theorem1_e_band, theorem1_wf_band : (n_vehicles,) ndarray
        The same errors relative over the whole band (2-norms).
    truth_power : float
        Mean square of the band-limited true road velocity, (m/s)^2.
    traces : RunTraces or None
        Time series for Figs. 5-7.
    iri : RunIri or None
        IRI per segment of the truth and of the last vehicle's estimates.
    """

    mse: dict
    max_rel_diff: np.ndarray
    max_rel_diff_hardened: np.ndarray
    theorem1_e: np.ndarray
    theorem1_wf: np.ndarray
    theorem1_e_band: np.ndarray
    theorem1_wf_band: np.ndarray
    truth_power: float
    traces: RunTraces | None = None
    iri: RunIri | None = None


def _estimate_spectra(pipe: FleetPipeline, j: int, Ys: list, plain, priv, fused, fused_post, central: list,
                      oracle: list) -> dict:
    """Spectrum of every estimator in :data:`ESTIMATORS` at vehicle ``j`` (0-based) from the relays' steps
    and the linear MMSE estimates of every prefix of the fleet (``central``, ``oracle``)."""
    est, r = pipe.estimators[j], plain.result
    return {"observer_only": r.W_obs, "own_inversion": est.invert(Ys[j]),
            "own_posterior_inversion": est.invert(Ys[j], posterior=True), "algorithm1": r.W_hat,
            "algorithm1_private": priv.result.W_hat, "fused": fused.estimate_spectrum,
            "fused_posterior": fused_post.estimate_spectrum, "centralized": central[j], "oracle_per_bin": oracle[j]}


def _theorem1(step: RelayStep, grid: SegmentGrid) -> tuple[float, float, float, float]:
    """Eq. 17 measured on one step of the private relay (:func:`~roadcollab.privacy.obfuscation.theorem1_errors`)."""
    clear, psi = step.clear, step.psi
    if clear is None or psi is None or not isinstance(step.message, ExchangeMessage):
        raise ParameterError("a step of the private relay carries no clear message or obfuscators")
    return theorem1_errors(clear, step.message, psi[0], psi[1], grid)


def simulate_run(pipe: FleetPipeline, rng, *, keep_traces: int = 0, privacy: bool = True,
                 iri_segment_length: float | None = None) -> RunResult:
    """One Monte Carlo run: road, measurements, and every estimator on the same records.

    Parameters
    ----------
    pipe : FleetPipeline
    rng : numpy.random.Generator | int | numpy.random.SeedSequence
    keep_traces : int
        Keep the time series of the first ``keep_traces`` vehicles (for Figs. 5-7).
    privacy : bool
        Also run the obfuscated chain (Algorithm 2).
    iri_segment_length : float, optional
        Also compare the IRI per segment of this length (m) of the true profile and of the last
        vehicle's estimates (:func:`~roadcollab.experiments.reproduction.iri.run_iri`).

    Returns
    -------
    RunResult
    """
    cfg, grid = pipe.config, pipe.grid
    ss = as_seed_sequence(rng)
    road_ss, noise_ss, priv_ss = (run_stream(ss, name) for name in ("road", "noise", "privacy"))
    road, ys, Ys = record_run(pipe, road_ss, noise_ss, cfg.sensor_noise_std)
    w = road.velocity
    n, sl = grid.n_samples, cfg.scored
    truth = grid.band_limited(grid.rfft(w), n)[sl]

    def mses(Xs: list) -> list:  # spectra of estimates, band-limited like the truth
        x = grid.band_limited_many(Xs, n)[sl]
        return [float(np.mean((x[:, 2 * i:2 * i + 2] - truth) ** 2)) for i in range(len(Xs))]

    ests = pipe.estimators
    plain = Relay(ests, "none", unguarded=True).run(ys, spectra=Ys)
    hard = Relay(ests, "hardened", unguarded=True).run(ys, spectra=Ys)
    fused = Relay(ests, "fused").run(ys, spectra=Ys)
    fused_post = Relay(ests, "fused_posterior").run(ys, spectra=Ys)
    priv = Relay(ests, Exchange("paper", cfg.obfuscation), rng=np.random.default_rng(priv_ss), unguarded=True).run(
        ys, spectra=Ys) if privacy else plain
    V = cfg.n_vehicles
    out = {k: np.zeros(V) for k in ESTIMATORS}
    windowed = out[WINDOWED_CONTROL] = np.zeros(V)
    rel, rel_h, t1e, t1w, t1e_b, t1w_b = (np.zeros(V) for _ in range(6))
    central, oracle = pipe.centralized.estimate_prefixes(Ys), pipe.oracle_per_bin.estimate_prefixes(Ys)
    for j in range(len(ests)):
        r = plain[j].result
        spectra = _estimate_spectra(pipe, j, Ys, plain[j], priv[j], fused[j], fused_post[j], central, oracle)
        scores = mses([*spectra.values(), grid.rfft(grid.irfft(oracle[j], n))])   # the last: zero in the padding,
        for name, score in zip(spectra, scores):                                  # like the truth
            out[name][j] = score
        windowed[j] = scores[-1]
        scale = max(float(np.max(np.abs(r.estimate))), 1e-300)
        rel[j] = float(np.max(np.abs(priv[j].result.estimate - r.estimate))) / scale
        rel_h[j] = float(np.max(np.abs(hard[j].result.estimate - r.estimate))) / scale
        if privacy:
            t1e[j], t1w[j], t1e_b[j], t1w_b[j] = _theorem1(priv[j], grid)
    iri = None
    if iri_segment_length is not None:  # the last vehicle: the fleet estimates use every record
        iri = run_iri(road.positions[sl.start:sl.stop + 1], w[sl], truth,
                      {name: grid.band_limited(X, n)[sl] for name, X in spectra.items()},
                      sample_rate=cfg.sample_rate, vehicle=V, segment_length=iri_segment_length)
    traces = None
    if keep_traces:
        traces = RunTraces(time=road.time[sl], truth=truth, truth_raw=w[sl],
                           plain=[grid.band_limited(s.result.W_hat, n)[sl] for s in plain[:keep_traces]],
                           private=[grid.band_limited(s.result.W_hat, n)[sl] for s in priv[:keep_traces]])
    return RunResult(mse=out, max_rel_diff=rel, max_rel_diff_hardened=rel_h, theorem1_e=t1e, theorem1_wf=t1w,
                     theorem1_e_band=t1e_b, theorem1_wf_band=t1w_b,
                     truth_power=float(np.mean(truth**2)), traces=traces, iri=iri)


@dataclass(frozen=True, eq=False)
class ReproductionResult:
    """All runs of a reproduction and their per-vehicle summary.

    Attributes
    ----------
    config : ExperimentConfig
    seed : int
        Root seed.
    fleet : list of Vehicle
        The fleet of every run (unless ``config.redraw_fleet``).
    runs : list of RunResult
        In run order.
    """

    config: ExperimentConfig
    seed: int
    fleet: list[Vehicle]
    runs: list[RunResult]

    def mse(self, estimator: str) -> np.ndarray:
        """MSE of one estimator in every run and vehicle.

        Parameters
        ----------
        estimator : str
            One of :data:`ESTIMATORS`.

        Returns
        -------
        (n_runs, n_vehicles) ndarray
            (m/s)^2.
        """
        return np.vstack([r.mse[estimator] for r in self.runs])

    def _stack(self, name: str) -> np.ndarray:
        return np.vstack([getattr(r, name) for r in self.runs])

    def table(self) -> list[MseRow]:
        """Rows of ``mse.csv``, one per vehicle (:class:`MseRow`).

        Returns
        -------
        list of MseRow
        """
        pw = np.array([r.truth_power for r in self.runs])[:, None]
        R = len(self.runs)
        std = (lambda x: x.std(ddof=1)) if R > 1 else (lambda x: 0.0)
        mse = {name: self.mse(name) for name in ESTIMATORS}
        worst = [self._stack(name).max(axis=0) for name in ("max_rel_diff", "theorem1_e", "theorem1_wf",
                                                            "theorem1_e_band", "theorem1_wf_band")]
        others = ("own_inversion", "own_posterior_inversion", "fused", "fused_posterior", "centralized",
                  "oracle_per_bin")
        rows = []
        for j in range(self.config.n_vehicles):
            col = {name: m[:, j] for name, m in mse.items()}
            nmse = {name: (m[:, j:j + 1] / pw).mean() for name, m in mse.items()}
            values: list[float] = [
                col["algorithm1_private"].mean(), std(col["algorithm1_private"]), col["algorithm1"].mean(),
                col["observer_only"].mean(), std(col["observer_only"]), *(col[name].mean() for name in others),
                nmse["algorithm1_private"], nmse["observer_only"], *(nmse[name] for name in others),
                *(w[j] for w in worst)]
            rows.append(MseRow(j + 1, *values))
        return rows

    def to_rows(self) -> list[MseRow]:
        """Rows of ``mse.csv``, one per vehicle (:meth:`table`).

        Returns
        -------
        list of MseRow
        """
        return self.table()

    def fusion_rows(self) -> list[FusionRow]:
        """Rows of the fusion figure's CSV: MSE mean, std and 95 % CI per estimator and vehicle.

        Returns
        -------
        list of FusionRow
            Estimator-major (order of :data:`ESTIMATORS`), then vehicle.
        """
        R = len(self.runs)
        rows = []
        for name in ESTIMATORS:
            m = self.mse(name)
            for j in range(self.config.n_vehicles):
                std = float(m[:, j].std(ddof=1)) if R > 1 else 0.0
                rows.append(FusionRow(name, j + 1, float(m[:, j].mean()), std, 1.96 * std / np.sqrt(R), R))
        return rows

    def iri_rows(self) -> list[IriRow]:
        """Rows of ``iri_measured.csv`` (empty unless run with ``iri_segment_length``).

        Returns
        -------
        list of IriRow
        """
        return iri_rows([r.iri for r in self.runs])

    def fleet_rows(self) -> list[FleetRow]:
        """Rows of ``fleet.csv``: true and estimated parameters of every vehicle.

        Returns
        -------
        list of FleetRow
        """
        return [FleetRow.of(v) for v in self.fleet]

    def bound_check(self) -> list[BoundRow]:
        """Is the per-bin oracle beaten? Paired per-run differences against ``oracle_per_bin``.

        ``oracle_per_bin`` is the best linear estimator per bin of the padded grid
        (:mod:`~roadcollab.collaboration.fusion`); every estimator of :data:`ESTIMATORS` is per-bin, so
        none should beat it. The last rows are the control :data:`WINDOWED_CONTROL`, which is not per-bin and
        is expected to beat it by a little (negative ``z``): the check has the power to see such a gap.

        Returns
        -------
        list of BoundRow
            Per estimator (then the control) and vehicle: ``mean_excess`` (mean of ``mse - oracle``, (m/s)^2),
            its standard error, and ``z = mean_excess / stderr``. An estimator beats the per-bin oracle
            (beyond Monte Carlo error) where ``z < -3``.
        """
        oracle = self.mse("oracle_per_bin")
        R = len(self.runs)
        rows = []
        for name in (*ESTIMATORS[:-1], WINDOWED_CONTROL):
            d = self.mse(name) - oracle
            for j in range(self.config.n_vehicles):
                se = d[:, j].std(ddof=1) / np.sqrt(R) if R > 1 else 0.0
                mean = float(d[:, j].mean())
                rows.append(BoundRow(name, j + 1, mean, float(se),
                                     mean / se if se > 0 else float("inf") if mean >= 0 else float("-inf")))
        return rows


@dataclass(frozen=True)
class _ReproductionTask:
    """Picklable task: runs ``indices`` of a reproduction (its setup from the study's cache)."""

    config: ExperimentConfig
    seed: int
    privacy: bool
    iri_segment_length: float | None = None

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[RunResult]:
        plan = SeedPlan(self.seed)
        out = []
        for i in indices:
            if self.config.redraw_fleet:
                fleet_ss, sim_ss = plan.run_fleet(i), plan.run_simulation(i)
                pipe = cache.fleet_pipeline(self.config, sample_fleet(self.config.n_vehicles, self.config.fleet,
                                                                      rng=np.random.default_rng(fleet_ss)))
            else:
                pipe, sim_ss = cache.pipeline(self.config, self.seed), plan.run(i)
            out.append(simulate_run(pipe, sim_ss, keep_traces=3 if i == 0 else 0, privacy=self.privacy,
                                    iri_segment_length=self.iri_segment_length))
        return out


def run_reproduction(config: ExperimentConfig, seed: int, *, progress: Callable[[int], None] | None = None,
                     privacy: bool = True, workers: int | None = None, scheduler: str | None = None,
                     iri_segment_length: float | None = None, cache: PipelineCache | None = None
                     ) -> ReproductionResult:
    """Run the Monte Carlo reproduction, serially or on Dask.

    Parameters
    ----------
    config : ExperimentConfig
    seed : int
        Root seed; the fleet and each run get independent SeedSequence children, so the result
        does not depend on ``workers`` or ``scheduler``.
    progress : callable, optional
        Called with the number of finished runs.
    privacy : bool
        Run the obfuscated chain too.
    workers : int, optional
        Local process pool with this many worker processes (identical results).
    scheduler : str, optional
        Address of an existing Dask scheduler.
    iri_segment_length : float, optional
        Compare true and estimated IRI per segment of this length, m (:meth:`ReproductionResult.iri_rows`).
    cache : PipelineCache, optional
        Per-fleet setup to use and keep (e.g. shared by the reproduction and its measured-profile runs,
        whose fleet and estimators are the same); a new one by default.

    Returns
    -------
    ReproductionResult

    Examples
    --------
    >>> import roadcollab as rc
    >>> res = rc.run_reproduction(rc.ExperimentConfig(n_vehicles=2, n_runs=1), seed=0)
    >>> rows = res.table()                       # the rows of mse.csv (MseRow), one per vehicle
    >>> [r.vehicle for r in rows]
    [1, 2]
    >>> all(r.max_rel_diff_privacy < 1e-9 for r in rows)   # Theorem 1, measured
    True
    """
    return run_reproductions([config], seed, progress=[progress], privacy=privacy, workers=workers, scheduler=scheduler,
                             iri_segment_lengths=[iri_segment_length], cache=cache)[0][0]


def run_reproductions(configs: Sequence[ExperimentConfig], seed: int, *,
                      progress: Sequence[Callable[[int], None] | None] | None = None, privacy: bool = True,
                      workers: int | None = None, scheduler: str | None = None,
                      iri_segment_lengths: Sequence[float | None] | None = None, cache: PipelineCache | None = None
                      ) -> list[tuple[ReproductionResult, float]]:
    """Several reproductions of one seed on one pool (e.g. ``roadcollab reproduce`` and its measured-profile runs).

    Each result equals :func:`run_reproduction` of its configuration alone; on a local pool the pool and
    its workers' warm-up are paid once (:func:`~roadcollab.experiments.runner.map_jobs`).

    Parameters
    ----------
    configs : sequence of ExperimentConfig
    seed : int
        Root seed of every reproduction.
    progress : sequence of callable or None, optional
        Per configuration, called with its number of finished runs.
    privacy, workers, scheduler
        As for :func:`run_reproduction`.
    iri_segment_lengths : sequence of float or None, optional
        Per configuration, as ``iri_segment_length`` of :func:`run_reproduction`.
    cache : PipelineCache, optional
        Per-fleet setup shared by the reproductions; a new one by default.

    Returns
    -------
    list of (ReproductionResult, float)
        Per configuration, its result and the wall time from the start (the setup of every configuration
        included) until its last run finished, s.
    """
    configs = list(configs)
    n = len(configs)
    progress = [None] * n if progress is None else list(progress)
    iri_segment_lengths = [None] * n if iri_segment_lengths is None else list(iri_segment_lengths)
    if not n or len(progress) != n or len(iri_segment_lengths) != n:
        raise ParameterError(f"configs ({n}), progress and iri_segment_lengths must have one entry per reproduction")
    for config in configs:
        if not isinstance(config, ExperimentConfig):
            raise ParameterError(f"config must be an ExperimentConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    if cache is not None and not isinstance(cache, PipelineCache):
        raise ParameterError(f"cache must be a PipelineCache, got {type(cache).__name__}")
    fleets = [fleet_and_run_seeds(config, seed)[0] for config in configs]
    iri_segment_lengths = [None if x is None else check_positive("iri_segment_length", x) for x in iri_segment_lengths]
    cache, t0 = (PipelineCache() if cache is None else cache), time.perf_counter()
    if scheduler is None:   # built here once, inherited by a forked pool
        # Single-threaded like the runs: the setup's small dense kernels (6x6 expm, 2x2 stacks) are
        # slower on two BLAS threads (a 6x6 expm 7.9 ms against 0.23-0.52 ms on one, measured).
        with threadpool_limits(limits=1):
            for config in configs:
                if not config.redraw_fleet:
                    cache.pipeline(config, seed).warm()
    jobs = [Job(_ReproductionTask(config, seed, privacy, iri), config.n_runs, cb)
            for config, iri, cb in zip(configs, iri_segment_lengths, progress)]
    setup = time.perf_counter() - t0
    done = map_jobs(jobs, workers=workers, scheduler=scheduler, shared=cache)
    return [(ReproductionResult(config=config, seed=seed, fleet=fleet, runs=runs), setup + elapsed)
            for config, fleet, (runs, elapsed) in zip(configs, fleets, done)]
