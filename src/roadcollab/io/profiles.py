"""Measured road profiles: the packaged profile, profile files, two-track roads built from them.

A profile file holds one measured wheel track as rows ``distance_m elevation_m`` or two as rows
``distance_m left_m right_m`` (whitespace or comma separated, ``#`` comments, an optional header line
of column names, UTF-8 with or without a byte-order mark); :func:`measured_road` turns it into a
two-track :class:`~roadcollab.models.profile.RoadProfile`, with a synthetic second track when the file
holds one.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from .._validation import check_matrix, check_nonnegative, check_positive
from ..errors import FileFormatError, ParameterError
from ..models.profile import RoadProfile
from ..models.road import MAX_SAMPLES, iso_gd0, moving_average, random_walk
from .limits import FileLimits, check_file_size, parse_ascii_number, short_repr

__all__ = ["MeasuredProfile", "packaged_profile_path", "load_profile", "measured_road"]

_LATERAL_HIGHPASS = 20.0    # m, window of the moving average removed from the lateral residual
MAX_DISTANCE = 1e7          # m: 10,000 km
MAX_ELEVATION = 1e4         # m: above Everest; a larger value is a glitch
MIN_SPACING, MAX_SPACING = 1e-4, 1.0   # m: profilometers sample every 1 mm to 0.3 m
#: A header field: a column name such as ``distance_m``, ``left (m)`` or ``z_right``.
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*(?: ?[(\[][A-Za-z0-9/^_ ]*[)\]])?")


@dataclass(frozen=True, eq=False)
class MeasuredProfile:
    """One or two measured tracks as read from a file: ``distance`` (n,) m, ``elevation`` (n,) or (n, 2) m.

    Parameters
    ----------
    distance : numpy.ndarray
        Shape (n,), m, as in the file.
    elevation : numpy.ndarray
        Shape (n,) for one track, (n, 2) for ``[left, right]``, m.
    spacing : float
        Median distance step, m, > 0.
    source : str
        The file path as given.
    """

    distance: np.ndarray   # m, shape (n,), as in the file
    elevation: np.ndarray  # m, shape (n,) or (n, 2)
    spacing: float         # m, median distance step
    source: str            # the file path as given

    def __post_init__(self):
        distance = check_matrix("distance", self.distance, (None,))
        elevation = np.asarray(self.elevation)
        elevation = check_matrix("elevation", elevation, (distance.shape[0],) if elevation.ndim != 2
                                 else (distance.shape[0], 2))
        for name, arr in (("distance", distance), ("elevation", elevation)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "spacing", check_positive("spacing", self.spacing))

    def __len__(self) -> int:
        return int(self.distance.shape[0])

    @property
    def tracks(self) -> int:
        """Number of measured tracks, 1 or 2."""
        return 1 if self.elevation.ndim == 1 else 2


def packaged_profile_path():
    """Path of the packaged measured profile ``data/profile_1.txt``.

    Returns
    -------
    importlib.resources.abc.Traversable
        A ``pathlib.Path`` in normal installs; readable by :func:`load_profile`.
    """
    return resources.files("roadcollab") / "data" / "profile_1.txt"


def _read_text(path, name: str, limits: FileLimits) -> str:
    """The UTF-8 text of ``path`` (str, PathLike or ``Traversable``) within ``limits``; FileFormatError otherwise."""
    if isinstance(path, (str, os.PathLike)):
        check_file_size(Path(path), "profile file", limits.max_bytes)
    try:
        # utf-8-sig: a byte-order mark (as spreadsheet programs write) is dropped, as the drive readers do.
        return (Path(path) if isinstance(path, (str, os.PathLike)) else path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise FileFormatError(f"{name}: expected a UTF-8 text file, got undecodable bytes ({err.reason})") from None
    except OSError as err:
        raise FileFormatError(f"{name}: cannot read profile file: {err.strerror or err}") from None


_WANT = "2 numbers 'distance_m elevation_m' or 3 'distance_m left_m right_m'"
_WANT_COLUMNS = {None: _WANT, 2: "2 numbers 'distance_m elevation_m'", 3: "3 numbers 'distance_m left_m right_m'"}


def _expected(tokens: list[str], columns: int | None) -> str:
    """What a line whose ``tokens`` :func:`parse_ascii_number` refused should have held."""
    want = _WANT_COLUMNS[columns]
    try:
        values = [float(t) for t in tokens]
    except (ValueError, OverflowError):
        return want
    if len(values) not in (2, 3) or (columns is not None and len(values) != columns):
        return want
    if not all(t.isascii() and "_" not in t for t in tokens):
        return want + " written with ASCII digits 0-9"
    return "finite numbers" if not all(map(math.isfinite, values)) else want + " in plain decimal notation"


def _tokens(raw: str) -> list[str]:
    """The fields of one line (comma or whitespace separated, ``#`` comment dropped); [] for a blank line."""
    line = raw.split("#", 1)[0].strip()
    if not line:
        return []
    return [t.strip() for t in line.split(",")] if "," in line else line.split()


def _is_header(tokens: list[str]) -> bool:
    """2 or 3 column names (none a number): the optional header line before the first data row."""
    return len(tokens) in (2, 3) and all(_NAME.fullmatch(t) and parse_ascii_number(t) is None for t in tokens)


def _parse_line(raw: str, lineno: int, name: str, columns: int | None = None) -> list[float] | None:
    """``[distance, elevation...]`` of one line (``columns`` numbers, 2 or 3 if None), None for a blank or
    comment line; FileFormatError otherwise."""
    tokens = _tokens(raw)
    if not tokens:
        return None
    parsed = [parse_ascii_number(t) for t in tokens]
    values = [v for v in parsed if v is not None]
    if len(parsed) not in (2, 3) or (columns is not None and len(parsed) != columns) or len(values) != len(parsed):
        same = "" if columns is None else f" (every row has the {columns} columns of the first)"
        raise FileFormatError(f"{name}: line {lineno}: expected {_expected(tokens, columns)}, got {short_repr(raw)}"
                              f"{same}")
    if abs(values[0]) > MAX_DISTANCE:
        raise FileFormatError(f"{name}: line {lineno}: expected a distance within +-{MAX_DISTANCE:g} m, got "
                              f"{values[0]:g}")
    for v in values[1:]:
        if abs(v) > MAX_ELEVATION:
            raise FileFormatError(f"{name}: line {lineno}: expected an elevation within +-{MAX_ELEVATION:g} m "
                                  f"(beyond it a sample is a glitch), got {v:g}")
    return values


def _parse_rows(text: str, name: str, max_rows: int) -> tuple[list[list[float]], list[int]]:
    """Data rows ``[distance, elevation...]`` with increasing distance, and their 1-based line numbers.

    Every row has the columns of the first (2 or 3); a header line of column names may come before it."""
    rows: list[list[float]] = []
    lines: list[int] = []
    columns = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        if not rows and columns is None and _is_header(_tokens(raw)):
            columns = len(_tokens(raw))
            continue
        values = _parse_line(raw, lineno, name, columns if columns is not None else (len(rows[0]) if rows else None))
        if values is None:
            continue
        if rows and values[0] <= rows[-1][0]:
            raise FileFormatError(f"{name}: line {lineno}: expected distance > {rows[-1][0]:g} (increasing), "
                                  f"got {values[0]:g}")
        if len(rows) >= max_rows:
            raise FileFormatError(f"{name}: line {lineno}: more than {max_rows} data rows; raise the limit with "
                                  "--max-rows")
        rows.append(values)
        lines.append(lineno)
    return rows, lines


def _uniform_spacing(distance: np.ndarray, lines: list[int], name: str) -> float:
    """Median step of ``distance`` (m); ParameterError naming the line of the first step off it."""
    steps = np.diff(distance)
    spacing = float(np.median(steps))
    # Tolerance relative to the spacing, plus float rounding of large distance values.
    bad = np.flatnonzero(np.abs(steps - spacing) > 1e-6 * spacing + 1e-12 * np.abs(distance[1:]))
    if bad.size:
        i = int(bad[0])
        raise FileFormatError(f"{name}: line {lines[i + 1]}: expected uniform spacing {spacing:g} m, "
                              f"got step {steps[i]:g} m")
    if not MIN_SPACING <= spacing <= MAX_SPACING:
        raise FileFormatError(f"{name}: expected a distance step between {MIN_SPACING:g} and {MAX_SPACING:g} m, got "
                              f"{spacing:g} m")
    return spacing


def load_profile(path, *, limits: FileLimits | None = None) -> MeasuredProfile:
    """Read rows ``distance_m elevation_m`` or ``distance_m left_m right_m`` (whitespace or comma separated;
    ``#`` comments; an optional header line of column names; UTF-8, a byte-order mark is dropped).

    Parameters
    ----------
    path : str, os.PathLike or importlib.resources.abc.Traversable
        The profile file, UTF-8.
    limits : FileLimits, optional
        Largest file (MB, checked before reading) and most rows; default ``FileLimits()``.

    Returns
    -------
    MeasuredProfile
        Distance and elevation in m as in the file (elevation (n,) for one track, (n, 2) for two),
        ``source = str(path)``.

    Raises
    ------
    FileFormatError
        Naming the file and 1-based line: too large or too many rows, not 2 or 3 plain ASCII numbers
        (as many in every row as in the first),
        non-finite values, a distance beyond +-1e7 m or an elevation beyond +-1e4 m, non-increasing or
        non-uniform distance (relative tolerance 1e-6 of the spacing), a spacing outside
        0.1 mm - 1 m, fewer than 8 rows.
    """
    name = str(path)
    limits = FileLimits() if limits is None else limits
    rows, lines = _parse_rows(_read_text(path, name, limits), name, limits.max_rows)
    if len(rows) < 8:
        raise FileFormatError(f"{name}: expected at least 8 data rows, got {len(rows)}")
    data = np.array(rows)
    spacing = _uniform_spacing(data[:, 0], lines, name)
    return MeasuredProfile(data[:, 0], data[:, 1] if data.shape[1] == 2 else data[:, 1:3], spacing, name)


def _detrend(distance: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Remove the least-squares line (DC and slope are unobservable to accelerometers)."""
    slope, offset = np.polyfit(distance, z, 1)
    return z - (offset + slope * distance)


def measured_road(path=None, *, second_track=None, lateral_class="A", detrend=True, spacing=None,
                  enveloping_length=0.25, rng=None, limits: FileLimits | None = None) -> RoadProfile:
    """Two-track road from a measured profile: its left track, and its right track or one made up.

    Parameters
    ----------
    path : str, PathLike, MeasuredProfile or None
        Profile file (see :func:`load_profile`), or one already read (a study drawing many roads
        from one file reads it once); None uses :func:`packaged_profile_path`.
    second_track : {None, "measured", "lateral", "same", "synthetic"}
        Right track: ``"measured"`` = the file's right track (two-track files only); ``None`` =
        ``"measured"`` for a two-track file, ``"lateral"`` for a one-track file;
        ``"lateral"`` = left + an independent ISO ``lateral_class`` random walk
        high-passed by subtracting its 20 m centred moving average (coherent at long, independent
        at short wavelengths); ``"same"`` = left; ``"synthetic"`` = an independent ISO
        ``lateral_class`` random walk (also detrended when ``detrend``).
    lateral_class : str or float
        ISO 8608 class (or Gd(n0) in m^3) of the right-track random walk.
    detrend : bool
        Remove a least-squares line from the measured track.
    spacing : float or None
        Resample linearly to this grid step (m); None keeps the file's spacing.
    enveloping_length : float
        Tyre enveloping moving-average width (m), as in
        :func:`~roadcollab.models.road.generate_road`; 0 disables.
    rng : None, int or numpy.random.Generator
    limits : FileLimits, optional
        Largest profile file and most rows (see :func:`load_profile`).

    Returns
    -------
    RoadProfile
        Distance starting at 0, elevation (n, 2) m, no anomalies, ``source`` = file name.
    """
    if second_track not in (None, "measured", "lateral", "same", "synthetic"):
        raise ParameterError(f"second_track must be None, 'measured', 'lateral', 'same' or 'synthetic', got "
                             f"{second_track!r}")
    gd0 = iso_gd0("lateral_class", lateral_class)
    enveloping_length = check_nonnegative("enveloping_length", enveloping_length)
    if not isinstance(detrend, (bool, np.bool_)):
        raise ParameterError(f"detrend must be a bool, got {detrend!r}")
    rng = np.random.default_rng(rng)
    if isinstance(path, MeasuredProfile):
        measured = path
    else:
        measured = load_profile(packaged_profile_path() if path is None else path, limits=limits)
    if second_track is None:
        second_track = "measured" if measured.tracks == 2 else "lateral"
    if second_track == "measured" and measured.tracks != 2:
        raise ParameterError(f"{measured.source}: second_track 'measured' needs a two-track profile "
                             "('distance_m left_m right_m'), got one track")
    distance = measured.distance - measured.distance[0]
    tracks = measured.elevation.reshape(len(measured), -1)
    left, right = (_detrend(distance, z) if detrend else z.copy() for z in (tracks[:, 0], tracks[:, -1]))
    step = measured.spacing
    if spacing is not None:
        step = check_positive("spacing", spacing)
        if not distance[-1] / MAX_SAMPLES <= step <= 0.5 * distance[-1]:
            raise ParameterError(f"spacing must lie in [{distance[-1] / MAX_SAMPLES:g}, {0.5 * distance[-1]:g}] m "
                                 f"(at most {MAX_SAMPLES} samples, at least 3), got {step:g}")
        grid = step * np.arange(int(math.floor(distance[-1] / step + 1e-9)) + 1)
        left, right, distance = np.interp(grid, distance, left), np.interp(grid, distance, right), grid
    # "measured" keeps the file's right track, detrended and resampled as the left.
    if second_track == "same":
        right = left.copy()
    elif second_track != "measured":
        walk = random_walk(distance.shape[0], step, gd0, rng, tracks=1)[:, 0]
        if second_track == "lateral":
            right = left + walk - moving_average(walk, step, _LATERAL_HIGHPASS)
        else:
            right = _detrend(distance, walk) if detrend else walk
    elevation = moving_average(np.column_stack([left, right]), step, enveloping_length)
    return RoadProfile(distance, elevation, (), Path(measured.source).name)


