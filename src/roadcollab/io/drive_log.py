"""A drive's acceleration log: parsing, clock checks and resampling of jittery time stamps.

Format (the full description is in :mod:`roadcollab.io.drives`): a header
``time_s,accel_left,accel_right`` optionally followed by ``,speed_mps`` or ``,distance_m``, then one
row of plain ASCII numbers per sample.

Clock handling
--------------
Let ``dt`` be the time steps and ``step`` their median.

* **Uniform** (every step within :data:`UNIFORM_RTOL` of ``step``): the samples are used as logged;
  the sample rate is ``1 / step`` rounded to 9 significant digits.
* **Clock steps** (time standing still or going backwards, ``dt <= 0``) are refused with the line.
* **Gaps** (``dt > MAX_GAP_STEPS * step``: missing samples or a clock jumping forward) are refused
  with the lines on either side: split the log there into two drives.
* **Jitter** (every step in ``(0, MAX_GAP_STEPS * step]``, not uniform): the log is resampled onto
  a uniform grid at its *mean* rate ``(N - 1) / (t[-1] - t[0])`` (so nothing is decimated and no
  aliasing is added), with the cubic interpolating spline through the logged samples
  (``scipy.interpolate.make_interp_spline``, ``k=3``; ``not-a-knot`` ends). A cubic spline is a
  band-limited interpolator to good approximation well below the Nyquist frequency and an
  attenuating one near it, where linear interpolation would leave a sawtooth from the jitter.
  Content the logger already aliased cannot be recovered by any resampler; one or two dropped
  samples in a row (a step up to 3x the median) are bridged by the spline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from .limits import MAX_ACCEL, FileLimits, check_file_size, parse_ascii_number, short_repr

__all__ = ["CSV_COLUMNS", "OPTIONAL_COLUMNS", "MIN_ROWS", "MAX_SAMPLE_RATE", "UNIFORM_RTOL", "MAX_GAP_STEPS",
           "SPEED_RANGE", "DriveLog", "read_drive_log"]

CSV_COLUMNS = ("time_s", "accel_left", "accel_right")
OPTIONAL_COLUMNS = ("speed_mps", "distance_m")
MIN_ROWS = 64
UNIFORM_RTOL = 1e-6
MAX_GAP_STEPS = 3.0          # a step above 3x the median is a gap (missing samples or a clock jump)
MAX_SAMPLE_RATE = 10_000.0   # Hz: vehicle accelerometer logs run at 50-1000 Hz
SPEED_RANGE = (0.5, 70.0)    # m/s, as speed_mps of the parameters file
_MAX_DISTANCE = 1e7          # m
_HEADER_TEXT = ",".join(CSV_COLUMNS)


@dataclass(frozen=True, eq=False)
class DriveLog:
    """The validated content of a drive CSV, on a uniform time grid.

    Attributes
    ----------
    time : (N,) ndarray
        Uniform time stamps, s (as logged, or the resampling grid).
    accel : (N, 2) ndarray
        Left and right body-tip accelerations, m/s^2.
    sample_rate : float
        Hz.
    column : str or None
        ``"speed_mps"``, ``"distance_m"`` or None (no fourth column).
    values : (N,) ndarray or None
        The fourth column on the same grid (m/s or m).
    resampled : bool
        True if jittery time stamps were resampled.
    max_jitter : float
        Largest ``|dt - step| / step`` of the logged steps.
    """

    time: np.ndarray
    accel: np.ndarray
    sample_rate: float
    column: str | None
    values: np.ndarray | None
    resampled: bool
    max_jitter: float


def _expected(s: str) -> str:
    """What a field that :func:`parse_ascii_number` refused should have been (NaN/overflow vs. non-ASCII)."""
    try:
        v = float(s)
    except (ValueError, OverflowError):
        return "a number"
    if not s.isascii() or "_" in s:
        return "a number written with ASCII digits 0-9 (no other scripts, no '_')"
    return "a finite number" if not math.isfinite(v) else "a plain decimal number"


def _parse_number(path: Path, lineno: int, col: int, name: str, text: str) -> float:
    s = text.strip()
    if not s:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected a number, got an empty "
                              "field")
    v = parse_ascii_number(s)
    if v is None:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected {_expected(s)}, got "
                              f"{short_repr(s)}")
    if name.startswith("accel") and abs(v) > MAX_ACCEL:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected an acceleration within "
                              f"+-{MAX_ACCEL:g} m/s^2 (beyond it a sample is a logger glitch), got {s}")
    if name == "speed_mps" and not SPEED_RANGE[0] <= v <= SPEED_RANGE[1]:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} (speed_mps): expected a speed in "
                              f"[{SPEED_RANGE[0]:g}, {SPEED_RANGE[1]:g}] m/s, got {s}")
    if name == "distance_m" and abs(v) > _MAX_DISTANCE:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} (distance_m): expected a distance within "
                              f"+-{_MAX_DISTANCE:g} m, got {s}")
    return v


def _read_rows(path: Path, limits: FileLimits) -> tuple[list[int], list[str], tuple[int, str] | None]:
    """The header (line number, text) and the 1-based line numbers and texts of the data rows.

    Streams the file; stops with a FileFormatError at the first row past ``limits.max_rows``.
    """
    check_file_size(path, "drive CSV", limits.max_bytes)
    linenos: list[int] = []
    rows: list[str] = []
    header: tuple[int, str] | None = None
    try:
        with path.open(encoding="utf-8-sig", newline=None) as fh:
            for lineno, ln in enumerate(fh, start=1):
                if not ln.strip():
                    continue
                if header is None:
                    header = (lineno, ln.rstrip("\n"))
                    continue
                if len(rows) >= limits.max_rows:
                    raise FileFormatError(f"{path} line {lineno}: more than {limits.max_rows} data rows; raise the "
                                          "limit with --max-rows")
                linenos.append(lineno)
                rows.append(ln)
    except UnicodeDecodeError as err:
        raise FileFormatError(f"{path}: expected a UTF-8 text file, got undecodable bytes ({err.reason})") from None
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read drive CSV: {err.strerror or err}") from None
    return linenos, rows, header


def _check_header(path: Path, head_no: int, head: str) -> tuple[str, ...]:
    """The column names of the header line ``head``; a FileFormatError saying how it differs otherwise."""
    names = [f.strip() for f in head.split(",")]
    if names[:3] == list(CSV_COLUMNS) and (len(names) == 3 or (len(names) == 4 and names[3] in OPTIONAL_COLUMNS)):
        return tuple(names)
    if len(names) in (3, 4) and all(parse_ascii_number(f) is not None for f in names):
        detail = "a row of numbers (the header line is required)"
    elif len(names) == 4 and names[:3] == list(CSV_COLUMNS):
        detail = (f"4 column name(s) {short_repr(head.strip())} (an optional fourth column must be "
                  f"{' or '.join(OPTIONAL_COLUMNS)})")
    elif len(names) != 3:
        detail = f"{len(names)} column name(s) {short_repr(head.strip())}"
    else:
        bad = next(i for i, (a, b) in enumerate(zip(names, CSV_COLUMNS)) if a != b)
        detail = f"{short_repr(head.strip())} (column {bad + 1} is {short_repr(names[bad], 30)}, expected {CSV_COLUMNS[bad]!r})"
    raise FileFormatError(f"{path} line {head_no}: expected the header '{_HEADER_TEXT}', got {detail}")


def _check_clock(path: Path, linenos: list[int], t: np.ndarray) -> tuple[float, float]:
    """Median step (s) and largest relative jitter; FileFormatError at a clock step or a gap."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0])
        raise FileFormatError(f"{path} line {linenos[k + 1]}: expected time_s to increase, got {float(t[k + 1])!r} "
                              f"after {float(t[k])!r} on line {linenos[k]} (a clock step; a log with a reset "
                              "clock must be split into two drives there)")
    step = float(np.median(dt))
    gap = np.flatnonzero(dt > MAX_GAP_STEPS * step)
    if gap.size:
        k = int(gap[0])
        raise FileFormatError(f"{path} line {linenos[k + 1]}: a gap in the log: time_s jumps by {dt[k]:.9g} s "
                              f"({dt[k] / step:.3g} median steps of {step:.9g} s; at most {MAX_GAP_STEPS:g} are "
                              f"bridged) from {float(t[k])!r} on line {linenos[k]}; {gap.size} such gap(s) in "
                              f"total: split the log at each gap into separate drives")
    return step, float(np.max(np.abs(dt - step)) / step)


def _resample(t: np.ndarray, data: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Uniform grid at the mean rate and the cubic interpolating spline of ``data`` on it."""
    # Imported for a log that needs resampling only: scipy.interpolate (with scipy.optimize) took 0.1-0.13 s
    # of every command that imports the drive readers, ``reproduce`` and ``bench`` too (docs/speed.md).
    from scipy.interpolate import make_interp_spline

    n = t.shape[0]
    fs = float(f"{(n - 1) / (t[-1] - t[0]):.9g}")
    grid = t[0] + np.arange(n) / fs
    grid = grid[grid <= t[-1] * (1 + 1e-12) + 1e-12]
    return grid, make_interp_spline(t, data, k=3, axis=0)(grid), fs


def read_drive_log(path, *, limits: FileLimits | None = None) -> DriveLog:
    """Read and validate a drive's acceleration log, resampling jittery time stamps (module docstring).

    Parameters
    ----------
    path : str or Path
    limits : FileLimits, optional
        Largest file (MB, checked before reading) and most data rows; default ``FileLimits()``.

    Returns
    -------
    DriveLog

    Raises
    ------
    FileFormatError
        ``"<path> line N: ..."`` for bad content (a clock step, a gap), ``"<path>: ..."`` otherwise.
    """
    path = Path(path)
    limits = FileLimits() if limits is None else limits
    linenos, rows, header = _read_rows(path, limits)
    if header is None:
        raise FileFormatError(f"{path} line 1: expected the header '{_HEADER_TEXT}', got an empty file")
    names = _check_header(path, *header)
    data = np.empty((len(rows), len(names)))
    for r, (lineno, ln) in enumerate(zip(linenos, rows)):
        parts = ln.split(",")
        if len(parts) != len(names):
            raise FileFormatError(f"{path} line {lineno}: expected {len(names)} numbers '{', '.join(names)}', "
                                  f"got {len(parts)}")
        for c, text in enumerate(parts):
            data[r, c] = _parse_number(path, lineno, c, names[c], text)
    if len(rows) < MIN_ROWS:
        raise FileFormatError(f"{path}: expected at least {MIN_ROWS} data rows after the header, got {len(rows)}")
    t = data[:, 0]
    step, jitter = _check_clock(path, linenos, t)
    resampled = jitter > UNIFORM_RTOL
    if resampled:
        t, values, fs = _resample(t, data[:, 1:])
    else:
        values, fs = data[:, 1:], float(f"{1.0 / step:.9g}")
    if fs > MAX_SAMPLE_RATE:
        raise FileFormatError(f"{path}: expected a sample rate of at most {MAX_SAMPLE_RATE:g} Hz (a time step of at "
                              f"least {1 / MAX_SAMPLE_RATE:g} s), got {fs:.6g} Hz (step {1 / fs:.3g} s)")
    column = names[3] if len(names) == 4 else None
    extra = values[:, 2].copy() if column else None
    if column == "distance_m" and extra is not None and np.any(np.diff(extra) <= 0):
        k = int(np.flatnonzero(np.diff(extra) <= 0)[0])
        where = f"near time_s {float(t[k + 1])!r}" if resampled else f"line {linenos[k + 1]}"
        raise FileFormatError(f"{path}: column 4 (distance_m) must increase (the vehicle moves at "
                              f">= {SPEED_RANGE[0]:g} m/s), got {float(extra[k + 1])!r} after {float(extra[k])!r} "
                              f"at {where}")
    return DriveLog(time=t.copy(), accel=values[:, :2].copy(), sample_rate=fs, column=column, values=extra,
                    resampled=bool(resampled), max_jitter=jitter)
