"""Grid and configuration of the sweep over observer, noise and model quality.

See :mod:`roadcollab.experiments.sweep.study` for what the sweep measures and how it draws its runs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

from ..._validation import check_int, check_nonnegative, check_positive, check_real
from ...errors import ParameterError
from ..config import ExperimentConfig

__all__ = ["SWEPT_ESTIMATORS", "SweepConfig"]

#: Estimators whose per-vehicle MSE the sweep keeps (``algorithm1_private`` equals
#: ``algorithm1`` with privacy off, so it is not kept).
SWEPT_ESTIMATORS = ("observer_only", "own_inversion", "own_posterior_inversion", "algorithm1", "fused",
                    "fused_posterior", "centralized", "oracle_per_bin")

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
