"""Recorded drives: reading and writing the acceleration logs and their parameters files.

Each drive is one vehicle's pass over the same road segment; drives are taken in the order
given (vehicle 1 first). This module reads and validates the logs (:func:`load_drives`) and writes
them (:func:`write_drive_csv`, :func:`write_drive_params`); the estimation is
:mod:`roadcollab.experiments.drive_estimation`, the command ``roadcollab estimate`` is
:mod:`roadcollab.cli.estimate`.

File formats
------------
**Accelerations** (``drive1.csv``): a header line ``time_s,accel_left,accel_right`` (exactly these
names; spaces around them are ignored), then one row per sample of three finite numbers: time in
s and the left and right body-tip vertical accelerations in m/s^2. Blank lines are ignored. Numbers
are plain ASCII decimals (``nan``, ``inf``, ``1_000`` and other scripts' digits are refused);
an acceleration beyond +-200 m/s^2 is a logger glitch and refused with its line. The
sampling must be uniform: every time step must be within 1e-6 relative of the median step (resample
jittery logs first); the sample rate is ``1 / median step``, rounded to 9 significant digits, at
most 10 kHz. At least 64 rows, at most 2,000,000 and 200 MB (:class:`~roadcollab.io.limits.FileLimits`;
``--max-rows`` and ``--max-file-mb`` raise them; the size is checked before reading). Only time
differences are used: ``time_s`` may start anywhere.

**Parameters** (beside the CSV, same stem: ``drive1.toml`` or ``drive1.json``, not both)::

    speed_mps = 15.0             # required, 0.5-70: constant speed of the pass, m/s
    sensor_noise_std = 0.05      # optional, 0-20, m/s^2 per sample (default 0.05)
    start_m = 0.0                # optional, +-1e7: road distance of the first sample, m (default 0)

    [vehicle]                    # required: the vehicle's *estimated* half-car parameters, SI units
    sprung_mass = 750.0          # kg, 100-20000
    roll_inertia = 550.0         # kg m^2, 10-100000
    left_arm = 0.75              # m, 0.2-2
    right_arm = 0.75             # m, 0.2-2
    stiffness = 22000.0          # N/m, 2000-1.5e6
    damping = 1800.0             # N s/m, 50-1e5

JSON: the same keys, ``{"speed_mps": 15.0, "vehicle": {"sprung_mass": 750.0, ...}}``. Every key of
``vehicle`` is required; unknown keys anywhere are an error (a misspelt key must not silently
fall back to a default), and so is a key given twice. The ranges and their sources are
:data:`roadcollab.io.drive_params.PARAMETER_RANGES`. At most 1 MB. TOML needs Python >= 3.11
(``tomllib``); on 3.10 use JSON.

All drives must share the sample rate (to 1e-6 relative), ``speed_mps`` and ``start_m``: the
estimators relay signals on one common segment grid, so sample ``k`` of every drive must be the
same spot of the road. Trim the logs so that every drive starts at the same road position. Drives
of different length are **truncated to the shortest** (the report says so).

Every error is a :class:`~roadcollab.errors.FileFormatError` (a ``ParameterError``) whose message
starts with the file's
path and, for CSV content, ``line N:`` (1-based; the header is line 1), and says what was expected
and what was found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import check_signal
from ..errors import FileFormatError, ParameterError
from ..models.vehicle import HalfCarParameters
from .drive_params import params_path_for, read_drive_params
from .limits import MAX_ACCEL, FileLimits, check_file_size, parse_ascii_number, short_repr

__all__ = ["CSV_COLUMNS", "MIN_ROWS", "MAX_SAMPLE_RATE", "UNIFORM_RTOL", "Drive", "read_drive_csv", "load_drive",
           "load_drives", "write_drive_csv"]

CSV_COLUMNS = ("time_s", "accel_left", "accel_right")
MIN_ROWS = 64
UNIFORM_RTOL = 1e-6
MAX_SAMPLE_RATE = 10_000.0   # Hz: vehicle accelerometer logs run at 50-1000 Hz
_HEADER_TEXT = ",".join(CSV_COLUMNS)


# --- reading -------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Drive:
    """One recorded pass, validated.

    Attributes
    ----------
    csv_path, params_path : Path
    time : (N,) ndarray
        ``time_s`` as logged, s.
    accel : (N, 2) ndarray
        Left and right body-tip accelerations, m/s^2.
    sample_rate : float
        ``1 / median time step``, rounded to 9 significant digits, Hz.
    speed : float
        m/s.
    start_m : float
        Road distance of the first sample, m.
    sensor_noise_std : float
        m/s^2.
    params : HalfCarParameters
        The vehicle's estimated parameters.
    """

    csv_path: Path
    params_path: Path
    time: np.ndarray
    accel: np.ndarray
    sample_rate: float
    speed: float
    start_m: float
    sensor_noise_std: float
    params: HalfCarParameters

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.accel.shape[0])

    def describe(self) -> dict:
        """JSON-ready description (no signals)."""
        return {"csv": str(self.csv_path), "params_file": str(self.params_path), "n_samples": self.n_samples,
                "sample_rate_hz": self.sample_rate, "speed_mps": self.speed, "start_m": self.start_m,
                "sensor_noise_std": self.sensor_noise_std, "vehicle": self.params.as_dict()}


def _parse_number(path: Path, lineno: int, col: int, text: str) -> float:
    name = CSV_COLUMNS[col]
    s = text.strip()
    if not s:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected a number, got an empty "
                              "field")
    v = parse_ascii_number(s)
    if v is None:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected {_expected(s)}, got "
                              f"{short_repr(s)}")
    if col > 0 and abs(v) > MAX_ACCEL:
        raise FileFormatError(f"{path} line {lineno}: column {col + 1} ({name}): expected an acceleration within "
                              f"+-{MAX_ACCEL:g} m/s^2 (beyond it a sample is a logger glitch), got {s}")
    return v


def _expected(s: str) -> str:
    """What a field that :func:`parse_ascii_number` refused should have been (NaN/overflow vs. non-ASCII)."""
    try:
        v = float(s)
    except (ValueError, OverflowError):
        return "a number"
    if not s.isascii() or "_" in s:
        return "a number written with ASCII digits 0-9 (no other scripts, no '_')"
    return "a finite number" if not math.isfinite(v) else "a plain decimal number"


def _looks_numeric(fields_: list[str]) -> bool:
    return all(parse_ascii_number(f.strip()) is not None for f in fields_)


def _read_rows(path: Path, limits: FileLimits) -> tuple[list[int], list[str], tuple[int, str] | None]:
    """The header (line number, text) and the 1-based line numbers and texts of the data rows.

    Streams the file; stops with a FileFormatError at the first row past ``limits.max_rows``.
    """
    check_file_size(path, "drive CSV", limits.max_bytes)
    linenos, rows, header = [], [], None
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


def read_drive_csv(path, *, limits: FileLimits | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Read and validate a drive's acceleration log (format in the module docstring).

    Parameters
    ----------
    path : str or Path
    limits : FileLimits, optional
        Largest file (MB, checked before reading) and most data rows; default ``FileLimits()``.

    Returns
    -------
    time : (N,) ndarray
        s.
    accel : (N, 2) ndarray
        m/s^2, columns ``[left, right]``.
    sample_rate : float
        ``1 / median(diff(time))`` rounded to 9 significant digits, Hz.

    Raises
    ------
    FileFormatError
        ``"<path> line N: ..."`` for bad content, ``"<path>: ..."`` otherwise.
    """
    path = Path(path)
    limits = FileLimits() if limits is None else limits
    linenos, rows, header = _read_rows(path, limits)
    if header is None:
        raise FileFormatError(f"{path} line 1: expected the header '{_HEADER_TEXT}', got an empty file")
    _check_header(path, *header)
    data = np.empty((len(rows), 3))
    for r, (lineno, ln) in enumerate(zip(linenos, rows)):
        parts = ln.split(",")
        if len(parts) != 3:
            raise FileFormatError(f"{path} line {lineno}: expected 3 numbers '{', '.join(CSV_COLUMNS)}', "
                                  f"got {len(parts)}")
        for c, text in enumerate(parts):
            data[r, c] = _parse_number(path, lineno, c, text)
    if len(rows) < MIN_ROWS:
        raise FileFormatError(f"{path}: expected at least {MIN_ROWS} data rows after the header, got {len(rows)}")
    t = data[:, 0]
    step = _uniform_step(path, linenos, t)
    sample_rate = float(f"{1.0 / step:.9g}")
    if sample_rate > MAX_SAMPLE_RATE:
        raise FileFormatError(f"{path}: expected a sample rate of at most {MAX_SAMPLE_RATE:g} Hz (a time step of at "
                              f"least {1 / MAX_SAMPLE_RATE:g} s), got {sample_rate:.6g} Hz (step {step:.3g} s)")
    return t.copy(), data[:, 1:].copy(), sample_rate


def _check_header(path: Path, head_no: int, head: str) -> None:
    """Raise a FileFormatError saying how the header line ``head`` differs from :data:`CSV_COLUMNS`."""
    names = [f.strip() for f in head.split(",")]
    if names == list(CSV_COLUMNS):
        return
    if len(names) == 3 and _looks_numeric(names):
        detail = "a row of numbers (the header line is required)"
    elif len(names) != 3:
        detail = f"{len(names)} column name(s) {short_repr(head.strip())}"
    else:
        bad = next(i for i, (a, b) in enumerate(zip(names, CSV_COLUMNS)) if a != b)
        detail = f"{short_repr(head.strip())} (column {bad + 1} is {short_repr(names[bad], 30)}, expected {CSV_COLUMNS[bad]!r})"
    raise FileFormatError(f"{path} line {head_no}: expected the header '{_HEADER_TEXT}', got {detail}")


def _uniform_step(path: Path, linenos: list[int], t: np.ndarray) -> float:
    """The median time step (s) of ``t``; a FileFormatError naming the line if ``t`` is not increasing and uniform."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0])
        raise FileFormatError(f"{path} line {linenos[k + 1]}: expected time_s to increase, got {float(t[k + 1])!r} "
                             f"after {float(t[k])!r} on line {linenos[k]}")
    step = float(np.median(dt))
    bad = np.flatnonzero(np.abs(dt - step) > UNIFORM_RTOL * step)
    if bad.size:
        k = int(bad[0])
        raise FileFormatError(f"{path} line {linenos[k + 1]}: expected uniform sampling (every time step within "
                             f"{UNIFORM_RTOL:g} relative of the median step {step:.9g} s), got a step of "
                             f"{dt[k]:.9g} s from time_s {float(t[k])!r} on line {linenos[k]}; resample the log")
    return step


def load_drive(csv_path, params_path=None, *, limits: FileLimits | None = None) -> Drive:
    """Read one drive: the CSV and its parameters file.

    Parameters
    ----------
    csv_path : str or Path
    params_path : str or Path, optional
        Default: :func:`params_path_for` ``(csv_path)``.
    limits : FileLimits, optional
        Largest CSV (MB) and most rows (default ``FileLimits()``).

    Returns
    -------
    Drive
    """
    csv_path = Path(csv_path)
    if csv_path.suffix.lower() in (".toml", ".json"):
        raise FileFormatError(f"{csv_path}: expected the drive's acceleration CSV here (its parameters file is "
                             f"found beside it), got a parameters file")
    t, accel, fs = read_drive_csv(csv_path, limits=limits)
    params_path = params_path_for(csv_path) if params_path is None else Path(params_path)
    p = read_drive_params(params_path)
    return Drive(csv_path=csv_path, params_path=params_path, time=t, accel=accel, sample_rate=fs, speed=p["speed"],
                 start_m=p["start_m"], sensor_noise_std=p["sensor_noise_std"], params=p["params"])


def load_drives(paths, *, limits: FileLimits | None = None) -> list[Drive]:
    """Read every drive and check that they share one segment grid.

    Sample rates must agree to 1e-6 relative, ``speed_mps`` and ``start_m`` to 1e-9 relative;
    the error names the drive that differs from the first.

    Parameters
    ----------
    paths : str, Path or sequence of them
        Drive CSVs in driving order.
    limits : FileLimits, optional
        Largest CSV (MB) and most rows per drive (default ``FileLimits()``).

    Returns
    -------
    list of Drive
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ParameterError("expected at least one drive (--drive FILE), got none")
    drives = [load_drive(p, limits=limits) for p in paths]
    d0 = drives[0]
    for d in drives[1:]:
        if abs(d.sample_rate - d0.sample_rate) > UNIFORM_RTOL * d0.sample_rate:
            raise FileFormatError(f"{d.csv_path}: expected the sample rate of {d0.csv_path} ({d0.sample_rate:.9g} Hz), "
                                 f"got {d.sample_rate:.9g} Hz; all drives must share one sample rate (resample the "
                                 "log)")
        if abs(d.speed - d0.speed) > 1e-9 * d0.speed:
            raise FileFormatError(f"{d.params_path}: expected speed_mps = {d0.speed:g} as in {d0.params_path}, got "
                                 f"{d.speed:g}; all drives must share one speed (one segment grid)")
        if abs(d.start_m - d0.start_m) > 1e-9 * max(1.0, abs(d0.start_m)):
            raise FileFormatError(f"{d.params_path}: expected start_m = {d0.start_m:g} as in {d0.params_path}, got "
                                 f"{d.start_m:g}; trim the logs so that every drive starts at the same road "
                                 "position")
    return drives


# --- writing -------------------------------------------------------------------------------------

def write_drive_csv(path, time, accel) -> Path:
    """Write a drive CSV in the documented format, full precision (``repr`` floats).

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    time : (N,) array_like
        ``time_s`` column, s (uniform sampling is not checked here; :func:`read_drive_csv` checks it).
    accel : (N, 2) array_like
        Left and right body-tip vertical accelerations, m/s^2, finite.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        If ``accel`` is not a finite (N, 2) array or ``time`` does not have shape (N,).
    """
    time = np.asarray(time, dtype=float)
    accel = check_signal("accel", accel, 2)
    if time.shape != (accel.shape[0],):
        raise ParameterError(f"time must have shape ({accel.shape[0]},), got {time.shape}")
    lines = [_HEADER_TEXT] + [f"{float(t)!r},{float(a)!r},{float(b)!r}" for t, (a, b) in zip(time, accel)]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
