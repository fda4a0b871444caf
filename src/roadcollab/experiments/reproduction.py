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
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._validation import check_int, check_nonnegative, check_positive, check_real
from ..collaboration.algorithm1 import CollaborativeEstimator
from ..errors import ParameterError
from ..estimation.estimator import JDPNoise
from ..collaboration.fusion import LinearMMSE, plant_moments, road_second_moment
from ..privacy.obfuscation import ObfuscationSpec, theorem1_errors
from ..collaboration.relay import Exchange, Relay, simulate_measurements
from ..io.profiles import measured_road
from ..models.profile import TimeRoad
from ..models.road import RoadSpec, generate_road, jump_statistics, wiener_intensity
from ..estimation.grid import SegmentGrid
from ..models.vehicle import FleetSpec, Vehicle, sample_fleet

__all__ = ["ExperimentConfig", "FleetPipeline", "RunResult", "ReproductionResult", "run_reproduction", "RunEstimates",
           "run_estimates",
           "simulate_run"]


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything a reproduction depends on besides the seed (all SI units).

    Parameters
    ----------
    n_vehicles : int
        Fleet size (vehicles traverse the segment in index order).
    n_runs : int
        Monte Carlo runs.
    speed : float
        Vehicle speed, m/s.
    sample_rate : float
        Accelerometer sample rate, Hz.
    segment_length : float
        Scored segment length, m.
    margin : float
        Recorded lead-in and lead-out on each side of the segment, m. The vehicle starts at
        rest at the start of the lead-in; the margins keep start-up and window-edge effects
        of the offline filters out of the score.
    iso_class : str
        ISO 8608 roughness class of the synthetic road.
    anomaly_density : float
        Potholes and bumps per metre.
    sensor_noise_std : float
        Accelerometer noise standard deviation per sample, m/s^2.
    fleet : FleetSpec
        How true and estimated vehicle parameters are drawn.
    gamma : float
        Observer parameter of eq. 4; corner ``gamma (1 + gamma) / 2`` rad/s.
    band_low_hz : float
        Lower edge of the evaluation band, Hz.
    obfuscation : ObfuscationSpec
        Distribution of the obfuscating systems (Algorithm 2).
    oracle : bool
        Use each vehicle's true plant in ``T_j`` (analysis only).
    road_profile : str | None
        Path of a measured profile (``"packaged"`` for the shipped one); None: synthetic.
    redraw_fleet : bool
        Draw a new fleet for every run (statistics over fleets, e.g. how the fused estimate
        improves with fleet size on average); by default one fleet serves every run.
    """

    n_vehicles: int = 10
    n_runs: int = 100
    speed: float = 15.0
    sample_rate: float = 200.0
    segment_length: float = 300.0
    margin: float = 15.0
    iso_class: str = "C"
    anomaly_density: float = 0.02
    sensor_noise_std: float = 0.05
    fleet: FleetSpec = field(default_factory=FleetSpec)
    gamma: float = 512.0
    band_low_hz: float = 0.5
    obfuscation: ObfuscationSpec = field(default_factory=ObfuscationSpec)
    oracle: bool = False
    road_profile: str | None = None
    redraw_fleet: bool = False

    def __post_init__(self) -> None:
        check_int("n_vehicles", self.n_vehicles, low=1, high=1000)
        check_int("n_runs", self.n_runs, low=1)
        check_positive("speed", self.speed)
        check_positive("sample_rate", self.sample_rate)
        check_positive("segment_length", self.segment_length)
        check_nonnegative("margin", self.margin)
        check_nonnegative("sensor_noise_std", self.sensor_noise_std)
        check_positive("gamma", self.gamma)
        check_real("band_low_hz", self.band_low_hz, low=0.0, low_open=True, high=self.sample_rate / 2)
        for name, typ in (("fleet", FleetSpec), ("obfuscation", ObfuscationSpec)):
            if not isinstance(getattr(self, name), typ):
                raise ParameterError(f"{name} must be a {typ.__name__}, got {type(getattr(self, name)).__name__}")
        self.road_spec()  # validates iso_class and the anomaly settings

    @property
    def window_length(self) -> float:
        """Recorded distance per vehicle, m."""
        return self.segment_length + 2 * self.margin

    @property
    def n_samples(self) -> int:
        """Samples in the recorded window."""
        return int(np.floor(self.window_length / self.speed * self.sample_rate + 1e-9))

    @property
    def scored(self) -> slice:
        """Sample indices of the scored segment inside the window."""
        k0 = int(round(self.margin / self.speed * self.sample_rate))
        k1 = k0 + int(round(self.segment_length / self.speed * self.sample_rate))
        return slice(k0, min(k1, self.n_samples))

    def road_spec(self) -> RoadSpec:
        """Synthetic road of the window length, anomalies kept out of the margins."""
        return RoadSpec(length=self.window_length + 1.0, iso_class=self.iso_class,
                        anomaly_density=self.anomaly_density, anomaly_margin=max(self.margin, 1.0))

    def noise_model(self) -> JDPNoise:
        """Road and sensor statistics the estimators are designed for (Lemma 1).

        The Wiener intensity is the ISO class's road-velocity intensity at ``speed``; the jump
        part comes from the pothole edges; the measurement intensity is ``std^2 * dt``. A
        floor of 1e-4 (m/s^2)^2 per sample keeps the design regular with noise-free sensors.
        """
        spec = self.road_spec()
        jumps = jump_statistics(spec, self.speed)
        r = max(self.sensor_noise_std, 1e-2) ** 2 / self.sample_rate
        return JDPNoise(wiener_cov=wiener_intensity(spec, self.speed), jump_rate=jumps.rate,
                        jump_mean=jumps.mean, jump_cov=jumps.covariance, measurement_cov=r * np.eye(2))

    def grid(self) -> SegmentGrid:
        return SegmentGrid(self.n_samples, self.sample_rate, band_low_hz=self.band_low_hz)

    def to_dict(self) -> dict:
        """JSON-ready configuration (nested dataclasses as dicts)."""
        return dataclasses.asdict(self)


class FleetPipeline:
    """Per-vehicle setup for a configuration: estimators, grids, realisations, and the linear
    MMSE estimators (centralised and oracle) of the fleet.

    Parameters
    ----------
    config : ExperimentConfig
    fleet : list of Vehicle
    """

    def __init__(self, config: ExperimentConfig, fleet: list[Vehicle]) -> None:
        if len(fleet) != config.n_vehicles:
            raise ParameterError(f"fleet must have n_vehicles={config.n_vehicles} vehicles, got {len(fleet)}")
        self.config = config
        self.fleet = fleet
        self.grid = config.grid()
        noise = config.noise_model()
        self.estimators = [CollaborativeEstimator(v, noise, self.grid, gamma=config.gamma, oracle=config.oracle,
                                                  fleet=config.fleet) for v in fleet]

    @functools.cached_property
    def road_moment(self) -> np.ndarray:
        """Per-bin road second moment of the configuration's road model (design draws)."""
        from ..experiments.runner import cached

        def build():
            return road_second_moment(lambda rng: self.road(rng).velocity[:self.grid.n_samples], self.grid)

        return cached(("road_moment", repr(self.config)), build)

    @functools.cached_property
    def centralized(self) -> LinearMMSE:
        """Linear MMSE from every record with the nominal models and the parameter uncertainty."""
        S = self.road_moment
        moments = [plant_moments(e.posterior_responses, S) for e in self.estimators]
        return LinearMMSE(self.grid, S, moments, [self.config.sensor_noise_std] * len(self.fleet))

    @functools.cached_property
    def oracle_bound(self) -> LinearMMSE:
        """Linear MMSE from every record with the true models (the bound)."""
        S = self.road_moment
        moments = [plant_moments(e.true_plant.frequency_response(self.grid.omega_dt[self.grid.active]), S)
                   for e in self.estimators]
        return LinearMMSE(self.grid, S, moments, [self.config.sensor_noise_std] * len(self.fleet))

    def road(self, rng: np.random.Generator) -> TimeRoad:
        """Draw the run's road and sample it for the fleet's speed."""
        cfg = self.config
        if cfg.road_profile is None:
            profile = generate_road(cfg.road_spec(), rng=rng)
        else:
            path = None if cfg.road_profile == "packaged" else cfg.road_profile
            profile = measured_road(path, rng=rng)
            if profile.length < cfg.window_length:
                raise ParameterError(f"road_profile covers {profile.length:.1f} m, the window needs "
                                     f"segment_length + 2 * margin = {cfg.window_length:.1f} m")
        return profile.sample(cfg.speed, cfg.sample_rate, duration=cfg.n_samples / cfg.sample_rate)


#: Estimators scored by the reproduction, in the order of ``mse.csv`` and Fig. 4.
ESTIMATORS = ("observer_only", "own_inversion", "own_posterior_inversion", "algorithm1", "algorithm1_private", "fused", "fused_posterior",
              "centralized", "oracle_bound")


@dataclass(frozen=True, eq=False)
class RunResult:
    """Per-vehicle metrics of one run.

    Attributes
    ----------
    mse : dict of str to (n_vehicles,) ndarray
        MSE of every estimator in :data:`ESTIMATORS`, (m/s)^2. ``fused``, ``centralized`` and
        ``oracle_bound`` at vehicle ``j`` use the records of vehicles ``1..j``.
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
    traces : dict | None
        Time series for Figs. 5-7.
    """

    mse: dict
    max_rel_diff: np.ndarray
    max_rel_diff_hardened: np.ndarray
    theorem1_e: np.ndarray
    theorem1_wf: np.ndarray
    theorem1_e_band: np.ndarray
    theorem1_wf_band: np.ndarray
    truth_power: float
    traces: dict | None = None


def _run_seeds(rng, n: int) -> list[np.random.SeedSequence]:
    ss = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(
        np.random.default_rng(rng).integers(2**63))
    return ss.spawn(n)


def simulate_run(pipe: FleetPipeline, rng, *, keep_traces: int = 0, privacy: bool = True) -> RunResult:
    """One Monte Carlo run: road, measurements, and every estimator on the same records.

    Parameters
    ----------
    pipe : FleetPipeline
    rng : numpy.random.Generator | int | numpy.random.SeedSequence
    keep_traces : int
        Keep the time series of the first ``keep_traces`` vehicles (for Figs. 5-7).
    privacy : bool
        Also run the obfuscated chain (Algorithm 2).

    Returns
    -------
    RunResult
    """
    cfg, grid = pipe.config, pipe.grid
    road_ss, noise_ss, priv_ss = _run_seeds(rng, 3)
    road = pipe.road(np.random.default_rng(road_ss))
    w = road.velocity
    n, sl = grid.n_samples, cfg.scored
    Wgt = grid.weight[:, None]
    truth = grid.irfft(Wgt * grid.rfft(w), n)[sl]

    def mse(X):  # X: spectrum of an estimate; band-limited like the truth
        return float(np.mean((grid.irfft(Wgt * X, n)[sl] - truth) ** 2))

    ests = pipe.estimators
    ys = simulate_measurements(ests, w, cfg.sensor_noise_std, rng=np.random.default_rng(noise_ss))
    Ys = [grid.rfft(y) for y in ys]
    plain = Relay(ests, "none").run(ys, spectra=Ys)
    hard = Relay(ests, "hardened").run(ys, spectra=Ys)
    fused = Relay(ests, "fused").run(ys, spectra=Ys)
    fused_post = Relay(ests, "fused_posterior").run(ys, spectra=Ys)
    priv = Relay(ests, Exchange("paper", cfg.obfuscation), rng=np.random.default_rng(priv_ss)).run(
        ys, spectra=Ys) if privacy else plain
    V = cfg.n_vehicles
    out = {k: np.zeros(V) for k in ESTIMATORS}
    rel, rel_h, t1e, t1w, t1e_b, t1w_b = (np.zeros(V) for _ in range(6))
    for j, est in enumerate(ests):
        r = plain[j].result
        out["observer_only"][j] = mse(r.W_obs)
        out["own_inversion"][j] = mse(est.invert(Ys[j]))
        out["own_posterior_inversion"][j] = mse(est.invert(Ys[j], posterior=True))
        out["algorithm1"][j] = mse(r.W_hat)
        out["algorithm1_private"][j] = mse(priv[j].result.W_hat)
        out["fused"][j] = mse(fused[j].estimate_spectrum)
        out["fused_posterior"][j] = mse(fused_post[j].estimate_spectrum)
        out["centralized"][j] = mse(pipe.centralized.estimate(Ys[:j + 1]))
        out["oracle_bound"][j] = mse(pipe.oracle_bound.estimate(Ys[:j + 1]))
        scale = max(float(np.max(np.abs(r.estimate))), 1e-300)
        rel[j] = float(np.max(np.abs(priv[j].result.estimate - r.estimate))) / scale
        rel_h[j] = float(np.max(np.abs(hard[j].result.estimate - r.estimate))) / scale
        if privacy:
            t1e[j], t1w[j], t1e_b[j], t1w_b[j] = theorem1_errors(priv[j].clear, priv[j].message, *priv[j].psi, grid)
    traces = None
    if keep_traces:
        traces = {"time": road.time[sl], "truth": truth, "truth_raw": w[sl],
                  "plain": [grid.irfft(Wgt * s.result.W_hat, n)[sl] for s in plain[:keep_traces]],
                  "private": [grid.irfft(Wgt * s.result.W_hat, n)[sl] for s in priv[:keep_traces]]}
    return RunResult(mse=out, max_rel_diff=rel, max_rel_diff_hardened=rel_h, theorem1_e=t1e, theorem1_wf=t1w,
                     theorem1_e_band=t1e_b, theorem1_wf_band=t1w_b,
                     truth_power=float(np.mean(truth**2)), traces=traces)


@dataclass(frozen=True, eq=False)
class ReproductionResult:
    """All runs of a reproduction and their per-vehicle summary."""

    config: ExperimentConfig
    seed: int
    fleet: list[Vehicle]
    runs: list[RunResult]

    def mse(self, estimator: str) -> np.ndarray:
        """(n_runs, n_vehicles) MSE of one estimator of :data:`ESTIMATORS`, (m/s)^2."""
        return np.vstack([r.mse[estimator] for r in self.runs])

    def _stack(self, name: str) -> np.ndarray:
        return np.vstack([getattr(r, name) for r in self.runs])

    def table(self) -> list[dict]:
        """Rows of ``mse.csv``: one per vehicle (1-based), MSE in (m/s)^2.

        ``mse_*`` is Algorithm 1 with Algorithm 2 (the paper's estimate), ``mse_no_privacy_mean``
        Algorithm 1 in the clear; every other estimator has ``<name>_mse_mean`` and
        ``<name>_nmse_mean`` (divided by the band-limited truth's mean square).
        """
        pw = np.array([r.truth_power for r in self.runs])[:, None]
        priv = self.mse("algorithm1_private")
        R = len(self.runs)
        std = (lambda x: x.std(ddof=1)) if R > 1 else (lambda x: 0.0)
        rel, t1e, t1w = self._stack("max_rel_diff"), self._stack("theorem1_e"), self._stack("theorem1_wf")
        t1e_b, t1w_b = self._stack("theorem1_e_band"), self._stack("theorem1_wf_band")
        rows = []
        for j in range(self.config.n_vehicles):
            row = {"vehicle": j + 1, "mse_mean": priv[:, j].mean(), "mse_std": std(priv[:, j]),
                   "mse_no_privacy_mean": self.mse("algorithm1")[:, j].mean(),
                   "nmse_mean": (priv[:, j:j + 1] / pw).mean()}
            for name in ("observer_only", "own_inversion", "own_posterior_inversion", "fused", "fused_posterior",
                         "centralized", "oracle_bound"):
                m = self.mse(name)
                row[f"{name}_mse_mean"] = m[:, j].mean()
                row[f"{name}_mse_std"] = std(m[:, j])
                row[f"{name}_nmse_mean"] = (m[:, j:j + 1] / pw).mean()
            row["max_rel_diff_privacy"] = rel[:, j].max()
            row["theorem1_e_max"] = t1e[:, j].max()
            row["theorem1_wf_max"] = t1w[:, j].max()
            row["theorem1_e_band_max"] = t1e_b[:, j].max()
            row["theorem1_wf_band_max"] = t1w_b[:, j].max()
            rows.append(row)
        return rows

    def bound_check(self) -> list[dict]:
        """Is the oracle bound beaten? Paired per-run differences against ``oracle_bound``.

        Returns
        -------
        list of dict
            Per estimator and vehicle: ``mean_excess`` (mean of ``mse - oracle``, (m/s)^2),
            its standard error, and ``z = mean_excess / stderr``. An estimator beats the bound
            (beyond Monte Carlo error) where ``z < -3``.
        """
        oracle = self.mse("oracle_bound")
        R = len(self.runs)
        rows = []
        for name in ESTIMATORS[:-1]:
            d = self.mse(name) - oracle
            for j in range(self.config.n_vehicles):
                se = d[:, j].std(ddof=1) / np.sqrt(R) if R > 1 else 0.0
                mean = float(d[:, j].mean())
                rows.append({"estimator": name, "vehicle": j + 1, "mean_excess": mean, "stderr": float(se),
                             "z": mean / se if se > 0 else float("inf") if mean >= 0 else float("-inf")})
        return rows


def _fleet(config: ExperimentConfig, seed: int) -> tuple[list[Vehicle], list[np.random.SeedSequence]]:
    """The fleet (from the root seed's first child) and one SeedSequence per run."""
    fleet_ss, runs_ss = np.random.SeedSequence(seed).spawn(2)
    fleet = sample_fleet(config.n_vehicles, config.fleet, rng=np.random.default_rng(fleet_ss))
    return fleet, runs_ss.spawn(config.n_runs)


def pipeline_for(config: ExperimentConfig, seed: int) -> FleetPipeline:
    """The (per-process cached) pipeline of a configuration and root seed."""
    from ..experiments.runner import cached

    return cached(("pipeline", repr(config), seed), lambda: FleetPipeline(config, _fleet(config, seed)[0]))


@dataclass(frozen=True)
class _ReproductionTask:
    """Picklable task: runs ``indices`` of a reproduction (rebuilds its setup once per process)."""

    config: ExperimentConfig
    seed: int
    privacy: bool

    def __call__(self, indices) -> list[RunResult]:
        run_ss = _fleet(self.config, self.seed)[1]
        out = []
        for i in indices:
            if self.config.redraw_fleet:
                fleet_ss, sim_ss = run_ss[i].spawn(2)
                pipe = FleetPipeline(self.config, sample_fleet(self.config.n_vehicles, self.config.fleet,
                                                               rng=np.random.default_rng(fleet_ss)))
            else:
                pipe, sim_ss = pipeline_for(self.config, self.seed), run_ss[i]
            out.append(simulate_run(pipe, sim_ss, keep_traces=3 if i == 0 else 0, privacy=self.privacy))
        return out


def run_reproduction(config: ExperimentConfig, seed: int, *, progress: Callable[[int], None] | None = None,
                     privacy: bool = True, workers: int | None = None, scheduler: str | None = None
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
        Local Dask cluster with this many worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    ReproductionResult
    """
    from ..experiments.runner import map_runs

    if not isinstance(config, ExperimentConfig):
        raise ParameterError(f"config must be an ExperimentConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    fleet = _fleet(config, seed)[0]
    runs = map_runs(_ReproductionTask(config, seed, privacy), config.n_runs, workers=workers, scheduler=scheduler,
                    progress=progress)
    return ReproductionResult(config=config, seed=seed, fleet=fleet, runs=runs)


@dataclass(frozen=True, eq=False)
class RunEstimates:
    """Band-limited road-velocity estimates of every vehicle on one run (for applications).

    Attributes
    ----------
    road : TimeRoad
        The road of the run (ground-truth anomalies in ``road.anomalies``).
    truth : (N, 2) ndarray
        Band-limited true road velocity over the recorded window, m/s.
    observer_only, collaborative, fused : (V, N, 2) ndarray
        Band-limited estimates per vehicle, m/s: own observer, Algorithm 1, running fleet
        average of the inversions ``z``.
    scored : slice
        Samples of the scored segment inside the window.
    positions : (N,) ndarray
        Road distance of each sample, m.
    """

    road: TimeRoad
    truth: np.ndarray
    observer_only: np.ndarray
    collaborative: np.ndarray
    fused: np.ndarray
    scored: slice
    positions: np.ndarray


def run_estimates(pipe: FleetPipeline, rng, *, sensor_noise_std: float | None = None) -> RunEstimates:
    """Estimates of every vehicle on one run (no privacy chain: it changes no estimate).

    Parameters
    ----------
    pipe : FleetPipeline
    rng : numpy.random.Generator | int | numpy.random.SeedSequence
    sensor_noise_std : float, optional
        Override the configuration's accelerometer noise (m/s^2) for this run, e.g. for a
        noise sweep with estimators designed for the nominal noise.

    Returns
    -------
    RunEstimates
    """
    cfg, grid = pipe.config, pipe.grid
    road_ss, noise_ss = _run_seeds(rng, 2)
    road = pipe.road(np.random.default_rng(road_ss))
    std = cfg.sensor_noise_std if sensor_noise_std is None else check_nonnegative("sensor_noise_std",
                                                                                  sensor_noise_std)
    n = grid.n_samples
    Wgt = grid.weight[:, None]
    w = road.velocity
    ys = simulate_measurements(pipe.estimators, w, std, rng=np.random.default_rng(noise_ss))
    Ys = [grid.rfft(y) for y in ys]
    plain = Relay(pipe.estimators, "none").run(ys, spectra=Ys)
    fused = Relay(pipe.estimators, "fused").run(ys, spectra=Ys)
    band = lambda X: grid.irfft(Wgt * X, n)  # noqa: E731
    return RunEstimates(road=road, truth=band(grid.rfft(w)),
                        observer_only=np.array([band(s.result.W_obs) for s in plain]),
                        collaborative=np.array([band(s.result.W_hat) for s in plain]),
                        fused=np.array([band(s.estimate_spectrum) for s in fused]), scored=cfg.scored,
                        positions=road.positions[:n])
