"""Recorded drives: reading and writing the acceleration logs and their parameters files.

Each drive is one vehicle's pass over the same road segment; drives are taken in the order
given (vehicle 1 first). This module reads and validates the logs (:func:`load_drives`) and writes
them (:func:`write_drive_csv`, :func:`write_drive_params`); the estimation is
:mod:`roadcollab.experiments.drives.estimation`, the command ``roadcollab estimate`` is
:mod:`roadcollab.cli.estimate`.

File formats
------------
**Accelerations** (``drive1.csv``): a header line ``time_s,accel_left,accel_right`` (exactly these
names; spaces around them are ignored), optionally followed by ``,speed_mps`` (the vehicle's speed
per sample, 0.5-70 m/s) or ``,distance_m`` (an odometer reading per sample, m, increasing), then one
row per sample of finite numbers: time in s and the left and right body-tip vertical accelerations
in m/s^2 (or g with ``accel_unit = "g"``; and the fourth column). Blank lines are ignored. Numbers are plain ASCII decimals
(``nan``, ``inf``, ``1_000`` and other scripts' digits are refused); an acceleration beyond
+-200 m/s^2 is a logger glitch and refused with its line. Time stamps (:mod:`roadcollab.io.drive_log`):
uniform ones (every step within 1e-6 of the median) are used as logged, jittery ones are resampled
onto a uniform grid at the mean rate with a cubic interpolating spline; a clock step (time not
increasing) and a gap (a step above 3x the median) are refused with the line. The sample rate is
at most 10 kHz and at least ``max(20 Hz, 10 x the highest body mode of the [vehicle] model)``:
a slower log cannot resolve the suspension's response and is refused with that reason. At least 64 rows, at most 2,000,000 and 200 MB (:class:`~roadcollab.io.limits.FileLimits`;
``--max-rows`` and ``--max-file-mb`` raise them; the size is checked before reading). Only time
differences are used: ``time_s`` may start anywhere.

**Parameters** (beside the CSV, same stem: ``drive1.toml`` or ``drive1.json``, not both)::

    speed_mps = 15.0             # 0.5-70: constant speed of the pass, m/s; required unless the CSV
                                 # has a speed_mps or distance_m column (then it must be absent)
    sensor_noise_std = 0.05      # optional, 0-20, m/s^2 per sample (default 0.05)
    start_m = 0.0                # optional, +-1e7: road distance of the first sample, m (default 0)
    accel_unit = "m/s^2"         # optional, "m/s^2" (default) or "g" (9.80665 m/s^2): unit of the CSV's
                                 # accel_left and accel_right; anything else is refused
    vehicle_id = "van-07"        # optional, 1-64 of A-Z a-z 0-9 . _ -: the vehicle that recorded the drive,
                                 # the same in all of its drives (map's per-vehicle IRI calibration)

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

Road position of sample ``k`` (:attr:`Drive.positions`): ``start_m + speed_mps * k / rate`` with a
constant speed; ``start_m`` + the trapezoidal integral of the ``speed_mps`` column; or
``start_m + distance_m[k] - distance_m[0]``. Drives may differ in speed, sample rate, start and
length: :func:`common_time_grid` says whether they share one time grid (then
:func:`roadcollab.experiments.drives.estimation.estimate_drives` relays them in time, as the
simulations do); otherwise :mod:`roadcollab.experiments.drives.fleet_estimation` works on road distance.

Every error is a :class:`~roadcollab.errors.FileFormatError` (a ``ParameterError``) whose message
starts with the file's
path and, for CSV content, ``line N:`` (1-based; the header is line 1), and says what was expected
and what was found.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import check_signal
from ..errors import FileFormatError, ParameterError
from ..models.vehicle import HalfCarParameters, half_car_model
from .drive_log import CSV_COLUMNS, MAX_SAMPLE_RATE, MIN_ROWS, OPTIONAL_COLUMNS, UNIFORM_RTOL, DriveLog, read_drive_log
from .drive_params import ACCEL_UNITS, params_path_for, read_drive_params
from .gps import GpsFixes, read_gps_log
from .limits import MAX_ACCEL, FileLimits

__all__ = ["CSV_COLUMNS", "MIN_ROWS", "MAX_SAMPLE_RATE", "UNIFORM_RTOL", "MIN_SAMPLE_RATE", "MODE_FACTOR", "Drive",
           "read_drive_csv", "body_mode_hz", "load_drive", "load_drives", "common_time_grid", "write_drive_csv"]

MIN_SAMPLE_RATE = 20.0   # Hz: never below, whatever the vehicle
MODE_FACTOR = 10.0       # the sample rate must be at least 10x the highest body mode
_HEADER_TEXT = ",".join(CSV_COLUMNS)


# --- reading -------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Drive:
    """One recorded pass, validated.

    Attributes
    ----------
    csv_path, params_path : Path
    time : (N,) ndarray
        Uniform time stamps, s (``time_s`` as logged, or the resampling grid).
    accel : (N, 2) ndarray
        Left and right body-tip accelerations, m/s^2.
    sample_rate : float
        Hz.
    speed : float
        The constant ``speed_mps`` of the parameters file, or the mean speed of the log, m/s.
    start_m : float
        Road distance of the first sample, m.
    sensor_noise_std : float
        m/s^2.
    params : HalfCarParameters
        The vehicle's estimated parameters.
    positions : (N,) ndarray
        Road distance of every sample, m (module docstring).
    speed_source : str
        ``"parameters"``, ``"speed_mps column"`` or ``"distance_m column"``.
    resampled : bool
        True if jittery time stamps were resampled (:mod:`roadcollab.io.drive_log`).
    max_jitter : float
        Largest relative deviation of a logged time step from the median step.
    accel_unit : str
        The ``accel_unit`` of the parameters file; ``accel`` is in m/s^2 whatever it is.
    gps : GpsFixes or None
        The ``lat_deg, lon_deg`` fixes of the log, if it has them (:mod:`roadcollab.io.gps`).
    vehicle_id : str or None
        The ``vehicle_id`` of the parameters file: drives with the same one were recorded by one vehicle.
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
    positions: np.ndarray
    speed_source: str = "parameters"
    resampled: bool = False
    max_jitter: float = 0.0
    accel_unit: str = "m/s^2"
    gps: GpsFixes | None = None
    vehicle_id: str | None = None

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.accel.shape[0])

    @property
    def constant_speed(self) -> bool:
        """True if the speed is the constant ``speed_mps`` of the parameters file."""
        return self.speed_source == "parameters"

    def speeds(self) -> np.ndarray:
        """(N,) ndarray: speed at every sample, m/s (``gradient(positions) * sample_rate``)."""
        return np.gradient(self.positions) * self.sample_rate

    def describe(self) -> dict:
        """JSON-ready description (no signals)."""
        v = self.speeds()
        return {"csv": str(self.csv_path), "params_file": str(self.params_path), "n_samples": self.n_samples,
                "sample_rate_hz": self.sample_rate, "speed_mps": self.speed, "speed_source": self.speed_source,
                "speed_min_mps": float(v.min()), "speed_max_mps": float(v.max()), "start_m": self.start_m,
                "end_m": float(self.positions[-1]), "resampled": self.resampled, "max_jitter": self.max_jitter,
                "accel_unit": self.accel_unit, "sensor_noise_std": self.sensor_noise_std, "vehicle": self.params.as_dict()}


def read_drive_csv(path, *, limits: FileLimits | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Read and validate a drive's acceleration log (format in the module docstring).

    Jittery time stamps are resampled (:func:`roadcollab.io.drive_log.read_drive_log`); a
    ``speed_mps`` or ``distance_m`` column is read but not returned here.

    Parameters
    ----------
    path : str or Path
    limits : FileLimits, optional
        Largest file (MB, checked before reading) and most data rows; default ``FileLimits()``.

    Returns
    -------
    time : (N,) ndarray
        Uniform time stamps, s.
    accel : (N, 2) ndarray
        m/s^2, columns ``[left, right]``.
    sample_rate : float
        Hz.

    Raises
    ------
    FileFormatError
        ``"<path> line N: ..."`` for bad content, ``"<path>: ..."`` otherwise.
    """
    log = read_drive_log(path, limits=limits)
    return log.time, log.accel, log.sample_rate


def body_mode_hz(params: HalfCarParameters) -> float:
    """Highest natural frequency of the half-car's body modes (heave, roll), Hz.

    Parameters
    ----------
    params : HalfCarParameters

    Returns
    -------
    float
        ``max |lambda| / (2 pi)`` over the poles of :func:`~roadcollab.models.vehicle.half_car_model`.
    """
    return float(np.max(np.abs(half_car_model(params).poles())) / (2 * np.pi))


def _positions(log: DriveLog, speed: float | None, start: float) -> np.ndarray:
    """Road distance of every sample (module docstring), m."""
    if log.column == "distance_m" and log.values is not None:
        return start + (log.values - log.values[0])
    if log.column == "speed_mps" and log.values is not None:
        v = log.values
        return start + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]) / log.sample_rate
    if speed is None:     # read_drive_params requires speed_mps when the log has neither column
        raise ParameterError("a drive log without a speed_mps or distance_m column needs speed_mps in its "
                             "parameters file")
    return start + speed * np.arange(log.time.shape[0]) / log.sample_rate


def _check_rate(log: DriveLog, csv_path: Path, params_path: Path, params: HalfCarParameters) -> None:
    """Refuse a sample rate below ``max(MIN_SAMPLE_RATE, MODE_FACTOR x body mode)`` with the reason."""
    mode = body_mode_hz(params)
    need = max(MIN_SAMPLE_RATE, MODE_FACTOR * mode)
    if log.sample_rate < need:
        raise FileFormatError(f"{csv_path}: expected a sample rate of at least {need:.4g} Hz (the larger of "
                              f"{MIN_SAMPLE_RATE:g} Hz and {MODE_FACTOR:g}x the highest body mode, {mode:.3g} Hz, "
                              f"of the vehicle in {params_path.name}), got {log.sample_rate:.6g} Hz: the log cannot "
                              "resolve the suspension's response")


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

    Raises
    ------
    FileFormatError
        A bad CSV or parameters file, ``speed_mps`` both in the parameters and as a column (or in
        neither), or a sample rate too low for the vehicle.
    """
    csv_path = Path(csv_path)
    if csv_path.suffix.lower() in (".toml", ".json"):
        raise FileFormatError(f"{csv_path}: expected the drive's acceleration CSV here (its parameters file is "
                             f"found beside it), got a parameters file")
    log, gps = read_gps_log(csv_path, limits=limits)
    params_path = params_path_for(csv_path) if params_path is None else Path(params_path)
    p = read_drive_params(params_path, speed_column=log.column)
    _check_rate(log, csv_path, params_path, p["params"])
    accel = log.accel * ACCEL_UNITS[p["accel_unit"]]
    if p["accel_unit"] != "m/s^2" and np.max(np.abs(accel)) > MAX_ACCEL:
        k = int(np.argmax(np.max(np.abs(accel), axis=1)))
        raise FileFormatError(f"{csv_path}: expected accelerations within +-{MAX_ACCEL:g} m/s^2 (beyond it a sample "
                              f"is a logger glitch), got {float(np.max(np.abs(accel[k]))):.6g} m/s^2 at sample {k + 1} "
                              f"(accel_unit = {p['accel_unit']!r} in {params_path.name})")
    positions = _positions(log, p["speed"], p["start_m"])
    duration = (log.time.shape[0] - 1) / log.sample_rate
    speed = p["speed"] if log.column is None else float((positions[-1] - positions[0]) / duration)
    source = "parameters" if log.column is None else f"{log.column} column"
    return Drive(csv_path=csv_path, params_path=params_path, time=log.time, accel=accel,
                 sample_rate=log.sample_rate, speed=speed, start_m=p["start_m"],
                 sensor_noise_std=p["sensor_noise_std"], params=p["params"], positions=positions,
                 speed_source=source, resampled=log.resampled, max_jitter=log.max_jitter,
                 accel_unit=p["accel_unit"], gps=gps, vehicle_id=p["vehicle_id"])


def load_drives(paths, *, limits: FileLimits | None = None) -> list[Drive]:
    """Read every drive (they may differ in speed, sample rate, start and length).

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
    return [load_drive(p, limits=limits) for p in paths]


def common_time_grid(drives: list[Drive]) -> bool:
    """True if the drives share one time grid: constant speeds (parameters files), sample rates to
    1e-6 relative, speeds to 1e-9 relative and ``start_m`` to 1e-9 relative (sample ``k`` of every
    drive is then the same spot of the road).

    Parameters
    ----------
    drives : list of Drive

    Returns
    -------
    bool
    """
    d0 = drives[0]
    return all(d.constant_speed and abs(d.sample_rate - d0.sample_rate) <= UNIFORM_RTOL * d0.sample_rate
               and abs(d.speed - d0.speed) <= 1e-9 * d0.speed
               and abs(d.start_m - d0.start_m) <= 1e-9 * max(1.0, abs(d0.start_m)) for d in drives)

# --- writing -------------------------------------------------------------------------------------

def write_drive_csv(path, time, accel, *, column: str | None = None, values=None) -> Path:
    """Write a drive CSV in the documented format, full precision (``repr`` floats).

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    time : (N,) array_like
        ``time_s`` column, s (the clock is not checked here; :func:`read_drive_csv` checks it).
    accel : (N, 2) array_like
        Left and right body-tip vertical accelerations, m/s^2, finite.
    column : {"speed_mps", "distance_m"} or None
        Name of an optional fourth column.
    values : (N,) array_like, optional
        Its values (m/s or m); required with ``column``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        If ``accel`` is not a finite (N, 2) array, ``time`` or ``values`` does not have shape (N,), or
        ``column`` is not one of the optional columns.
    """
    time = np.asarray(time, dtype=float)
    accel = check_signal("accel", accel, 2)
    if time.shape != (accel.shape[0],):
        raise ParameterError(f"time must have shape ({accel.shape[0]},), got {time.shape}")
    cols = [time, accel[:, 0], accel[:, 1]]
    header = _HEADER_TEXT
    if column is not None:
        if column not in OPTIONAL_COLUMNS or values is None or np.shape(values) != time.shape:
            raise ParameterError(f"column must be one of {OPTIONAL_COLUMNS} with values of shape {time.shape}, got "
                                 f"{column!r} and {None if values is None else np.shape(values)}")
        cols.append(np.asarray(values, dtype=float))
        header += f",{column}"
    lines = [header] + [",".join(repr(float(v)) for v in row) for row in zip(*cols)]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
