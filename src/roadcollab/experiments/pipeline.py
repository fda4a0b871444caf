"""Per-fleet setup of a configuration and the seeds of a reproduction.

A :class:`FleetPipeline` holds what every run of one fleet shares: the vehicles' estimators,
the frequency grid and the fleet's linear MMSE estimators. A :class:`PipelineCache`, owned by a
study and handed to its runs by :func:`~roadcollab.experiments.runner.map_runs` (``shared=``), builds
it once per worker process for a configuration and root seed, and shares the road moment between the
fleets of one configuration. Seeds: :class:`~roadcollab.experiments.seeds.SeedPlan` (the fleet
stream and one seed per run).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ..collaboration.algorithm1 import CollaborativeEstimator
from ..collaboration.fusion import LinearMMSE, plant_moments, road_second_moment
from ..collaboration.relay import simulate_measurements
from ..errors import ParameterError
from ..models.profile import TimeRoad
from ..models.road import RoadSpec, generate_road, with_anomalies
from ..io.profiles import MeasuredProfile, load_profile, measured_road, packaged_profile_path
from ..models.vehicle import Vehicle, sample_fleet
from .config import ExperimentConfig
from .seeds import SeedPlan

__all__ = ["FleetPipeline", "PipelineCache", "design_key", "fleet_and_run_seeds", "record_run"]

#: Pipelines a :class:`PipelineCache` keeps (the oldest is dropped beyond this).
_MAX_PIPELINES = 8


class FleetPipeline:
    """Per-vehicle setup for a configuration: estimators, grids, realisations, and the linear
    MMSE estimators (centralised and oracle) of the fleet.

    Parameters
    ----------
    config : ExperimentConfig
    fleet : list of Vehicle
        ``config.n_vehicles`` vehicles in driving order.
    road_moment : (n_bins, 2) ndarray, optional
        The configuration's per-bin road second moment if already computed (another fleet of the
        same configuration, :class:`PipelineCache`); computed on first use otherwise.
    estimators : list of CollaborativeEstimator, optional
        The fleet's estimators if already built for a configuration with the same design
        (:func:`design_key`, e.g. the same fleet on a measured instead of a synthetic road); built
        otherwise.

    Attributes
    ----------
    grid : SegmentGrid
        The configuration's frequency grid.
    estimators : list of CollaborativeEstimator
        One per vehicle, designed for ``config.noise_model()``.
    """

    def __init__(self, config: ExperimentConfig, fleet: list[Vehicle], *, road_moment: np.ndarray | None = None,
                 estimators: list[CollaborativeEstimator] | None = None) -> None:
        if len(fleet) != config.n_vehicles:
            raise ParameterError(f"fleet must have n_vehicles={config.n_vehicles} vehicles, got {len(fleet)}")
        self.config = config
        self.fleet = fleet
        if estimators is None:
            self.grid = config.grid()
            noise = config.noise_model()
            self.estimators = [CollaborativeEstimator(v, noise, self.grid, gamma=config.gamma, oracle=config.oracle,
                                                      fleet=config.fleet) for v in fleet]
        else:
            if len(estimators) != len(fleet) or any(e.vehicle is not v for e, v in zip(estimators, fleet)):
                raise ParameterError("estimators must hold one CollaborativeEstimator per vehicle of fleet, in order")
            self.grid = estimators[0].grid
            self.estimators = list(estimators)
        if road_moment is not None:
            self.__dict__["road_moment"] = road_moment   # the cached_property's slot

    @functools.cached_property
    def road_moment(self) -> np.ndarray:
        """Per-bin road second moment of the configuration's road model (design draws); it depends
        on the configuration only, so fleets of one configuration can share it (``road_moment=``)."""
        return road_second_moment(lambda rng: self.road(rng).velocity[:self.grid.n_samples], self.grid)

    @functools.cached_property
    def centralized(self) -> LinearMMSE:
        """Linear MMSE from every record with the nominal models and the parameter uncertainty."""
        S = self.road_moment
        moments = [plant_moments(e.posterior_responses, S) for e in self.estimators]
        return LinearMMSE(self.grid, S, moments, [self.config.sensor_noise_std] * len(self.fleet))

    @functools.cached_property
    def oracle_per_bin(self) -> LinearMMSE:
        """Per-bin linear MMSE from every record with the true models (the reference of ``bound_check``;
        per bin of the padded grid, not a bound on the windowed error: see :mod:`~roadcollab.collaboration.fusion`)."""
        S = self.road_moment
        moments = [plant_moments(e.true_plant.frequency_response(self.grid.omega_dt[self.grid.active]), S)
                   for e in self.estimators]
        return LinearMMSE(self.grid, S, moments, [self.config.sensor_noise_std] * len(self.fleet))

    @functools.cached_property
    def profile_file(self) -> MeasuredProfile | None:
        """The measured profile file of ``config.road_profile``, read once (None for a synthetic road)."""
        cfg = self.config
        if cfg.road_profile is None:
            return None
        path = packaged_profile_path() if cfg.road_profile == "packaged" else cfg.road_profile
        return load_profile(path, limits=cfg.profile_limits)

    def warm(self) -> FleetPipeline:
        """Build everything the runs share now (road moment, centralized and oracle estimators).

        A study calls it before its runs so that a forked worker pool inherits it instead of
        building it once per worker; serially it only moves the same work earlier.

        Returns
        -------
        FleetPipeline
            ``self``.
        """
        _ = self.centralized, self.oracle_per_bin
        return self

    def road(self, rng: np.random.Generator, spec: RoadSpec | None = None) -> TimeRoad:
        """Draw the run's road and sample it for the fleet's speed.

        Parameters
        ----------
        rng : numpy.random.Generator
        spec : RoadSpec, optional
            A road condition other than the configuration's (e.g. every anomaly of one depth);
            the estimators, designed for the configuration's road, are unchanged. With a measured
            profile, the anomalies of ``spec`` are added to the profile.

        Returns
        -------
        TimeRoad
            Synthetic (``config.road_spec()`` or ``spec``) or measured (``config.road_profile``)
            road, sampled at ``config.speed`` m/s and ``config.sample_rate`` Hz for ``n_samples``.
        """
        cfg = self.config
        if spec is not None:
            if cfg.road_profile is None:
                profile = generate_road(spec, rng=rng)
            else:
                measured = measured_road(self.profile_file, spacing=spec.spacing, rng=rng)
                profile = with_anomalies(measured, spec, rng=rng)
        elif cfg.road_profile is None:
            profile = generate_road(cfg.road_spec(), rng=rng)
        else:
            profile = measured_road(self.profile_file, rng=rng)
            if profile.length < cfg.window_length:
                raise ParameterError(f"road_profile covers {profile.length:.1f} m, the window needs "
                                     f"segment_length + 2 * margin = {cfg.window_length:.1f} m")
        return profile.sample(cfg.speed, cfg.sample_rate, duration=cfg.n_samples / cfg.sample_rate)


def record_run(pipe: FleetPipeline, road_ss: np.random.SeedSequence, noise_ss: np.random.SeedSequence,
               sensor_noise_std: float, road_spec: RoadSpec | None = None
               ) -> tuple[TimeRoad, list[np.ndarray], list[np.ndarray]]:
    """The road of one run and every vehicle's record of it.

    Parameters
    ----------
    pipe : FleetPipeline
    road_ss, noise_ss : numpy.random.SeedSequence
        Seeds of the road and of the sensor noise.
    sensor_noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    road_spec : RoadSpec, optional
        Road condition other than the configuration's (:meth:`FleetPipeline.road`).

    Returns
    -------
    road : TimeRoad
    records : list of (N, 2) ndarray
        Measured accelerations per vehicle, m/s^2.
    spectra : list of (N // 2 + 1, 2) ndarray
        Their spectra (``grid.rfft``).
    """
    road = pipe.road(np.random.default_rng(road_ss), road_spec)
    ys = simulate_measurements(pipe.estimators, road.velocity, sensor_noise_std, rng=np.random.default_rng(noise_ss))
    return road, ys, [pipe.grid.rfft(y) for y in ys]


def design_key(config: ExperimentConfig) -> str:
    """What a fleet's estimators depend on: the configuration without the road actually driven.

    The estimators are designed for the configuration's *synthetic* road statistics
    (:meth:`~roadcollab.experiments.config.ExperimentConfig.noise_model`), whatever road the runs drive, so
    configurations that differ only in ``road_profile``, ``n_runs``, ``redraw_fleet``, the obfuscation or
    the file limits share them.

    Parameters
    ----------
    config : ExperimentConfig

    Returns
    -------
    str
        Equal for configurations whose fleets (from one root seed) have identical estimators.
    """
    return repr(dataclasses.replace(config, n_runs=1, road_profile=None, redraw_fleet=False,
                                    obfuscation=ExperimentConfig().obfuscation,
                                    profile_limits=ExperimentConfig().profile_limits))


def fleet_and_run_seeds(config: ExperimentConfig, seed: int) -> tuple[list[Vehicle], list[np.random.SeedSequence]]:
    """The fleet (from the root seed's first child) and one SeedSequence per run.

    Parameters
    ----------
    config : ExperimentConfig
    seed : int
        Root seed.

    Returns
    -------
    fleet : list of Vehicle
        ``config.n_vehicles`` vehicles.
    run_seeds : list of numpy.random.SeedSequence
        ``config.n_runs`` children of the root seed's second child.
    """
    plan = SeedPlan(seed)
    fleet = sample_fleet(config.n_vehicles, config.fleet, rng=np.random.default_rng(plan.fleet()))
    return fleet, plan.runs(config.n_runs)


class PipelineCache:
    """Fleet pipelines and road moments built on first use and kept, owned by one study.

    A study creates one, passes it to :func:`~roadcollab.experiments.runner.map_runs` as
    ``shared=`` (so each worker process holds one copy for all its chunks, and a serial run one for
    all runs) and its tasks ask it for pipelines. Every builder is deterministic, so results do not
    depend on whether it hits. A copy (pickle) starts empty: what it holds is rebuilt where it is used.

    Examples
    --------
    >>> import roadcollab as rc
    >>> cache = PipelineCache()
    >>> cfg = rc.ExperimentConfig(n_vehicles=2)
    >>> cache.pipeline(cfg, 0) is cache.pipeline(cfg, 0)
    True
    """

    def __init__(self) -> None:
        self._clear()

    def _clear(self) -> None:
        self._pipelines: dict = {}
        self._moments: dict = {}
        self._estimators: dict = {}

    def __getstate__(self) -> dict:
        return {}

    def __setstate__(self, state: dict) -> None:
        self._clear()

    def pipeline(self, config: ExperimentConfig, seed: int) -> FleetPipeline:
        """The pipeline of a configuration and the fleet of a root seed (built once).

        Parameters
        ----------
        config : ExperimentConfig
        seed : int
            Root seed; the fleet is :func:`fleet_and_run_seeds`'s.

        Returns
        -------
        FleetPipeline
            The same object for equal ``(repr(config), seed)``.
        """
        key = (repr(config), seed)
        if key not in self._pipelines:
            if len(self._pipelines) >= _MAX_PIPELINES:
                self._pipelines.pop(next(iter(self._pipelines)))
            shared = self._estimators.get((design_key(config), seed))
            if shared is None:
                pipe = FleetPipeline(config, fleet_and_run_seeds(config, seed)[0])
                if len(self._estimators) >= _MAX_PIPELINES:
                    self._estimators.pop(next(iter(self._estimators)))
                self._estimators[(design_key(config), seed)] = pipe.estimators
            else:   # the same fleet on another road: same estimators
                pipe = FleetPipeline(config, [e.vehicle for e in shared], estimators=shared)
            self._pipelines[key] = pipe
        return self._pipelines[key]

    def fleet_pipeline(self, config: ExperimentConfig, fleet: list[Vehicle]) -> FleetPipeline:
        """A new pipeline for a fleet drawn per run, sharing the configuration's road moment.

        Parameters
        ----------
        config : ExperimentConfig
        fleet : list of Vehicle
            ``config.n_vehicles`` vehicles in driving order.

        Returns
        -------
        FleetPipeline
            With the road moment of ``config`` computed once per cache.
        """
        pipe = FleetPipeline(config, fleet, road_moment=self._moments.get(repr(config)))
        self._moments[repr(config)] = pipe.road_moment
        return pipe
