"""Ground truth of road anomalies: potholes and bumps on one or both wheel tracks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_positive, check_real
from ..errors import ParameterError

__all__ = ["ANOMALY_SIDES", "ANOMALY_KINDS", "Anomaly", "check_anomaly_fields"]

#: Wheel tracks an anomaly can sit on.
ANOMALY_SIDES = ("left", "right", "both")
#: Shapes of anomaly.
ANOMALY_KINDS = ("pothole", "bump")


@dataclass(frozen=True)
class Anomaly:
    """Ground truth of a pothole (rectangular, ``-depth``) or bump (raised cosine of height ``depth``).

    Parameters
    ----------
    position : float
        Start of the anomaly along the road, m.
    side : {"left", "right", "both"}
        Wheel track(s) it sits on.
    kind : {"pothole", "bump"}
    depth : float
        Depth of a pothole or height of a bump, m, > 0.
    length : float
        Extent along the road, m, > 0.
    """

    position: float   # m, start of the anomaly along the road
    side: str         # "left" | "right" | "both"
    kind: str         # "pothole" | "bump"
    depth: float      # m, > 0: depth of a pothole or height of a bump
    length: float     # m, > 0, extent along the road

    def __post_init__(self):
        check_anomaly_fields(self)
        object.__setattr__(self, "length", check_positive("length", self.length))

    @property
    def center(self) -> float:
        """Middle of the anomaly (m)."""
        return self.position + 0.5 * self.length

    @property
    def end(self) -> float:
        """End of the anomaly (m)."""
        return self.position + self.length

    @property
    def tracks(self) -> tuple[int, ...]:
        """Elevation columns hit: ``(0,)`` left, ``(1,)`` right, ``(0, 1)`` both."""
        return {"left": (0,), "right": (1,), "both": (0, 1)}[self.side]

    def elevation(self, distance) -> np.ndarray:
        """Elevation added by this anomaly.

        Parameters
        ----------
        distance : (n,) array_like
            Road distance, m.

        Returns
        -------
        (n,) ndarray
            m.
        """
        x = np.asarray(distance, dtype=float)
        u = (x - self.position) / self.length
        if self.kind == "pothole":
            # Half-open so that the two edges are single jumps of -depth and +depth.
            return np.where((u >= 0.0) & (u < 1.0), -self.depth, 0.0)
        return np.where((u >= 0.0) & (u <= 1.0), self.depth * 0.5 * (1.0 - np.cos(2 * np.pi * u)), 0.0)


def check_anomaly_fields(obj) -> None:
    """Validate (and normalise) ``position``, ``side``, ``kind`` and ``depth`` of a frozen
    anomaly-like dataclass (a true :class:`Anomaly` or a detection).

    Parameters
    ----------
    obj : frozen dataclass
        With ``position`` (m), ``side``, ``kind`` and ``depth`` (m); ``position`` and
        ``depth`` are replaced by their checked float values.

    Raises
    ------
    ParameterError
        If ``position`` is not a finite real, ``side`` or ``kind`` is not one of
        ``ANOMALY_SIDES``/``ANOMALY_KINDS``, or ``depth <= 0``.
    """
    object.__setattr__(obj, "position", check_real("position", obj.position))
    if obj.side not in ANOMALY_SIDES:
        raise ParameterError(f"side must be one of {ANOMALY_SIDES}, got {obj.side!r}")
    if obj.kind not in ANOMALY_KINDS:
        raise ParameterError(f"kind must be one of {ANOMALY_KINDS}, got {obj.kind!r}")
    object.__setattr__(obj, "depth", check_positive("depth", obj.depth))
