"""Configuration of the road anomaly detection study (see :mod:`roadcollab.experiments.anomalies.study`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..._validation import check_int, check_positive, check_real
from ...detection.detector import DetectorSpec
from ...errors import ParameterError
from ...models.road import RoadSpec
from ..config import ExperimentConfig

__all__ = ["ESTIMATORS", "AnomalyStudyConfig", "check_levels"]

#: Estimates scored by the study (attributes of :class:`~roadcollab.experiments.anomalies.estimates.RunEstimates`).
ESTIMATORS = ("observer_only", "collaborative", "fused")


def check_levels(name: str, value, *, positive: bool) -> tuple[float, ...]:
    """Validate a tuple of sweep levels (depths in m, noise stds in m/s^2).

    Parameters
    ----------
    name : str
        Name in error messages.
    value : tuple or list of float
    positive : bool
        Require every level > 0 (else >= 0).

    Returns
    -------
    tuple of float
        The levels, in the given order.
    """
    if not isinstance(value, (tuple, list)):
        raise ParameterError(f"{name} must be a tuple of numbers, got {type(value).__name__}")
    check = check_positive if positive else (lambda n, v: check_real(n, v, low=0.0))
    return tuple(check(f"{name}[{i}]", v) for i, v in enumerate(value))


@dataclass(frozen=True)
class AnomalyStudyConfig:
    """Everything the anomaly study depends on besides the seed.

    Parameters
    ----------
    experiment : ExperimentConfig
        Fleet, road and sensors of the default condition (its ``n_runs`` is not used), at
        least 2 vehicles. With ``road_profile`` set, the measured profile's roughness gets
        synthetic anomalies with ground truth (:func:`roadcollab.models.road.with_anomalies`).
    n_runs : int
        Roads (runs); every condition uses the same runs.
    depths : tuple of float
        Anomaly depths/heights (m) of the F1-vs-depth sweep: every anomaly of the default road
        gets this depth (``RoadSpec.depth_range = (d, d)``). Empty: no sweep.
    noise_levels : tuple of float
        Accelerometer noise std (m/s^2) of the F1-vs-noise sweep; the estimators stay designed
        for ``experiment.sensor_noise_std``. Empty: no sweep.
    detector : DetectorSpec
    tolerance : float
        Center distance (m) within which a detection matches a true anomaly.
    map_vehicle : int
        1-based vehicle whose detections on run 1 make ``map_example``.
    """

    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    n_runs: int = 20
    depths: tuple[float, ...] = (0.01, 0.015, 0.02, 0.03, 0.05, 0.08)
    noise_levels: tuple[float, ...] = (0.01, 0.025, 0.05, 0.1, 0.2)
    detector: DetectorSpec = field(default_factory=DetectorSpec)
    tolerance: float = 1.0
    map_vehicle: int = 2

    def __post_init__(self):
        if not isinstance(self.experiment, ExperimentConfig):
            raise ParameterError(f"experiment must be an ExperimentConfig, got {type(self.experiment).__name__}")
        check_int("experiment.n_vehicles", self.experiment.n_vehicles, low=2)
        check_int("n_runs", self.n_runs, low=1)
        object.__setattr__(self, "depths", check_levels("depths", self.depths, positive=True))
        object.__setattr__(self, "noise_levels", check_levels("noise_levels", self.noise_levels, positive=False))
        if not isinstance(self.detector, DetectorSpec):
            raise ParameterError(f"detector must be a DetectorSpec, got {type(self.detector).__name__}")
        object.__setattr__(self, "tolerance", check_positive("tolerance", self.tolerance))
        check_int("map_vehicle", self.map_vehicle, low=1, high=self.experiment.n_vehicles)
        for d in self.depths:   # the road spec must accept every sweep depth
            self.road_spec(d)

    def road_spec(self, depth: float | None = None) -> RoadSpec:
        """The default road, or with every anomaly ``depth`` m deep (high).

        Parameters
        ----------
        depth : float, optional
            Depth (height) of every anomaly, m; None: the experiment's road unchanged.

        Returns
        -------
        RoadSpec
        """
        spec = self.experiment.road_spec()
        return spec if depth is None else dataclasses.replace(spec, depth_range=(depth, depth))

    def to_dict(self) -> dict:
        """JSON-ready configuration.

        Returns
        -------
        dict
            Every field by name, nested dataclasses as dicts.
        """
        return dataclasses.asdict(self)
