"""Linear referencing: fixed segments along a road and their geometry.

A road's measure runs from 0 at its first position to its length at the last (the GeoJSON's
order). Segments are fixed in that measure, ``[0, L), [L, 2L), ...`` with ``L`` the segment length
(default 100 m), the same for both directions of travel, so the two lanes of a road and every
drive share them; a remainder shorter than half a segment is merged into the last one (a 30 m
stub would carry an IRI of little weight), a longer one is a segment of its own.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.ops import substring

from .._validation import check_real
from .network import RoadNetwork

__all__ = ["DEFAULT_SEGMENT_LENGTH", "IN_PER_MI_PER_M_PER_KM", "segment_bounds", "segment_lonlat"]

DEFAULT_SEGMENT_LENGTH = 100.0
#: 1 m/km = 1e-3 m/m = 63.36 in/mi (1 mi = 63,360 in): the unit US agencies report IRI in.
IN_PER_MI_PER_M_PER_KM = 63.36


def segment_bounds(length: float, segment_length: float = DEFAULT_SEGMENT_LENGTH) -> list[tuple[float, float]]:
    """The segments of a road (module docstring).

    Parameters
    ----------
    length : float
        Road length, m.
    segment_length : float
        m, > 0.

    Returns
    -------
    list of (float, float)
        ``(from_m, to_m)``, contiguous from 0 to ``length``.

    Examples
    --------
    >>> segment_bounds(230.0, 100.0)
    [(0.0, 100.0), (100.0, 230.0)]
    """
    length = check_real("length", length, low=0.0, low_open=True)
    seg = check_real("segment_length", segment_length, low=0.0, low_open=True)
    n = max(1, math.floor(length / seg + 1e-9))
    if length - n * seg >= 0.5 * seg - 1e-9:
        n += 1
    edges = [min(k * seg, length) for k in range(n)] + [length]
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:])]


def segment_lonlat(network: RoadNetwork, road_id: str, from_m: float, to_m: float) -> np.ndarray:
    """Geometry of a stretch of road, WGS 84.

    Parameters
    ----------
    network : RoadNetwork
    road_id : str
    from_m, to_m : float
        Measures, m.

    Returns
    -------
    (K, 2) ndarray
        ``[lon, lat]`` from ``from_m`` to ``to_m`` (the road's vertices between them included).
    """
    line = network.roads[road_id].line
    part = substring(line, from_m, to_m)
    xy = shapely.get_coordinates(part)
    lon, lat = network.projection.to_lonlat(xy[:, 0], xy[:, 1])
    return np.column_stack([lon, lat])
