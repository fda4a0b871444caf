"""Configuration of the anomaly detector's calibration: training seeds, road conditions, grid.

See :mod:`roadcollab.experiments.anomalies.calibration` for the procedure.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Sequence

from ..._validation import check_int, check_positive, check_real
from ...detection.detector import DetectorSpec
from ...errors import ParameterError
from .config import AnomalyStudyConfig, check_levels
from ..config import ExperimentConfig

__all__ = ["EVALUATION_SEEDS", "OBJECTIVE_ESTIMATORS", "AnomalyCalibrationConfig", "parse_seeds"]

#: Root seeds of the evaluation (the default ``--seed`` of ``roadcollab anomalies``): refused.
EVALUATION_SEEDS = (0,)

#: Estimates whose F1 enters the objective (attributes of :class:`~roadcollab.experiments.anomalies.estimates.RunEstimates`).
OBJECTIVE_ESTIMATORS = ("collaborative", "fused")


def _check_grid(name: str, value, *, low_open: bool) -> tuple[float, ...]:
    """A non-empty tuple of distinct numbers >= 0 (> 0 with ``low_open``), in the given order."""
    if not isinstance(value, (tuple, list)) or len(value) == 0:
        raise ParameterError(f"{name} must be a non-empty tuple of numbers, got {value!r}")
    out = tuple(check_real(f"{name}[{i}]", v, low=0.0, low_open=low_open) for i, v in enumerate(value))
    if len(set(out)) != len(out):
        raise ParameterError(f"{name} must not repeat a value, got {out}")
    return out


@dataclass(frozen=True)
class AnomalyCalibrationConfig:
    """Everything the calibration depends on, the training seeds included.

    Parameters
    ----------
    seeds : tuple of int
        Training root seeds (>= 0, distinct, none of :data:`EVALUATION_SEEDS`).
    runs_per_seed : int
        Roads (runs) per seed.
    experiment : ExperimentConfig
        Fleet, road and sensors of the default condition (its ``n_runs`` is not used), at least
        2 vehicles.
    condition_depths : tuple of float
        Depth/height (m) of every anomaly in each further road condition (besides the default
        road, whose anomalies are 2.5-10 cm).
    snr_thresholds : tuple of float
        Grid of ``DetectorSpec.snr_threshold`` (dimensionless, > 0).
    min_depths : tuple of float
        Grid of ``DetectorSpec.min_depth``, m (>= 0).
    detector : DetectorSpec
        The other detector parameters; its ``snr_threshold`` and ``min_depth`` are the reference
        point whose gap to the best point is reported.
    tolerance : float
        Center distance, m, within which a detection matches a true anomaly.
    """

    seeds: tuple[int, ...] = (1000, 1001, 1002, 1003, 1004)
    runs_per_seed: int = 8
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    condition_depths: tuple[float, ...] = (0.02, 0.03)
    snr_thresholds: tuple[float, ...] = (3.5, 4.0, 4.25, 4.5, 5.0, 5.5)
    min_depths: tuple[float, ...] = (0.005, 0.0075, 0.01, 0.0125, 0.015)
    detector: DetectorSpec = field(default_factory=DetectorSpec)
    tolerance: float = 1.0

    def __post_init__(self):
        if not isinstance(self.seeds, (tuple, list)) or len(self.seeds) == 0:
            raise ParameterError(f"seeds must be a non-empty tuple of integers, got {self.seeds!r}")
        seeds = tuple(check_int(f"seeds[{i}]", s, low=0) for i, s in enumerate(self.seeds))
        if len(set(seeds)) != len(seeds):
            raise ParameterError(f"seeds must be distinct, got {seeds}")
        evaluation = sorted(set(seeds) & set(EVALUATION_SEEDS))
        if evaluation:
            raise ParameterError(f"seeds must be training seeds, not evaluation seeds {list(EVALUATION_SEEDS)} "
                                 f"(the default seed of `roadcollab anomalies`), got {evaluation}")
        object.__setattr__(self, "seeds", seeds)
        check_int("runs_per_seed", self.runs_per_seed, low=1)
        if not isinstance(self.experiment, ExperimentConfig):
            raise ParameterError(f"experiment must be an ExperimentConfig, got {type(self.experiment).__name__}")
        depths = check_levels("condition_depths", self.condition_depths, positive=True)
        if len(set(depths)) != len(depths):
            raise ParameterError(f"condition_depths must not repeat a depth, got {depths}")
        object.__setattr__(self, "condition_depths", depths)
        object.__setattr__(self, "snr_thresholds", _check_grid("snr_thresholds", self.snr_thresholds,
                                                               low_open=True))
        object.__setattr__(self, "min_depths", _check_grid("min_depths", self.min_depths, low_open=False))
        if not isinstance(self.detector, DetectorSpec):
            raise ParameterError(f"detector must be a DetectorSpec, got {type(self.detector).__name__}")
        object.__setattr__(self, "tolerance", check_positive("tolerance", self.tolerance))
        self.study_config()   # validates the fleet size and the condition depths against the road model

    @property
    def conditions(self) -> tuple[str, ...]:
        """Names of the road conditions: ``"default"``, then ``"all_<depth>mm"`` per condition depth."""
        return ("default",) + tuple(f"all_{1000 * d:g}mm" for d in self.condition_depths)

    def study_config(self) -> AnomalyStudyConfig:
        """The anomaly study of one training seed.

        Returns
        -------
        AnomalyStudyConfig
            Its default condition and depth sweep are the calibration's conditions (no noise
            sweep); ``runs_per_seed`` runs.
        """
        return AnomalyStudyConfig(experiment=self.experiment, n_runs=self.runs_per_seed,
                                  depths=self.condition_depths, noise_levels=(), detector=self.detector,
                                  tolerance=self.tolerance)

    def grid(self) -> list[DetectorSpec]:
        """Detector of every grid point.

        Returns
        -------
        list of DetectorSpec
            ``detector`` with each ``(snr_threshold, min_depth)`` of the grid,
            ``snr_threshold``-major.
        """
        return [dataclasses.replace(self.detector, snr_threshold=t, min_depth=d)
                for t in self.snr_thresholds for d in self.min_depths]

    def to_dict(self) -> dict:
        """JSON-ready configuration.

        Returns
        -------
        dict
            Every field by name, nested dataclasses as dicts.
        """
        return dataclasses.asdict(self)


def parse_seeds(items: Sequence[str] | str) -> tuple[int, ...]:
    """Seeds from command-line text: integers and inclusive ranges ``a-b``, comma or space separated.

    Parameters
    ----------
    items : str or sequence of str
        E.g. ``"1000-1004"`` or ``["1000", "1002,1005-1006"]``.

    Returns
    -------
    tuple of int
        In the given order, ranges expanded.

    Raises
    ------
    ParameterError
        On text that is not a non-negative integer or an ascending range.

    Examples
    --------
    >>> parse_seeds(["1000-1002", "7"])
    (1000, 1001, 1002, 7)
    """
    parts = [t for item in ([items] if isinstance(items, str) else list(items)) for t in item.split(",")]
    out: list[int] = []
    for text in (t.strip() for t in parts):
        lo, sep, hi = text.partition("-")
        if not (text.isascii() and lo.isdigit() and (not sep or hi.isdigit())):
            raise ParameterError(f"seeds must be integers >= 0 or ranges 'a-b', got {text!r}")
        if sep and int(hi) < int(lo):
            raise ParameterError(f"seeds range must be ascending, got {text!r}")
        out.extend(range(int(lo), int(hi if sep else lo) + 1))
    if not out:
        raise ParameterError(f"seeds must name at least one seed, got {items!r}")
    return tuple(out)
