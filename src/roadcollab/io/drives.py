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
s and the left and right body-tip vertical accelerations in m/s^2. Blank lines are ignored. The
sampling must be uniform: every time step must be within 1e-6 relative of the median step (resample
jittery logs first); the sample rate is ``1 / median step``, rounded to 9 significant digits. At
least 64 rows. Only time differences are used: ``time_s`` may start anywhere.

**Parameters** (beside the CSV, same stem: ``drive1.toml`` or ``drive1.json``, not both)::

    speed_mps = 15.0             # required, > 0: constant speed of the pass, m/s
    sensor_noise_std = 0.05      # optional, >= 0, m/s^2 per sample (default 0.05)
    start_m = 0.0                # optional: road distance of the first sample, m (default 0)

    [vehicle]                    # required: the vehicle's *estimated* half-car parameters, SI units
    sprung_mass = 750.0          # kg
    roll_inertia = 550.0         # kg m^2
    left_arm = 0.75              # m
    right_arm = 0.75             # m
    stiffness = 22000.0          # N/m
    damping = 1800.0             # N s/m

JSON: the same keys, ``{"speed_mps": 15.0, "vehicle": {"sprung_mass": 750.0, ...}}``. Every key of
``vehicle`` is required; unknown keys anywhere are an error (a misspelt key must not silently
fall back to a default). TOML needs Python >= 3.11 (``tomllib``); on 3.10 use JSON.

All drives must share the sample rate (to 1e-6 relative), ``speed_mps`` and ``start_m``: the
estimators relay signals on one common segment grid, so sample ``k`` of every drive must be the
same spot of the road. Trim the logs so that every drive starts at the same road position. Drives
of different length are **truncated to the shortest** (the report says so).

Every error is a :class:`~roadcollab.errors.ParameterError` whose message starts with the file's
path and, for CSV content, ``line N:`` (1-based; the header is line 1), and says what was expected
and what was found.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from .._validation import check_signal
from ..errors import ParameterError
from ..models.vehicle import HalfCarParameters

__all__ = [
    "CSV_COLUMNS", "MIN_ROWS", "UNIFORM_RTOL", "DEFAULT_SENSOR_NOISE_STD", "Drive", "read_drive_csv",
    "read_drive_params", "params_path_for", "load_drive", "load_drives", "write_drive_csv", "write_drive_params",
]

CSV_COLUMNS = ("time_s", "accel_left", "accel_right")
MIN_ROWS = 64
UNIFORM_RTOL = 1e-6
DEFAULT_SENSOR_NOISE_STD = 0.05
_VEHICLE_KEYS = tuple(f.name for f in fields(HalfCarParameters))
_VEHICLE_UNITS = {"sprung_mass": "kg", "roll_inertia": "kg m^2", "left_arm": "m", "right_arm": "m",
                  "stiffness": "N/m", "damping": "N s/m"}
_TOP_KEYS = ("speed_mps", "vehicle", "sensor_noise_std", "start_m")
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


def _read_text(path: Path, what: str) -> str:
    if not path.is_file():
        raise ParameterError(f"{path}: {what} not found (expected an existing file)")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise ParameterError(f"{path}: expected a UTF-8 text file, got undecodable bytes ({err.reason} at byte "
                             f"{err.start})") from None
    except OSError as err:
        raise ParameterError(f"{path}: cannot read {what}: {err.strerror or err}") from None


def _parse_number(path: Path, lineno: int, col: int, text: str) -> float:
    name = CSV_COLUMNS[col]
    s = text.strip()
    if not s:
        raise ParameterError(f"{path} line {lineno}: column {col + 1} ({name}): expected a number, got an empty field")
    try:
        v = float(s)
    except ValueError:
        raise ParameterError(f"{path} line {lineno}: column {col + 1} ({name}): expected a number, got {s!r}") from None
    if not math.isfinite(v):
        raise ParameterError(f"{path} line {lineno}: column {col + 1} ({name}): expected a finite number, got {s!r}")
    return v


def _looks_numeric(fields_: list[str]) -> bool:
    try:
        [float(f) for f in fields_]
    except ValueError:
        return False
    return True


def read_drive_csv(path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read and validate a drive's acceleration log (format in the module docstring).

    Parameters
    ----------
    path : str or Path

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
    ParameterError
        ``"<path> line N: ..."`` for bad content, ``"<path>: ..."`` otherwise.
    """
    path = Path(path)
    lines = _read_text(path, "drive CSV").splitlines()
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    if not numbered:
        raise ParameterError(f"{path} line 1: expected the header '{_HEADER_TEXT}', got an empty file")
    _check_header(path, *numbered[0])
    rows = numbered[1:]
    data = np.empty((len(rows), 3))
    for r, (lineno, ln) in enumerate(rows):
        parts = ln.split(",")
        if len(parts) != 3:
            raise ParameterError(f"{path} line {lineno}: expected 3 numbers '{', '.join(CSV_COLUMNS)}', "
                                 f"got {len(parts)}")
        for c, text in enumerate(parts):
            data[r, c] = _parse_number(path, lineno, c, text)
    if len(rows) < MIN_ROWS:
        raise ParameterError(f"{path}: expected at least {MIN_ROWS} data rows after the header, got {len(rows)}")
    t = data[:, 0]
    step = _uniform_step(path, [lineno for lineno, _ in rows], t)
    sample_rate = float(f"{1.0 / step:.9g}")
    return t.copy(), data[:, 1:].copy(), sample_rate


def _check_header(path: Path, head_no: int, head: str) -> None:
    """Raise a ParameterError saying how the header line ``head`` differs from :data:`CSV_COLUMNS`."""
    names = [f.strip() for f in head.split(",")]
    if names == list(CSV_COLUMNS):
        return
    if len(names) == 3 and _looks_numeric(names):
        detail = "a row of numbers (the header line is required)"
    elif len(names) != 3:
        detail = f"{len(names)} column name(s) {head.strip()!r}"
    else:
        bad = next(i for i, (a, b) in enumerate(zip(names, CSV_COLUMNS)) if a != b)
        detail = f"{head.strip()!r} (column {bad + 1} is {names[bad]!r}, expected {CSV_COLUMNS[bad]!r})"
    raise ParameterError(f"{path} line {head_no}: expected the header '{_HEADER_TEXT}', got {detail}")


def _uniform_step(path: Path, linenos: list[int], t: np.ndarray) -> float:
    """The median time step (s) of ``t``; a ParameterError naming the line if ``t`` is not increasing and uniform."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0])
        raise ParameterError(f"{path} line {linenos[k + 1]}: expected time_s to increase, got {float(t[k + 1])!r} "
                             f"after {float(t[k])!r} on line {linenos[k]}")
    step = float(np.median(dt))
    bad = np.flatnonzero(np.abs(dt - step) > UNIFORM_RTOL * step)
    if bad.size:
        k = int(bad[0])
        raise ParameterError(f"{path} line {linenos[k + 1]}: expected uniform sampling (every time step within "
                             f"{UNIFORM_RTOL:g} relative of the median step {step:.9g} s), got a step of "
                             f"{dt[k]:.9g} s from time_s {float(t[k])!r} on line {linenos[k]}; resample the log")
    return step


def params_path_for(csv_path) -> Path:
    """The parameters file beside ``csv_path``: same stem, ``.toml`` or ``.json`` (exactly one)."""
    csv_path = Path(csv_path)
    candidates = [csv_path.with_suffix(s) for s in (".toml", ".json")]
    found = [p for p in candidates if p.is_file()]
    if not found:
        raise ParameterError(f"{csv_path}: parameters file not found: expected {candidates[0]} or {candidates[1]} "
                             "beside the CSV (speed_mps and the [vehicle] parameters)")
    if len(found) > 1:
        raise ParameterError(f"{csv_path}: ambiguous parameters: both {found[0]} and {found[1]} exist; keep one")
    return found[0]


def _load_mapping(path: Path) -> dict:
    text = _read_text(path, "parameters file")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:  # tomllib is in the standard library only from Python 3.11: import it where TOML is read
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            raise ParameterError(f"{path}: reading TOML needs Python >= 3.11 (tomllib); write the parameters as "
                                 f"JSON in {path.with_suffix('.json')} instead") from None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise ParameterError(f"{path}: expected valid TOML, got a syntax error: {err}") from None
    elif suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise ParameterError(f"{path} line {err.lineno}: expected valid JSON, got a syntax error: {err.msg} "
                                 f"(column {err.colno})") from None
        if not isinstance(data, dict):
            raise ParameterError(f"{path}: expected a JSON object {{\"speed_mps\": ..., \"vehicle\": {{...}}}}, "
                                 f"got a {type(data).__name__}")
    else:
        raise ParameterError(f"{path}: expected a .toml or .json parameters file, got suffix {path.suffix!r}")
    return data


def _number(path: Path, key: str, value, *, low: float | None = None, low_open: bool = False,
            unit: str = "") -> float:
    unit_s = f" ({unit})" if unit else ""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{path}: key '{key}' must be a number{unit_s}, got {value!r} ({type(value).__name__})")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{path}: key '{key}' must be a finite number{unit_s}, got {v!r}")
    if low is not None and (v < low or (low_open and v == low)):
        op = ">" if low_open else ">="
        raise ParameterError(f"{path}: key '{key}' must be {op} {low:g}{unit_s}, got {v:g}")
    return v


def _check_keys(path: Path, mapping: dict, allowed: tuple[str, ...], required: tuple[str, ...], where: str) -> None:
    unknown = [k for k in mapping if k not in allowed]
    if unknown:
        raise ParameterError(f"{path}: unknown key(s) {', '.join(repr(where + k) for k in unknown)}; expected only "
                             f"{', '.join(where + k for k in allowed)}")
    missing = [k for k in required if k not in mapping]
    if missing:
        raise ParameterError(f"{path}: missing required key(s) {', '.join(repr(where + k) for k in missing)}")


def read_drive_params(path) -> dict:
    """Read and validate a drive's parameters file (TOML or JSON, keys in the module docstring).

    Returns
    -------
    dict
        ``speed`` (m/s), ``sensor_noise_std`` (m/s^2), ``start_m`` (m), ``params``
        (:class:`~roadcollab.models.vehicle.HalfCarParameters`).
    """
    path = Path(path)
    data = _load_mapping(path)
    _check_keys(path, data, _TOP_KEYS, ("speed_mps", "vehicle"), "")
    speed = _number(path, "speed_mps", data["speed_mps"], low=0.0, low_open=True, unit="m/s")
    noise = _number(path, "sensor_noise_std", data.get("sensor_noise_std", DEFAULT_SENSOR_NOISE_STD), low=0.0,
                    unit="m/s^2")
    start = _number(path, "start_m", data.get("start_m", 0.0), unit="m")
    veh = data["vehicle"]
    if not isinstance(veh, dict):
        raise ParameterError(f"{path}: key 'vehicle' must be a table ([vehicle] in TOML, an object in JSON) of "
                             f"{', '.join(_VEHICLE_KEYS)}, got {veh!r} ({type(veh).__name__})")
    _check_keys(path, veh, _VEHICLE_KEYS, _VEHICLE_KEYS, "vehicle.")
    values = {k: _number(path, f"vehicle.{k}", veh[k], low=0.0, low_open=True, unit=_VEHICLE_UNITS[k])
              for k in _VEHICLE_KEYS}
    return {"speed": speed, "sensor_noise_std": noise, "start_m": start, "params": HalfCarParameters(**values)}


def load_drive(csv_path, params_path=None) -> Drive:
    """Read one drive: the CSV and its parameters file (default: :func:`params_path_for`)."""
    csv_path = Path(csv_path)
    if csv_path.suffix.lower() in (".toml", ".json"):
        raise ParameterError(f"{csv_path}: expected the drive's acceleration CSV here (its parameters file is "
                             f"found beside it), got a parameters file")
    t, accel, fs = read_drive_csv(csv_path)
    params_path = params_path_for(csv_path) if params_path is None else Path(params_path)
    p = read_drive_params(params_path)
    return Drive(csv_path=csv_path, params_path=params_path, time=t, accel=accel, sample_rate=fs, speed=p["speed"],
                 start_m=p["start_m"], sensor_noise_std=p["sensor_noise_std"], params=p["params"])


def load_drives(paths) -> list[Drive]:
    """Read every drive and check that they share one segment grid.

    Sample rates must agree to 1e-6 relative, ``speed_mps`` and ``start_m`` to 1e-9 relative;
    the error names the drive that differs from the first.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ParameterError("expected at least one drive (--drive FILE), got none")
    drives = [load_drive(p) for p in paths]
    d0 = drives[0]
    for d in drives[1:]:
        if abs(d.sample_rate - d0.sample_rate) > UNIFORM_RTOL * d0.sample_rate:
            raise ParameterError(f"{d.csv_path}: expected the sample rate of {d0.csv_path} ({d0.sample_rate:.9g} Hz), "
                                 f"got {d.sample_rate:.9g} Hz; all drives must share one sample rate (resample the "
                                 "log)")
        if abs(d.speed - d0.speed) > 1e-9 * d0.speed:
            raise ParameterError(f"{d.params_path}: expected speed_mps = {d0.speed:g} as in {d0.params_path}, got "
                                 f"{d.speed:g}; all drives must share one speed (one segment grid)")
        if abs(d.start_m - d0.start_m) > 1e-9 * max(1.0, abs(d0.start_m)):
            raise ParameterError(f"{d.params_path}: expected start_m = {d0.start_m:g} as in {d0.params_path}, got "
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


def write_drive_params(path, *, speed: float, params: HalfCarParameters, sensor_noise_std: float | None = None,
                       start_m: float | None = None) -> Path:
    """Write a parameters file (``.toml`` or ``.json`` by suffix), full precision.

    Values are not validated here; :func:`read_drive_params` checks them.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten); the suffix ``.toml`` or ``.json`` (any case) picks the format.
    speed : float
        ``speed_mps``, m/s.
    params : HalfCarParameters
        The vehicle's estimated parameters, written as the ``vehicle`` table (SI units).
    sensor_noise_std : float, optional
        m/s^2; the key is omitted if None (readers then use 0.05).
    start_m : float, optional
        Road distance of the first sample, m; the key is omitted if None (readers then use 0).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        If the suffix is neither ``.toml`` nor ``.json`` (nothing is written).
    """
    path = Path(path)
    top = {"speed_mps": float(speed)}
    if sensor_noise_std is not None:
        top["sensor_noise_std"] = float(sensor_noise_std)
    if start_m is not None:
        top["start_m"] = float(start_m)
    veh = {k: float(v) for k, v in params.as_dict().items()}
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps({**top, "vehicle": veh}, indent=2) + "\n")
    elif path.suffix.lower() == ".toml":
        lines = [f"{k} = {v!r}" for k, v in top.items()] + ["", "[vehicle]"] + [f"{k} = {v!r}" for k, v in veh.items()]
        path.write_text("\n".join(lines) + "\n")
    else:
        raise ParameterError(f"{path}: expected a .toml or .json suffix, got {path.suffix!r}")
    return path
