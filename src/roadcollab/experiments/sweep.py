"""Where does Algorithm 1 beat a single vehicle? A sweep over observer, noise and model quality.

The sweep crosses three settings of :class:`~roadcollab.experiments.reproduction.ExperimentConfig`:

- the observer parameter ``gamma`` of eq. 4 (corner ``gamma (1 + gamma) / 2`` rad/s; 1 is a
  weak observer, about 128 and beyond the strongest),
- the accelerometer noise standard deviation ``sensor_noise_std``, m/s^2,
- the relative parameter uncertainty of each vehicle's model
  (:attr:`~roadcollab.models.vehicle.FleetSpec.estimate_uncertainty`).

Every grid point runs the same ``n_runs`` Monte Carlo runs with the engine of the reproduction
(:class:`~roadcollab.experiments.reproduction.FleetPipeline` and
:func:`~roadcollab.experiments.reproduction.simulate_run`, privacy off: it changes no estimate). Each run draws
a *new* fleet and its own road, so the statistics are over fleets. The randomness of run ``r``
is the same at every grid point (common random numbers): the same road, the same standard-normal
sensor noise (scaled by the noise level) and the same fleet draw (true parameters, and
parameter-estimate errors scaled by the uncertainty). Differences between grid points are then
paired comparisons, free of most of the run-to-run scatter.

Seeds::

    SeedSequence(seed) --spawn(n_runs)--> run r --spawn(2)--> (fleet draw, simulate_run)

Every (grid point, run) pair is an independent task rebuilt from these seeds, so the result
does not depend on the number of workers or on the scheduler.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._validation import check_int, check_matrix, check_nonnegative, check_positive, check_real
from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..experiments.pipeline import FleetPipeline
from ..experiments.reproduction import simulate_run
from ..models.vehicle import sample_fleet

__all__ = ["SWEPT_ESTIMATORS", "SweepConfig", "SweepRow", "SweepFinding", "SweepResult", "run_sweep",
           "ratio_of_means"]

#: Estimators whose per-vehicle MSE the sweep keeps (``algorithm1_private`` equals
#: ``algorithm1`` with privacy off, so it is not kept).
SWEPT_ESTIMATORS = ("observer_only", "own_inversion", "own_posterior_inversion", "algorithm1", "fused",
                    "fused_posterior", "centralized", "oracle_bound")

#: The largest relative parameter uncertainty a fleet accepts (FleetSpec's limit).
_MAX_UNCERTAINTY = 0.3


def _grid(name: str, values, check: Callable[[str, object], float]) -> tuple[float, ...]:
    """Validate a grid: a non-empty sequence of distinct valid numbers, returned sorted ascending."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
        raise ParameterError(f"{name} must be a sequence of numbers, got {values!r}")
    vals = tuple(check(f"{name}[{i}]", v) for i, v in enumerate(values))
    if not vals:
        raise ParameterError(f"{name} must hold at least one value, got none")
    if len(set(vals)) != len(vals):
        raise ParameterError(f"{name} must not repeat a value, got {vals}")
    return tuple(sorted(vals))


@dataclass(frozen=True)
class SweepConfig:
    """The grid of a sweep and everything else it depends on besides the seed (SI units).

    Parameters
    ----------
    gammas : sequence of float
        Observer parameters ``gamma`` of eq. 4, each > 0 (dimensionless; the observer's corner
        is ``gamma (1 + gamma) / 2`` rad/s). Stored sorted ascending.
    sensor_noise_stds : sequence of float
        Accelerometer noise standard deviations per sample, m/s^2, each >= 0. Stored sorted.
    parameter_uncertainties : sequence of float
        Relative standard deviations of each vehicle's parameter estimates
        (``FleetSpec.estimate_uncertainty``), each in [0, 0.3]. Stored sorted.
    n_vehicles : int
        Fleet size ``V``, at least 2 (Algorithm 1 is scored on vehicles ``2..V``).
    n_runs : int
        Monte Carlo runs per grid point ``R`` (each with a new fleet and road).
    experiment : ExperimentConfig
        Everything else (speed, sample rate, segment, road, fleet spread, band). Its
        ``gamma``, ``sensor_noise_std`` and ``fleet.estimate_uncertainty`` are replaced at each
        grid point; ``n_vehicles``, ``n_runs`` and ``redraw_fleet=True`` are set from the sweep.

    Raises
    ------
    ParameterError
        A grid value, ``n_vehicles``, ``n_runs`` or ``experiment`` is invalid; the message names
        it (e.g. ``gammas[0] must be > 0, got -1``).

    Examples
    --------
    >>> cfg = SweepConfig(gammas=(1, 128), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,),
    ...                   n_vehicles=3, n_runs=2)
    >>> cfg.points()
    [(1.0, 0.05, 0.1), (128.0, 0.05, 0.1)]
    """

    gammas: tuple[float, ...] = (1.0, 8.0, 32.0, 128.0, 512.0)
    sensor_noise_stds: tuple[float, ...] = (0.05, 0.2)
    parameter_uncertainties: tuple[float, ...] = (0.05, 0.15)
    n_vehicles: int = 10
    n_runs: int = 8
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)

    def __post_init__(self) -> None:
        def setattr_(name: str, value) -> None:  # normalise the fields of the frozen instance
            object.__setattr__(self, name, value)

        setattr_("gammas", _grid("gammas", self.gammas, check_positive))
        setattr_("sensor_noise_stds", _grid("sensor_noise_stds", self.sensor_noise_stds, check_nonnegative))
        setattr_("parameter_uncertainties", _grid(
            "parameter_uncertainties", self.parameter_uncertainties,
            lambda n, v: check_real(n, v, low=0.0, high=_MAX_UNCERTAINTY)))
        setattr_("n_vehicles", check_int("n_vehicles", self.n_vehicles, low=2, high=1000))
        setattr_("n_runs", check_int("n_runs", self.n_runs, low=1))
        if not isinstance(self.experiment, ExperimentConfig):
            raise ParameterError(f"experiment must be an ExperimentConfig, got {type(self.experiment).__name__}")
        setattr_("experiment", dataclasses.replace(self.experiment, n_vehicles=self.n_vehicles,
                                                   n_runs=self.n_runs, redraw_fleet=True))

    def points(self) -> list[tuple[float, float, float]]:
        """Grid points ``(gamma, sensor_noise_std, parameter_uncertainty)`` in sweep order.

        Ordered by noise, then uncertainty, then gamma (ascending), so the points of one
        (noise, uncertainty) panel are consecutive.

        Returns
        -------
        list of (float, float, float)
            ``(gamma, sensor_noise_std in m/s^2, parameter_uncertainty)``.
        """
        return [(g, s, u) for s in self.sensor_noise_stds for u in self.parameter_uncertainties for g in self.gammas]

    def point_config(self, gamma: float, sensor_noise_std: float, parameter_uncertainty: float) -> ExperimentConfig:
        """The experiment of one grid point.

        Parameters
        ----------
        gamma : float
            Observer parameter of eq. 4 (> 0).
        sensor_noise_std : float
            Accelerometer noise standard deviation, m/s^2.
        parameter_uncertainty : float
            Relative standard deviation of the vehicles' parameter estimates.

        Returns
        -------
        ExperimentConfig
            ``experiment`` with these three settings replaced.
        """
        exp = self.experiment
        return dataclasses.replace(exp, gamma=gamma, sensor_noise_std=sensor_noise_std,
                                   fleet=dataclasses.replace(exp.fleet, estimate_uncertainty=parameter_uncertainty))

    def to_dict(self) -> dict:
        """JSON-ready configuration.

        The experiment's swept fields (``gamma``, ``sensor_noise_std``,
        ``fleet.estimate_uncertainty``) are left out of ``experiment`` and listed under
        ``swept`` with the grid that replaces them.
        """
        d = dataclasses.asdict(self)
        exp = d["experiment"]
        del exp["gamma"], exp["sensor_noise_std"], exp["fleet"]["estimate_uncertainty"]
        d["swept"] = {"experiment.gamma": "gammas", "experiment.sensor_noise_std": "sensor_noise_stds",
                      "experiment.fleet.estimate_uncertainty": "parameter_uncertainties"}
        return d


def ratio_of_means(num, den) -> tuple[float, float]:
    """Ratio of two paired sample means and its delta-method standard error.

    With per-run pairs ``(a_r, b_r)``, ``r = 1..R``:

    .. math::

        \\hat G = \\bar a / \\bar b,\\qquad
        \\mathrm{SE}(\\hat G) = \\frac{1}{\\bar b}
        \\sqrt{\\frac{\\sum_r (a_r - \\hat G b_r)^2}{R (R - 1)}}

    (first-order linearisation of ``a / b`` around the means; the pairing enters through the
    covariance of ``a`` and ``b``, which the residuals ``a_r - G b_r`` carry).

    Parameters
    ----------
    num, den : (R,) array_like
        Paired per-run values (e.g. MSE in (m/s)^2); ``mean(den) != 0``.

    Returns
    -------
    ratio : float
        ``mean(num) / mean(den)``.
    se : float
        Its standard error; NaN for ``R = 1``.

    Raises
    ------
    ParameterError
        ``num`` and ``den`` are not 1-D of the same length, or ``mean(den) == 0``.

    Examples
    --------
    >>> ratio_of_means([2.0, 4.0], [1.0, 2.0])
    (2.0, 0.0)
    """
    a = check_matrix("num", num, (None,))
    b = check_matrix("den", den, (a.size,))
    if a.size == 0:
        raise ParameterError("num must hold at least one value, got none")
    mb = float(b.mean())
    if mb == 0.0:
        raise ParameterError("den must have a non-zero mean, got 0")
    g = float(a.mean()) / mb
    if a.size < 2:
        return g, float("nan")
    return g, float(np.sqrt(np.sum((a - g * b) ** 2) / (a.size * (a.size - 1))) / abs(mb))


def _stderr(x: np.ndarray) -> float:
    """Standard error of the mean of independent values; NaN for a single value."""
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")


@dataclass(frozen=True)
class SweepRow:
    """One grid point of ``sweep.csv``: MSE in (m/s)^2, averaged over the runs.

    Attributes
    ----------
    gamma : float
        Observer parameter of eq. 4.
    sensor_noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    parameter_uncertainty : float
        Relative standard deviation of the vehicles' parameter estimates.
    vehicle1_observer_mse : float
        Vehicle 1's own online observer (the single vehicle, nobody ahead of it).
    algorithm1_mse : float
        Algorithm 1, averaged over vehicles ``2..V``.
    own_inversion_mse : float
        Each vehicle's offline inversion of its own record, averaged over all vehicles.
    fused_mse : float
        Fleet average of the inversions ``z`` at vehicle ``V``.
    oracle_bound_mse : float
        Linear MMSE from all ``V`` records with the true models (the bound).
    observer_only_mse : float
        Own observer, averaged over all vehicles.
    centralized_mse : float
        Linear MMSE from all ``V`` records with the nominal models.
    algorithm1_gain : float
        ``vehicle1_observer_mse / algorithm1_mse`` (> 1: Algorithm 1 is better).
    algorithm1_gain_se : float
        Delta-method standard error of the gain over the paired runs (:func:`ratio_of_means`).
    algorithm1_mse_se : float
        Standard error of ``algorithm1_mse`` over runs (per-run means over vehicles 2..V).
    vehicle1_observer_mse_se : float
        Standard error of ``vehicle1_observer_mse`` over runs.
    own_posterior_inversion_mse : float
        Each vehicle's inversion of its posterior-mean plant, averaged over all vehicles.
    fused_posterior_mse : float
        Fleet average of the posterior inversions at vehicle ``V``.
    n_runs : int
        Runs averaged ``R``.
    n_vehicles : int
        Fleet size ``V``.
    """

    gamma: float
    sensor_noise_std: float
    parameter_uncertainty: float
    vehicle1_observer_mse: float
    algorithm1_mse: float
    own_inversion_mse: float
    fused_mse: float
    oracle_bound_mse: float
    observer_only_mse: float
    centralized_mse: float
    algorithm1_gain: float
    algorithm1_gain_se: float
    algorithm1_mse_se: float
    vehicle1_observer_mse_se: float
    own_posterior_inversion_mse: float
    fused_posterior_mse: float
    n_runs: int
    n_vehicles: int


@dataclass(frozen=True)
class SweepFinding:
    """What the sweep says for one (noise, uncertainty) pair, read off the numbers.

    Attributes
    ----------
    sensor_noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    parameter_uncertainty : float
        Relative standard deviation of the vehicles' parameter estimates.
    threshold : float
        "Within" means ``vehicle1_observer_mse <= threshold * algorithm1_mse``; "Algorithm 1
        wins" means the opposite (the single vehicle is more than ``threshold`` times worse).
    smallest_gamma_within : float or None
        Smallest swept gamma at which vehicle 1's observer is within ``threshold`` of
        Algorithm 1 (None: at no swept gamma).
    within_at_every_larger_gamma : bool
        The observer stays within ``threshold`` at every swept gamma above that one.
    gammas_algorithm1_wins : tuple of float
        Swept gammas at which Algorithm 1 wins.
    largest_gamma : float
        The strongest swept observer.
    algorithm1_over_observer_at_largest : float
        ``algorithm1_mse / vehicle1_observer_mse`` at ``largest_gamma`` (< 1: Algorithm 1 better).
    algorithm1_over_observer_at_largest_se : float
        Its delta-method standard error over the paired runs.
    algorithm1_over_own_inversion_at_largest : float
        Algorithm 1 against each vehicle's own offline inversion (the other single-vehicle
        estimator) on the same vehicles ``2..V`` at ``largest_gamma``: ratio of run means.
    algorithm1_over_own_inversion_at_largest_se : float
        Its delta-method standard error over the paired runs.
    algorithm1_over_own_observer_at_largest : float
        Algorithm 1 against each vehicle's own online observer on the same vehicles ``2..V`` at
        ``largest_gamma`` (a paired comparison, free of the vehicle-to-vehicle scatter that
        ``algorithm1_over_observer_at_largest`` carries).
    algorithm1_over_own_observer_at_largest_se : float
        Its delta-method standard error over the paired runs.
    unresolved_gammas : tuple of float
        Swept gammas at which the gain ``vehicle1_observer_mse / algorithm1_mse`` lies within
        two standard errors of ``threshold``: there the within/wins classification is not
        resolved by the runs.
    """

    sensor_noise_std: float
    parameter_uncertainty: float
    threshold: float
    smallest_gamma_within: float | None
    within_at_every_larger_gamma: bool
    gammas_algorithm1_wins: tuple[float, ...]
    largest_gamma: float
    algorithm1_over_observer_at_largest: float
    algorithm1_over_observer_at_largest_se: float
    algorithm1_over_own_inversion_at_largest: float
    algorithm1_over_own_inversion_at_largest_se: float
    algorithm1_over_own_observer_at_largest: float
    algorithm1_over_own_observer_at_largest_se: float
    unresolved_gammas: tuple[float, ...]

    @property
    def wins_only_for_weak_observers(self) -> bool:
        """Algorithm 1 wins at some swept gamma, but not at the largest one."""
        return bool(self.gammas_algorithm1_wins) and self.largest_gamma not in self.gammas_algorithm1_wins


@dataclass(frozen=True, eq=False)
class SweepResult:
    """Per-run, per-vehicle MSE of every grid point of a sweep.

    Parameters
    ----------
    config : SweepConfig
    seed : int
        Root seed.
    mse : dict of str to (n_points, n_runs, n_vehicles) ndarray
        MSE of every estimator of :data:`SWEPT_ESTIMATORS`, (m/s)^2; points in the order of
        :meth:`SweepConfig.points`. ``fused``, ``centralized`` and ``oracle_bound`` at vehicle
        index ``j`` use the records of vehicles ``1..j+1``.

    Raises
    ------
    ParameterError
        An estimator is missing or an array has the wrong shape.
    """

    config: SweepConfig
    seed: int
    mse: dict

    def __post_init__(self) -> None:
        if not isinstance(self.config, SweepConfig):
            raise ParameterError(f"config must be a SweepConfig, got {type(self.config).__name__}")
        check_int("seed", self.seed, low=0)
        if not isinstance(self.mse, dict) or set(self.mse) != set(SWEPT_ESTIMATORS):
            got = sorted(self.mse) if isinstance(self.mse, dict) else type(self.mse).__name__
            raise ParameterError(f"mse must map exactly {list(SWEPT_ESTIMATORS)} to arrays, got {got}")
        shape = (len(self.config.points()), self.config.n_runs, self.config.n_vehicles)
        object.__setattr__(self, "mse", {k: check_matrix(f"mse[{k!r}]", self.mse[k], shape)
                                         for k in SWEPT_ESTIMATORS})

    def table(self) -> list[SweepRow]:
        """One :class:`SweepRow` per grid point, in the order of :meth:`SweepConfig.points`.

        Per run ``r``: ``a_r`` = vehicle 1's observer MSE, ``b_r`` = Algorithm 1's MSE averaged
        over vehicles ``2..V``; the row holds the run means, their standard errors (runs are
        independent) and the gain ``mean(a) / mean(b)`` with its paired standard error.
        """
        m = self.mse
        V, R = self.config.n_vehicles, self.config.n_runs
        rows = []
        for p, (g, s, u) in enumerate(self.config.points()):
            a = m["observer_only"][p, :, 0]
            b = m["algorithm1"][p, :, 1:].mean(axis=1)
            gain, gain_se = ratio_of_means(a, b)
            rows.append(SweepRow(
                gamma=g, sensor_noise_std=s, parameter_uncertainty=u,
                vehicle1_observer_mse=float(a.mean()), algorithm1_mse=float(b.mean()),
                own_inversion_mse=float(m["own_inversion"][p].mean()),
                fused_mse=float(m["fused"][p, :, V - 1].mean()),
                oracle_bound_mse=float(m["oracle_bound"][p, :, V - 1].mean()),
                observer_only_mse=float(m["observer_only"][p].mean()),
                centralized_mse=float(m["centralized"][p, :, V - 1].mean()),
                algorithm1_gain=gain, algorithm1_gain_se=gain_se, algorithm1_mse_se=_stderr(b),
                vehicle1_observer_mse_se=_stderr(a),
                own_posterior_inversion_mse=float(m["own_posterior_inversion"][p].mean()),
                fused_posterior_mse=float(m["fused_posterior"][p, :, V - 1].mean()), n_runs=R, n_vehicles=V))
        return rows

    def to_rows(self) -> list[dict]:
        """Rows of ``sweep.csv``: :meth:`table` as dicts, keys in column order."""
        return [dataclasses.asdict(r) for r in self.table()]

    def findings(self, *, threshold: float = 1.25) -> list[SweepFinding]:
        """Per (noise, uncertainty) pair: where the single vehicle's observer catches up.

        Parameters
        ----------
        threshold : float
            Ratio (> 1) below which vehicle 1's observer counts as "within" Algorithm 1.

        Returns
        -------
        list of SweepFinding
            One per (noise, uncertainty) pair, in sweep order.
        """
        threshold = check_real("threshold", threshold, low=1.0)
        rows = self.table()
        n_g = len(self.config.gammas)
        out = []
        for k in range(0, len(rows), n_g):
            panel = rows[k:k + n_g]  # one (noise, uncertainty) pair, gamma ascending
            within = [r.vehicle1_observer_mse <= threshold * r.algorithm1_mse for r in panel]
            first = next((i for i, w in enumerate(within) if w), None)
            last = panel[-1]
            p_last = k + n_g - 1
            alg1_last = self.mse["algorithm1"][p_last, :, 1:].mean(axis=1)
            ratio, ratio_se = ratio_of_means(alg1_last, self.mse["observer_only"][p_last, :, 0])
            own, own_se = ratio_of_means(alg1_last, self.mse["own_inversion"][p_last, :, 1:].mean(axis=1))
            obs, obs_se = ratio_of_means(alg1_last, self.mse["observer_only"][p_last, :, 1:].mean(axis=1))
            out.append(SweepFinding(
                sensor_noise_std=last.sensor_noise_std, parameter_uncertainty=last.parameter_uncertainty,
                threshold=threshold, smallest_gamma_within=None if first is None else panel[first].gamma,
                within_at_every_larger_gamma=first is not None and all(within[first:]),
                gammas_algorithm1_wins=tuple(r.gamma for r, w in zip(panel, within) if not w),
                largest_gamma=last.gamma, algorithm1_over_observer_at_largest=ratio,
                algorithm1_over_observer_at_largest_se=ratio_se,
                algorithm1_over_own_inversion_at_largest=own, algorithm1_over_own_inversion_at_largest_se=own_se,
                algorithm1_over_own_observer_at_largest=obs, algorithm1_over_own_observer_at_largest_se=obs_se,
                unresolved_gammas=tuple(r.gamma for r in panel
                                        if abs(r.algorithm1_gain - threshold) <= 2 * r.algorithm1_gain_se)))
        return out

    def plot(self, path):
        """Draw ``sweep.png`` (hands off to :func:`roadcollab.reporting.plotting_sweep.plot_sweep`).

        Parameters
        ----------
        path : str or Path
            Output image.

        Returns
        -------
        Path
            ``path``.
        """
        from ..reporting.plotting_sweep import plot_sweep

        return plot_sweep(self.table(), path)


def _run_seed_sequences(seed: int, n_runs: int, r: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """(fleet, simulation) SeedSequences of run ``r``, the same at every grid point.

    Built afresh on every call: ``SeedSequence.spawn`` advances the parent's child counter, so
    reusing a parent (or passing the same child to two ``simulate_run`` calls) would hand later
    grid points different randomness.
    """
    fleet_ss, sim_ss = np.random.SeedSequence(seed).spawn(n_runs)[r].spawn(2)
    return fleet_ss, sim_ss


@dataclass(frozen=True)
class _SweepTask:
    """Picklable task: evaluates flat indices ``i = point * n_runs + run`` of a sweep."""

    config: SweepConfig
    seed: int

    def __call__(self, indices) -> list[dict]:
        cfg = self.config
        points = cfg.points()
        out = []
        for i in indices:
            p, r = divmod(i, cfg.n_runs)
            exp = cfg.point_config(*points[p])
            fleet_ss, sim_ss = _run_seed_sequences(self.seed, cfg.n_runs, r)
            pipe = FleetPipeline(exp, sample_fleet(cfg.n_vehicles, exp.fleet, rng=np.random.default_rng(fleet_ss)))
            res = simulate_run(pipe, sim_ss, privacy=False)
            out.append({k: np.asarray(res.mse[k], dtype=float) for k in SWEPT_ESTIMATORS})
        return out


def run_sweep(config: SweepConfig, seed: int, *, progress: Callable[[int], None] | None = None,
              workers: int | None = None, scheduler: str | None = None) -> SweepResult:
    """Run every grid point of a sweep, serially or on Dask.

    Cost: one fleet setup (:class:`~roadcollab.experiments.reproduction.FleetPipeline`, including the
    centralised and oracle estimators) and one run per (grid point, run) pair; about 0.8 s
    for 10 vehicles on one core.

    Parameters
    ----------
    config : SweepConfig
    seed : int
        Root seed (>= 0). Run ``r`` gets the same randomness at every grid point.
    progress : callable, optional
        Called with the number of finished (grid point, run) pairs, out of
        ``len(config.points()) * config.n_runs``.
    workers : int, optional
        Local Dask cluster with this many worker processes (the result is identical).
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    SweepResult

    Raises
    ------
    ParameterError
        ``config`` is not a SweepConfig, ``seed`` is negative, or the parallel options clash.

    Examples
    --------
    >>> cfg = SweepConfig(gammas=(1, 128), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,),
    ...                   n_vehicles=3, n_runs=2)
    >>> rows = run_sweep(cfg, 0).table()  # doctest: +SKIP
    """
    from ..experiments.runner import map_runs

    if not isinstance(config, SweepConfig):
        raise ParameterError(f"config must be a SweepConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    P, R, V = len(config.points()), config.n_runs, config.n_vehicles
    runs = map_runs(_SweepTask(config, seed), P * R, workers=workers, scheduler=scheduler, progress=progress)
    mse = {k: np.array([run[k] for run in runs]).reshape(P, R, V) for k in SWEPT_ESTIMATORS}
    return SweepResult(config=config, seed=seed, mse=mse)
