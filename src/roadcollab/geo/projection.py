"""A local metric projection of WGS 84 and great-circle distances (pyproj).

Map matching and linear referencing need metres. A transverse Mercator projection centred on the
network (``+proj=tmerc +lat_0 +lon_0``, WGS 84 ellipsoid) has a scale error below 1e-6 within
10 km of its centre (the scale factor grows as ``1 + x^2 / (2 R^2)``: 1.2e-6 at 10 km), far below
the GPS error, so lengths along the roads are metres on the ground. Distances between two
positions given in degrees (the done-when checks) are geodesics on the WGS 84 ellipsoid
(``pyproj.Geod.inv``, Karney's algorithm), not the projection's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pyproj import Geod, Transformer

from .._validation import check_real

__all__ = ["LocalProjection", "geodesic_m"]

_GEOD = Geod(ellps="WGS84")


@dataclass(frozen=True)
class LocalProjection:
    """Transverse Mercator centred on ``(lat0_deg, lon0_deg)``: degrees <-> metres east/north.

    Parameters
    ----------
    lat0_deg, lon0_deg : float
        Centre, WGS 84 degrees.
    """

    lat0_deg: float
    lon0_deg: float
    _fwd: Transformer = field(init=False, repr=False, compare=False)
    _inv: Transformer = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        check_real("lat0_deg", self.lat0_deg, low=-85.0, high=85.0)
        check_real("lon0_deg", self.lon0_deg, low=-180.0, high=180.0)
        crs = f"+proj=tmerc +lat_0={self.lat0_deg!r} +lon_0={self.lon0_deg!r} +k=1 +ellps=WGS84 +units=m +no_defs"
        object.__setattr__(self, "_fwd", Transformer.from_crs("EPSG:4326", crs, always_xy=True))
        object.__setattr__(self, "_inv", Transformer.from_crs(crs, "EPSG:4326", always_xy=True))

    def to_xy(self, lon, lat) -> tuple[np.ndarray, np.ndarray]:
        """Degrees to metres.

        Parameters
        ----------
        lon, lat : array_like
            WGS 84 degrees (lon first, as GeoJSON).

        Returns
        -------
        x, y : ndarray
            Metres east and north of the centre.
        """
        x, y = self._fwd.transform(np.asarray(lon, float), np.asarray(lat, float))
        return np.asarray(x), np.asarray(y)

    def to_lonlat(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Metres to degrees.

        Parameters
        ----------
        x, y : array_like
            Metres east and north of the centre.

        Returns
        -------
        lon, lat : ndarray
            WGS 84 degrees.
        """
        lon, lat = self._inv.transform(np.asarray(x, float), np.asarray(y, float))
        return np.asarray(lon), np.asarray(lat)


def geodesic_m(lon1, lat1, lon2, lat2) -> np.ndarray:
    """Geodesic (great-circle on the WGS 84 ellipsoid) distance, m.

    Parameters
    ----------
    lon1, lat1, lon2, lat2 : array_like
        Degrees.

    Returns
    -------
    ndarray
        m.
    """
    _, _, d = _GEOD.inv(np.asarray(lon1, float), np.asarray(lat1, float), np.asarray(lon2, float),
                        np.asarray(lat2, float))
    return np.asarray(d)
