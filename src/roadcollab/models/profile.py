"""Two-track road profiles: on a distance grid, and as seen in time by a vehicle at constant speed.

Columns are the wheel tracks ``[left, right]``; elevations in m, distances in m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import check_matrix, check_positive, check_real
from ..errors import ParameterError
from .anomaly import Anomaly

__all__ = ["TimeRoad", "RoadProfile"]


@dataclass(frozen=True, eq=False)
class TimeRoad:
    """The road seen by a vehicle at constant speed, sampled in time.

    The elevation is taken as linear between samples, so the road velocity is exactly
    piecewise constant and a zero-order-hold discretisation of the vehicle is exact.

    Parameters
    ----------
    time : numpy.ndarray
        Shape (N,), s: ``k / sample_rate``, start of each sample interval.
    elevation : numpy.ndarray
        Shape (N + 1, 2), m: ``[left, right]`` at ``k / sample_rate``, ``k = 0..N``.
    velocity : numpy.ndarray
        Shape (N, 2), m/s: ``(elevation[k + 1] - elevation[k]) * sample_rate``.
    speed : float
        m/s, > 0.
    sample_rate : float
        Hz, > 0.
    start : float
        Road distance of sample 0, m.
    anomalies : tuple of Anomaly
        Those overlapping the window, positions in road distance.
    """

    time: np.ndarray        # s, shape (N,): k / sample_rate, start of each sample interval
    elevation: np.ndarray   # m, shape (N + 1, 2): [left, right] at k / sample_rate, k = 0..N
    velocity: np.ndarray    # m/s, shape (N, 2): (elevation[k + 1] - elevation[k]) * sample_rate
    speed: float            # m/s
    sample_rate: float      # Hz
    start: float            # m, road distance of sample 0
    anomalies: tuple[Anomaly, ...] = ()   # overlapping the window, positions in road distance

    def __post_init__(self):
        time = check_matrix("time", self.time, (None,))
        n = time.shape[0]
        elevation = check_matrix("elevation", self.elevation, (n + 1, 2))
        velocity = check_matrix("velocity", self.velocity, (n, 2))
        for name, arr in (("time", time), ("elevation", elevation), ("velocity", velocity)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "speed", check_positive("speed", self.speed))
        object.__setattr__(self, "sample_rate", check_positive("sample_rate", self.sample_rate))
        object.__setattr__(self, "start", check_real("start", self.start))
        object.__setattr__(self, "anomalies", tuple(self.anomalies))

    @property
    def positions(self) -> np.ndarray:
        """Road distance (m) of the elevation samples, shape (N + 1,)."""
        return self.start + self.speed * np.arange(self.time.shape[0] + 1) / self.sample_rate

    def position(self, k) -> float:
        """Road distance of an elevation sample.

        Parameters
        ----------
        k : float
            Sample index (may be fractional).

        Returns
        -------
        float
            m.
        """
        return self.start + self.speed * check_real("k", k) / self.sample_rate


@dataclass(frozen=True, eq=False)
class RoadProfile:
    """A two-track road profile on a distance grid.

    Parameters
    ----------
    distance : numpy.ndarray
        Shape (n,), m, strictly increasing, n >= 2.
    elevation : numpy.ndarray
        Shape (n, 2), m, columns ``[left, right]``.
    anomalies : tuple of Anomaly
        Ground truth (empty for measured roads).
    source : str
        Where the profile comes from, e.g. ``"synthetic ISO C"`` or a file name.
    """

    distance: np.ndarray    # m, shape (n,), strictly increasing
    elevation: np.ndarray   # m, shape (n, 2), columns [left, right]
    anomalies: tuple[Anomaly, ...] = ()   # ground truth (empty for measured roads)
    source: str = ""        # e.g. "synthetic ISO C" or the file name

    def __post_init__(self):
        distance = check_matrix("distance", self.distance, (None,))
        if distance.shape[0] < 2 or np.any(np.diff(distance) <= 0):
            raise ParameterError(f"distance must be strictly increasing with >= 2 points, got {distance.shape[0]} "
                                 f"points and {int(np.sum(np.diff(distance) <= 0))} non-increasing steps")
        elevation = check_matrix("elevation", self.elevation, (distance.shape[0], 2))
        for name, arr in (("distance", distance), ("elevation", elevation)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if not all(isinstance(a, Anomaly) for a in self.anomalies):
            raise ParameterError("anomalies must be a sequence of Anomaly")
        object.__setattr__(self, "anomalies", tuple(self.anomalies))
        if not isinstance(self.source, str):
            raise ParameterError(f"source must be a str, got {type(self.source).__name__}")

    @property
    def length(self) -> float:
        """Covered distance (m)."""
        return float(self.distance[-1] - self.distance[0])

    def sample(self, speed, sample_rate, *, start=0.0, duration=None) -> TimeRoad:
        """Elevation seen at constant ``speed`` (m/s), sampled at ``sample_rate`` (Hz).

        Linear interpolation in distance at ``x_k = start + speed * k / sample_rate`` for
        ``k = 0..N`` with ``N = floor(duration * sample_rate)`` (``duration`` in s; default:
        up to the end of the profile). The window ``[start, x_N]`` must lie in the profile.

        Parameters
        ----------
        speed : float
            m/s, > 0.
        sample_rate : float
            Hz, > 0.
        start : float
            Road distance of the first sample, m.
        duration : float or None
            s, > 0; None samples to the end of the profile.

        Returns
        -------
        TimeRoad
            N intervals, with the anomalies that overlap ``[start, x_N]``.

        Raises
        ------
        ParameterError
            If the window does not lie in the profile or covers less than one interval.
        """
        speed = check_positive("speed", speed)
        sample_rate = check_positive("sample_rate", sample_rate)
        start = check_real("start", start)
        first, last = float(self.distance[0]), float(self.distance[-1])
        tol = 1e-9 * max(1.0, abs(first), abs(last))   # absorbs float rounding of x_N
        if not first - tol <= start < last:
            raise ParameterError(f"start must lie in the profile [{first:g}, {last:g}) m, got {start:g}")
        if duration is None:
            duration = (last - start) / speed
        else:
            duration = check_positive("duration", duration)
        n = int(math.floor(duration * sample_rate + 1e-9))
        end = start + speed * n / sample_rate
        if n < 1:
            raise ParameterError(f"duration must cover at least one sample interval 1/sample_rate = "
                                 f"{1 / sample_rate:g} s, got {duration:g} s")
        if end > last + tol:
            raise ParameterError(f"duration must keep the window inside the profile: start + speed * duration = "
                                 f"{end:g} m > profile end {last:g} m (max duration {(last - start) / speed:g} s)")
        x = np.clip(start + speed * np.arange(n + 1) / sample_rate, first, last)
        elevation = np.column_stack([np.interp(x, self.distance, self.elevation[:, c]) for c in range(2)])
        inside = tuple(a for a in self.anomalies if a.end >= start and a.position <= end)
        return TimeRoad(time=np.arange(n) / sample_rate, elevation=elevation,
                        velocity=np.diff(elevation, axis=0) * sample_rate, speed=speed,
                        sample_rate=sample_rate, start=start, anomalies=inside)

