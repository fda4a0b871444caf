"""The fleet's road plan: the distance grid, its segments and the estimator design every vehicle shares.

A networked fleet cannot wait for its slowest vehicle to learn the wavenumber band edge that
:func:`roadcollab.experiments.drives.fleet_estimation.estimate_fleet` takes from the drives
(``n_low = band_low_hz / v_min``): the plan fixes it when the fleet is enrolled, from the slowest speed
the fleet admits (``min_speed``). With ``min_speed`` equal to the drives' slowest speed the networked
run and ``roadcollab estimate`` compute the same numbers.

Segment ``s`` is the grid points ``i`` with ``s * m <= i < (s + 1) * m``, ``m = segment_length / spacing``,
grid point ``i`` at ``i * spacing`` metres (the grid of :func:`~roadcollab.experiments.drives.distance_maps.distance_grid`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._validation import check_positive
from ..errors import ParameterError

__all__ = ["RoadPlan"]

_TEXT = ("fleet_id", "road_id", "road_sha256")


@dataclass(frozen=True)
class RoadPlan:
    """Grid, segments and estimator design of one fleet.

    Attributes
    ----------
    fleet_id : str
        The fleet's name (topic prefix ``rc/<fleet_id>``).
    spacing : float
        Distance grid step, m (``estimate --grid-step``, default 0.05).
    segment_length : float
        Segment length, m; a whole number of grid steps.
    min_speed : float
        Slowest speed the fleet admits, m/s; fixes the wavenumber band edge.
    band_low_hz : float
        Band edge in time, Hz (ExperimentConfig default 0.5).
    gamma : float
        Observer parameter (ExperimentConfig default 512).
    road_id : str
        The road of ``road-network.geojson`` in the fleet folder whose measure is the fleet's distance
        axis (``enroll --network FILE --road-id ID``; :mod:`roadcollab.network.fleetroad`); empty: the
        drives' own distance axis, without GPS.
    road_sha256 : str
        SHA-256 (hex) of that network file, so that the service and every vehicle read the same roads.
    """

    fleet_id: str = "fleet"
    spacing: float = 0.05
    segment_length: float = 100.0
    min_speed: float = 10.0
    band_low_hz: float = 0.5
    gamma: float = 512.0
    road_id: str = ""
    road_sha256: str = ""

    def __post_init__(self) -> None:
        if bool(self.road_id) != bool(self.road_sha256):
            raise ParameterError("road_id and road_sha256 go together (a fleet on a road of its network file)")
        for name in ("spacing", "segment_length", "min_speed", "band_low_hz", "gamma"):
            check_positive(name, getattr(self, name))
        m = self.segment_length / self.spacing
        if abs(m - round(m)) > 1e-9 * m or round(m) < 16:
            raise ParameterError(f"segment_length must be a whole number (at least 16) of grid steps of "
                                 f"{self.spacing:g} m, got {self.segment_length:g} m")

    @property
    def band_low_per_m(self) -> float:
        """Wavenumber band edge ``band_low_hz / min_speed``, cycles/m (as estimate_fleet forms it)."""
        return self.band_low_hz / self.min_speed

    @property
    def points_per_segment(self) -> int:
        """Grid points per segment."""
        return int(round(self.segment_length / self.spacing))

    def segment_range(self, s: int) -> tuple[int, int]:
        """Grid indices ``[i0, i1)`` of segment ``s``.

        Parameters
        ----------
        s : int
            Segment index.
        """
        m = self.points_per_segment
        return s * m, (s + 1) * m

    def segments_of(self, i_first: int, i_last: int) -> list[int]:
        """Segments touched by grid points ``i_first..i_last`` (inclusive).

        Parameters
        ----------
        i_first, i_last : int
            First and last grid index.
        """
        m = self.points_per_segment
        return list(range(i_first // m, i_last // m + 1))

    def positions(self, i0: int, i1: int) -> np.ndarray:
        """Grid positions of indices ``i0..i1-1``, m (``spacing * arange``, as distance_grid).

        Parameters
        ----------
        i0, i1 : int
            Grid index range ``[i0, i1)``.
        """
        return self.spacing * np.arange(i0, i1)

    def to_dict(self) -> dict:
        """The plan as a TOML/JSON table (without the road keys of a fleet without a road: the same table as
        before fleets had roads)."""
        d = asdict(self)
        if not self.road_id:
            del d["road_id"], d["road_sha256"]
        return d

    @classmethod
    def from_dict(cls, data: object, where: str) -> "RoadPlan":
        """The plan from a table read from ``where`` (unknown or mistyped keys refused, naming ``where``).

        Parameters
        ----------
        data : dict
            The table.
        where : str
            Its file, for the message.
        """
        if not isinstance(data, dict):
            raise ParameterError(f"{where}: expected a [plan] table")
        known = set(cls.__dataclass_fields__)
        extra = sorted(set(data) - known)
        if extra:
            raise ParameterError(f"{where}: unknown plan keys {extra}; expected some of {sorted(known)}")
        kwargs: dict[str, Any] = {}     # str or float per field, checked above
        for k, v in data.items():
            if k in _TEXT:
                if not isinstance(v, str):
                    raise ParameterError(f"{where}: {k} must be a string")
                kwargs[k] = v
            elif isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ParameterError(f"{where}: {k} must be a number, got {v!r}")
            else:
                kwargs[k] = float(v)
        try:
            return cls(**kwargs)
        except ParameterError as err:
            raise ParameterError(f"{where}: {err}") from None
