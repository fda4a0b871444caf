"""GPS fixes in a drive CSV: ``lat_deg, lon_deg`` columns at the GPS rate, empty between fixes.

Format
------
A drive CSV (:mod:`roadcollab.io.drives`) may end its header with ``,lat_deg,lon_deg`` (after the
optional ``speed_mps`` or ``distance_m`` column): WGS 84 latitude and longitude in degrees. Real
loggers write a fix on some rows only (1-10 Hz in a 100-200 Hz log) and leave both cells empty on
the others, so a row carries both or neither; a latitude must lie in [-90, 90] and a longitude in
[-180, 180]. At least :data:`MIN_FIXES` fixes are needed. Everything else in the file is read by
:func:`roadcollab.io.drive_log.read_drive_log` exactly as without GPS (same checks, same line
numbers in the messages).

The fixes are kept as logged (time of the row, lat, lon). Turning them into a position along a road
needs a map (:mod:`roadcollab.geo.matching`); the speed or odometer of the log gives the shape of
the position curve, the fixes only its offset (module docstring there).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import check_signal
from ..errors import FileFormatError, ParameterError
from .drive_log import DriveLog, read_drive_log
from .limits import FileLimits, check_file_size, parse_ascii_number, short_repr

__all__ = ["GPS_COLUMNS", "MIN_FIXES", "GpsFixes", "read_gps_log", "write_gps_drive_csv"]

GPS_COLUMNS = ("lat_deg", "lon_deg")
MIN_FIXES = 2
_RANGES = {"lat_deg": 90.0, "lon_deg": 180.0}


@dataclass(frozen=True, eq=False)
class GpsFixes:
    """The GPS fixes of one drive, as logged.

    Attributes
    ----------
    time : (F,) ndarray
        ``time_s`` of the rows carrying a fix, s (the log's clock, increasing).
    lat, lon : (F,) ndarray
        WGS 84 latitude and longitude, degrees.
    """

    time: np.ndarray
    lat: np.ndarray
    lon: np.ndarray

    @property
    def n_fixes(self) -> int:
        """Number of fixes F."""
        return int(self.time.shape[0])

    @property
    def rate_hz(self) -> float:
        """Mean fix rate, Hz."""
        return float((self.n_fixes - 1) / (self.time[-1] - self.time[0]))


def _header(path: Path) -> tuple[int, list[str]] | None:
    """Line number and column names of the first non-blank line (None for an empty file)."""
    try:
        with path.open(encoding="utf-8-sig", newline=None) as fh:
            for lineno, ln in enumerate(fh, start=1):
                if ln.strip():
                    return lineno, [f.strip() for f in ln.rstrip("\n").split(",")]
    except (UnicodeDecodeError, OSError):
        return None          # read_drive_log reports it with its own message
    return None


def _gps_value(path: Path, lineno: int, col: int, name: str, text: str) -> float:
    v = parse_ascii_number(text.strip())
    if v is None or abs(v) > _RANGES[name]:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected degrees within "
                              f"+-{_RANGES[name]:g} or an empty field between fixes, got {short_repr(text.strip())}")
    return v


def _split(path: Path, names: list[str], out) -> tuple[list[int], list[float], list[float]]:
    """Write every line without its GPS cells to ``out``; line numbers, lats and lons of the fixes."""
    k = len(names) - 2
    rows, lats, lons, header = [], [], [], False
    with path.open(encoding="utf-8-sig", newline=None) as fh:
        for lineno, ln in enumerate(fh, start=1):
            parts = ln.rstrip("\n").split(",")
            if not ln.strip() or not header or len(parts) != len(names):
                # blank lines keep the line numbers; the header and a row of the wrong width are passed on
                # without the GPS cells where they have them, and drive_log says what is wrong
                header = header or bool(ln.strip())
                out.write(",".join(parts[:k]) + "\n" if len(parts) == len(names) else ln.rstrip("\n") + "\n")
                continue
            lat, lon = parts[k].strip(), parts[k + 1].strip()
            if lat or lon:
                if not (lat and lon):
                    raise FileFormatError(f"{path} line {lineno}: expected both lat_deg and lon_deg or neither, "
                                          f"got {short_repr(lat) if lat else 'an empty lat_deg'} and "
                                          f"{short_repr(lon) if lon else 'an empty lon_deg'}")
                lats.append(_gps_value(path, lineno, k, "lat_deg", lat))
                lons.append(_gps_value(path, lineno, k + 1, "lon_deg", lon))
                rows.append(lineno)
            out.write(",".join(parts[:k]) + "\n")
    return rows, lats, lons


def read_gps_log(path, *, limits: FileLimits | None = None) -> tuple[DriveLog, GpsFixes | None]:
    """Read a drive CSV that may carry GPS columns (module docstring).

    Parameters
    ----------
    path : str or Path
    limits : FileLimits, optional
        Largest file (MB) and most rows, as for :func:`~roadcollab.io.drive_log.read_drive_log`.

    Returns
    -------
    DriveLog
        The acceleration log, read as without the GPS columns.
    GpsFixes or None
        None if the header has no GPS columns.

    Raises
    ------
    FileFormatError
        ``"<path> line N: ..."``: a half-filled or out-of-range fix, fewer than :data:`MIN_FIXES`
        fixes, and every error of ``read_drive_log``.
    """
    path = Path(path)
    limits = FileLimits() if limits is None else limits
    head = _header(path)
    if head is None or not set(GPS_COLUMNS) & set(head[1]):
        return read_drive_log(path, limits=limits), None
    lineno, names = head
    if names[-2:] != list(GPS_COLUMNS) or len(names) < 5:
        raise FileFormatError(f"{path} line {lineno}: expected the GPS columns last, as ',lat_deg,lon_deg' after "
                              f"'time_s,accel_left,accel_right[,speed_mps|distance_m]', got "
                              f"{short_repr(','.join(names))}")
    check_file_size(path, "drive CSV", limits.max_bytes)
    with tempfile.TemporaryDirectory(prefix="roadcollab-gps-") as tmp:
        bare = Path(tmp) / path.name
        with bare.open("w") as out:
            rows, lats, lons = _split(path, names, out)
        try:
            log = read_drive_log(bare, limits=limits)
        except FileFormatError as err:
            raise FileFormatError(str(err).replace(str(bare), str(path))) from None
    if len(rows) < MIN_FIXES:
        raise FileFormatError(f"{path}: expected at least {MIN_FIXES} GPS fixes (rows with lat_deg and lon_deg), "
                              f"got {len(rows)}")
    times = _fix_times(path, rows)
    return log, GpsFixes(time=times, lat=np.array(lats), lon=np.array(lons))


def _fix_times(path: Path, rows: list[int]) -> np.ndarray:
    """``time_s`` of the given lines (already validated by ``read_drive_log``)."""
    wanted, out = set(rows), []
    with path.open(encoding="utf-8-sig", newline=None) as fh:
        for lineno, ln in enumerate(fh, start=1):
            if lineno in wanted:
                out.append(float(ln.split(",", 1)[0]))
    return np.array(out)


def write_gps_drive_csv(path, time, accel, lat, lon, *, column: str | None = None, values=None) -> Path:
    """Write a drive CSV with GPS columns (module docstring), full precision.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    time : (N,) array_like
        ``time_s``, s.
    accel : (N, 2) array_like
        Left and right body-tip accelerations, m/s^2.
    lat, lon : (N,) array_like
        Degrees on the rows with a fix, NaN on the others (written as empty cells).
    column : {"speed_mps", "distance_m"} or None
        Optional fourth column.
    values : (N,) array_like, optional
        Its values (required with ``column``).

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        Shapes that do not agree, or a fix with only one of lat and lon.
    """
    accel = check_signal("accel", accel, 2)
    n = accel.shape[0]
    cols = [np.asarray(time, float), accel[:, 0], accel[:, 1]]
    header = "time_s,accel_left,accel_right"
    if column is not None:
        cols.append(np.asarray(values, float))
        header += f",{column}"
    lat, lon = np.asarray(lat, float), np.asarray(lon, float)
    if any(c.shape != (n,) for c in cols + [lat, lon]) or np.any(np.isnan(lat) != np.isnan(lon)):
        raise ParameterError(f"time, lat, lon (and values) must have shape ({n},), with NaN in lat and lon on the "
                             "same rows")
    lines = [header + ",lat_deg,lon_deg"]
    for k, row in enumerate(zip(*cols)):
        gps = ",," if np.isnan(lat[k]) else f",{float(lat[k])!r},{float(lon[k])!r}"
        lines.append(",".join(repr(float(v)) for v in row) + gps)
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
