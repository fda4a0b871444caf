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
weight ``W`` of :class:`~roadcollab.spectral.SegmentGrid` (DC and the lowest frequencies are
invisible to accelerometers). NMSE divides by the band-limited truth's mean square.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ._validation import check_int, check_nonnegative, check_positive, check_real
from .collaborative import CollaborativeEstimator
from .errors import ParameterError
from .estimator import JDPNoise
from .privacy import ObfuscationSpec, obfuscate
from .road import RoadSpec, TimeRoad, generate_road, jump_statistics, measured_road, wiener_intensity
from .simulation import add_sensor_noise, simulate_response
from .spectral import SegmentGrid, inv2x2, matvec
from .vehicle import FleetSpec, Vehicle, sample_fleet

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
    gamma: float = 32.0
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
    """Per-vehicle setup for a configuration: estimators, grids, realisations.

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
        self.estimators = [CollaborativeEstimator(v, noise, self.grid, gamma=config.gamma, oracle=config.oracle)
                           for v in fleet]
        self.z_error_information = [self._z_information(e, noise) for e in self.estimators]

    def _z_information(self, est: CollaborativeEstimator, noise: JDPNoise, n_models: int = 32) -> np.ndarray:
        """Inverse error covariance (per active bin, 2x2) of ``z = P_hat^-1 y`` for the
        centralised estimator.

        ``z - w = (P_hat^-1 P - I) w + P_hat^-1 n``. The model-error term is estimated from
        ``n_models`` plausible true plants drawn around the nominal model with the fleet's
        parameter uncertainty (a fixed, documented seed: this is design, not data).
        """
        from .vehicle import half_car_model

        cfg, grid = self.config, self.grid
        act = grid.active
        # Continuous responses suffice for error statistics (ZOH differs by a half-sample delay
        # common to both factors of P_hat^-1 P) and avoid one matrix exponential per model.
        s = 2j * np.pi * grid.freqs[act]
        Pinv = inv2x2(est.vehicle.nominal_model.frequency_response(s))
        rng = np.random.default_rng(12345)
        names = list(est.vehicle.estimated_params.as_dict())
        G2 = np.zeros((s.size, 2, 2), complex)
        u = cfg.fleet.estimate_uncertainty
        for _ in range(n_models):
            f = 1.0 + u * np.clip(rng.standard_normal(len(names)), -3, 3)
            model = half_car_model(est.vehicle.estimated_params.scaled(dict(zip(names, f))))
            G = Pinv @ model.frequency_response(s) - np.eye(2)
            G2 += G @ G.conj().transpose(0, 2, 1) / n_models
        Pinv = inv2x2(est.P_f[act])
        var_w = float(np.trace(noise.sigma_bar)) / 2 * cfg.sample_rate     # per-sample variance of w
        var_n = max(cfg.sensor_noise_std, 1e-3) ** 2
        C = var_w * G2 + var_n * Pinv @ Pinv.conj().transpose(0, 2, 1)
        return inv2x2(C)

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


@dataclass(frozen=True, eq=False)
class RunResult:
    """Per-vehicle metrics of one run (arrays of shape (n_vehicles,), (m/s)^2)."""

    mse_observer: np.ndarray
    mse_plain: np.ndarray
    mse_private: np.ndarray
    mse_fused: np.ndarray
    mse_centralized: np.ndarray
    max_rel_diff: np.ndarray
    max_rel_diff_hardened: np.ndarray
    truth_power: float
    traces: dict | None = None


def simulate_run(pipe: FleetPipeline, rng, *, keep_traces: int = 0, privacy: bool = True) -> RunResult:
    """One Monte Carlo run: road, measurements, Algorithm 1 with and without Algorithm 2.

    Parameters
    ----------
    pipe : FleetPipeline
    rng : numpy.random.Generator | int | numpy.random.SeedSequence
    keep_traces : int
        Keep the time series of the first ``keep_traces`` vehicles (for Figs. 5-7).
    privacy : bool
        Also run the obfuscated chain (Algorithm 2).
    """
    cfg, grid = pipe.config, pipe.grid
    ss = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(
        np.random.default_rng(rng).integers(2**63))
    road_ss, noise_ss, priv_ss = ss.spawn(3)
    road = pipe.road(np.random.default_rng(road_ss))
    noise_rng = np.random.default_rng(noise_ss)
    priv_rng = np.random.default_rng(priv_ss)
    w = road.velocity
    n, sl, act = grid.n_samples, cfg.scored, grid.active
    Wgt = grid.weight[:, None]
    truth = grid.irfft(Wgt * grid.rfft(w), n)[sl]
    power = float(np.mean(truth**2))

    def mse(X):  # X: spectrum of an estimate; band-limited like the truth
        return float(np.mean((grid.irfft(Wgt * X, n)[sl] - truth) ** 2))

    V = cfg.n_vehicles
    out = {k: np.zeros(V) for k in ("obs", "plain", "priv", "fused", "central", "rel", "rel_h")}
    msg_plain = msg_priv = msg_hard = msg_fused = None
    num = np.zeros((int(act.sum()), 2), complex)
    info = np.zeros((int(act.sum()), 2, 2), complex)
    traces = {"time": road.time[sl], "truth": truth, "truth_raw": w[sl], "plain": [], "private": []} \
        if keep_traces else None
    for j, est in enumerate(pipe.estimators):
        y = add_sensor_noise(simulate_response(est.true_plant, w), cfg.sensor_noise_std, rng=noise_rng)
        r = est.estimate(y, msg_plain)
        msg_plain = est.message(r)
        out["obs"][j] = mse(r.W_obs)
        out["plain"][j] = mse(r.W_hat)
        scale = max(float(np.max(np.abs(r.estimate))), 1e-300)
        if privacy:
            rp = est.estimate(y, msg_priv)
            msg_priv, _, _ = obfuscate(est.message(rp), grid, cfg.obfuscation, rng=priv_rng,
                                       T_response=est.T_ss_f, S_response=est.S_ss_f)
            out["priv"][j] = mse(rp.W_hat)
            out["rel"][j] = float(np.max(np.abs(rp.estimate - r.estimate))) / scale
        else:
            rp = r
            out["priv"][j] = out["plain"][j]
        # Hardened exchange: only z = W P_hat^-1 y crosses the network; same estimates.
        rh = est.estimate(y, msg_hard)
        msg_hard = est.hardened_message(rh)
        out["rel_h"][j] = float(np.max(np.abs(rh.estimate - r.estimate))) / scale
        # Fused: the running average of the band-limited inversions z_i of vehicles 1..j.
        # Only z crosses the network (no dynamics); independent parameter errors and noise
        # average out.
        msg_fused = est.fused_message(r, msg_fused)
        Y = r.Y
        out["fused"][j] = mse(grid.rfft(msg_fused.z))
        # Centralised: one party with every raw measurement, nominal model and the parameter
        # uncertainty combines the inversions per bin with their error covariances (BLUE).
        Ci = pipe.z_error_information[j]
        info += Ci
        num += matvec(Ci, est.invert(Y)[act])
        Wc = np.zeros_like(Y)
        Wc[act] = matvec(inv2x2(info), num)
        out["central"][j] = mse(Wc)
        if j < keep_traces:
            traces["plain"].append(grid.irfft(Wgt * r.W_hat, n)[sl])
            traces["private"].append(grid.irfft(Wgt * rp.W_hat, n)[sl])
    return RunResult(mse_observer=out["obs"], mse_plain=out["plain"], mse_private=out["priv"],
                     mse_fused=out["fused"], mse_centralized=out["central"], max_rel_diff=out["rel"],
                     max_rel_diff_hardened=out["rel_h"],
                     truth_power=power, traces=traces)


@dataclass(frozen=True, eq=False)
class ReproductionResult:
    """All runs of a reproduction and their per-vehicle summary."""

    config: ExperimentConfig
    seed: int
    fleet: list[Vehicle]
    runs: list[RunResult]

    def _stack(self, name: str) -> np.ndarray:
        return np.vstack([getattr(r, name) for r in self.runs])

    def table(self) -> list[dict]:
        """Rows of ``mse.csv``: one per vehicle (1-based), MSE in (m/s)^2."""
        pw = np.array([r.truth_power for r in self.runs])[:, None]
        priv, plain = self._stack("mse_private"), self._stack("mse_plain")
        obs, fused, cen = self._stack("mse_observer"), self._stack("mse_fused"), self._stack("mse_centralized")
        rel = self._stack("max_rel_diff")
        rows = []
        for j in range(self.config.n_vehicles):
            rows.append({
                "vehicle": j + 1,
                "mse_mean": priv[:, j].mean(), "mse_std": priv[:, j].std(ddof=1) if len(self.runs) > 1 else 0.0,
                "mse_no_privacy_mean": plain[:, j].mean(),
                "observer_only_mse_mean": obs[:, j].mean(),
                "observer_only_mse_std": obs[:, j].std(ddof=1) if len(self.runs) > 1 else 0.0,
                "fused_mse_mean": fused[:, j].mean(),
                "centralized_mse_mean": cen[:, j].mean(),
                "nmse_mean": (priv[:, j:j + 1] / pw).mean(),
                "observer_only_nmse_mean": (obs[:, j:j + 1] / pw).mean(),
                "fused_nmse_mean": (fused[:, j:j + 1] / pw).mean(),
                "centralized_nmse_mean": (cen[:, j:j + 1] / pw).mean(),
                "max_rel_diff_privacy": rel[:, j].max(),
            })
        return rows


def _fleet(config: ExperimentConfig, seed: int) -> tuple[list[Vehicle], list[np.random.SeedSequence]]:
    """The fleet (from the root seed's first child) and one SeedSequence per run."""
    fleet_ss, runs_ss = np.random.SeedSequence(seed).spawn(2)
    fleet = sample_fleet(config.n_vehicles, config.fleet, rng=np.random.default_rng(fleet_ss))
    return fleet, runs_ss.spawn(config.n_runs)


def pipeline_for(config: ExperimentConfig, seed: int) -> FleetPipeline:
    """The (per-process cached) pipeline of a configuration and root seed."""
    from .parallel import cached

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
    from .parallel import map_runs

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
    """
    cfg, grid = pipe.config, pipe.grid
    ss = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(
        np.random.default_rng(rng).integers(2**63))
    road_ss, noise_ss = ss.spawn(2)
    road = pipe.road(np.random.default_rng(road_ss))
    noise_rng = np.random.default_rng(noise_ss)
    std = cfg.sensor_noise_std if sensor_noise_std is None else check_nonnegative("sensor_noise_std",
                                                                                  sensor_noise_std)
    n = grid.n_samples
    Wgt = grid.weight[:, None]
    band = lambda X: grid.irfft(Wgt * X, n)  # noqa: E731
    w = road.velocity
    out = {k: [] for k in ("obs", "col", "fus")}
    msg = fused = None
    for est in pipe.estimators:
        y = add_sensor_noise(simulate_response(est.true_plant, w), std, rng=noise_rng)
        r = est.estimate(y, msg)
        msg = est.message(r)
        fused = est.fused_message(r, fused)
        out["obs"].append(band(r.W_obs))
        out["col"].append(band(r.W_hat))
        out["fus"].append(band(grid.rfft(fused.z)))
    return RunEstimates(road=road, truth=band(grid.rfft(w)), observer_only=np.array(out["obs"]),
                        collaborative=np.array(out["col"]), fused=np.array(out["fus"]), scored=cfg.scored,
                        positions=road.positions[:n])
