"""Estimation from recorded drives: ``roadcollab estimate --drive FILE [--drive FILE ...] --out DIR``.

Each drive is one vehicle's pass over the same road segment; drives are taken in the order
given (vehicle 1 first). This module reads the logs, runs Algorithm 1 down the drives exactly as
the in-memory pipeline (:func:`roadcollab.experiments.reproduction.run_estimates`) does, integrates elevations,
looks for anomalies and writes CSV files, figures, ``config.json`` and ``report.md``.

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

Processing
----------
* The estimators are designed (Lemma 1) as in the simulations, by
  ``ExperimentConfig(speed=..., sample_rate=..., sensor_noise_std=...).noise_model()``: an ISO 8608
  class C road with the default pothole statistics at the drives' speed and the drive's sensor
  noise. Real roads differ; the design is a prior, not a fit.
* One :class:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator` per drive with
  ``Vehicle(index=j, true_params=p, estimated_params=p)`` (the true parameters of a real car are
  unknown; only the estimated ones are used, ``oracle=False``), observer gamma and band edge from
  the :class:`~roadcollab.experiments.reproduction.ExperimentConfig` defaults (512, 0.5 Hz), on
  ``SegmentGrid(n_samples, sample_rate, band_low_hz=0.5)``.
* Per drive ``k``: ``single`` = the vehicle's own observer ``D_k y_k``; ``collaborative`` =
  Algorithm 1 with the message of drive ``k - 1`` (drive 1: the observer only, so equal to
  ``single``); ``fused`` = the running average of the band-limited inversions ``z`` of drives
  1..k (:meth:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator.fused_message`).
* Every road-velocity output is band-limited by the grid's band weight ``W`` exactly as
  :func:`~roadcollab.experiments.reproduction.run_estimates` does (DC and everything well below 0.5 Hz is
  invisible to accelerometers and is not estimated).
* Elevation: :func:`integrate_elevation` of the band-limited road velocity, mean removed. It is
  defined only up to a slow drift: wavelengths above ``speed / 0.5 Hz`` (30 m at 15 m/s) are not
  observed.
* Anomalies: :func:`roadcollab.detection.detector.detect_anomalies` on every band-limited estimate of every
  drive (:func:`find_anomalies`).

The offline filters act on a finite window: the first and last second or so of every estimate
carry window-edge effects (the simulations record a 15 m lead-in and lead-out for this reason);
log a little more road than the stretch of interest.
"""

from __future__ import annotations

import json
import math
import time as _time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from .._validation import check_signal
from ..errors import ParameterError
from ..models.vehicle import HalfCarParameters, Vehicle

__all__ = [
    "CSV_COLUMNS", "MIN_ROWS", "ESTIMATORS", "Drive", "DriveEstimates", "read_drive_csv", "read_drive_params",
    "params_path_for", "load_drive", "load_drives", "estimate_drives", "integrate_elevation", "find_anomalies",
    "write_drive_csv", "write_drive_params", "write_estimates", "estimate_command", "add_estimate_arguments",
]

CSV_COLUMNS = ("time_s", "accel_left", "accel_right")
MIN_ROWS = 64
UNIFORM_RTOL = 1e-6
ESTIMATORS = ("single", "collaborative", "fused")
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
    head_no, head = numbered[0]
    names = [f.strip() for f in head.split(",")]
    if names != list(CSV_COLUMNS):
        if len(names) == 3 and _looks_numeric(names):
            detail = "a row of numbers (the header line is required)"
        elif len(names) != 3:
            detail = f"{len(names)} column name(s) {head.strip()!r}"
        else:
            bad = next(i for i, (a, b) in enumerate(zip(names, CSV_COLUMNS)) if a != b)
            detail = f"{head.strip()!r} (column {bad + 1} is {names[bad]!r}, expected {CSV_COLUMNS[bad]!r})"
        raise ParameterError(f"{path} line {head_no}: expected the header '{_HEADER_TEXT}', got {detail}")
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
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0])
        raise ParameterError(f"{path} line {rows[k + 1][0]}: expected time_s to increase, got {float(t[k + 1])!r} "
                             f"after {float(t[k])!r} on line {rows[k][0]}")
    step = float(np.median(dt))
    bad = np.flatnonzero(np.abs(dt - step) > UNIFORM_RTOL * step)
    if bad.size:
        k = int(bad[0])
        raise ParameterError(f"{path} line {rows[k + 1][0]}: expected uniform sampling (every time step within "
                             f"{UNIFORM_RTOL:g} relative of the median step {step:.9g} s), got a step of "
                             f"{dt[k]:.9g} s from time_s {float(t[k])!r} on line {rows[k][0]}; resample the log")
    sample_rate = float(f"{1.0 / step:.9g}")
    return t.copy(), data[:, 1:].copy(), sample_rate


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
        try:
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


# --- processing ----------------------------------------------------------------------------------

def integrate_elevation(w, sample_rate: float) -> np.ndarray:
    """Elevation (m) from road velocity (m/s), mean removed.

    The road velocity is taken as constant over each sample interval (the convention of
    :class:`roadcollab.models.road.TimeRoad` and of the ZOH-exact simulation), so the elevation at the
    *start* of sample ``k`` is ``h[k] = sum_{i<k} w[i] / sample_rate`` exactly (``h[0] = 0``). The
    mean over the window is then removed: the integration constant is unknown, and for a
    band-limited velocity the elevation is defined only up to a slow drift (wavelengths above
    ``speed / band_low_hz`` are not observed).

    Parameters
    ----------
    w : (N, C) array_like
    sample_rate : float
        Hz.

    Returns
    -------
    (N, C) ndarray
    """
    from .._validation import check_positive

    w = check_signal("w", w)
    fs = check_positive("sample_rate", sample_rate)
    h = np.zeros_like(w)
    h[1:] = np.cumsum(w[:-1], axis=0) / fs
    return h - h.mean(axis=0)


@dataclass(frozen=True, eq=False)
class DriveEstimates:
    """Estimates of every drive on the common window.

    Attributes
    ----------
    drives : list of Drive
    sample_rate, speed, start_m : float
        Hz, m/s, m.
    n_samples : int
        Common window length (the shortest drive).
    time : (n,) ndarray
        ``k / sample_rate``, s (time since each drive's first sample).
    positions : (n,) ndarray
        ``start_m + speed * time``, m.
    velocity, elevation : dict
        ``{estimator: (V, n, 2) ndarray}`` for estimator in :data:`ESTIMATORS`: band-limited road
        velocity (m/s) and its elevation (m), columns ``[left, right]``.
    gamma, band_low_hz : float
        Observer parameter and band edge used.
    """

    drives: list
    sample_rate: float
    speed: float
    start_m: float
    n_samples: int
    time: np.ndarray
    positions: np.ndarray
    velocity: dict
    elevation: dict
    gamma: float
    band_low_hz: float

    @property
    def truncated(self) -> bool:
        return any(d.n_samples > self.n_samples for d in self.drives)


def estimate_drives(drives: list[Drive], *, gamma: float | None = None, band_low_hz: float | None = None
                    ) -> DriveEstimates:
    """Run the single-vehicle, collaborative (Algorithm 1) and fused estimators down the drives.

    Relays through the same engine as :func:`roadcollab.experiments.reproduction.run_estimates`
    (:class:`roadcollab.collaboration.relay.Relay`, same estimator design, grid and band limiting), so
    simulated drives give the in-memory estimates.

    Parameters
    ----------
    drives : list of Drive
        In driving order, sharing sample rate, speed and start (see :func:`load_drives`).
    gamma, band_low_hz : float, optional
        Default: the :class:`~roadcollab.experiments.reproduction.ExperimentConfig` defaults (512, 0.5 Hz).
    """
    from ..collaboration.algorithm1 import CollaborativeEstimator
    from ..experiments.reproduction import ExperimentConfig
    from ..collaboration.relay import Relay
    from ..estimation.grid import SegmentGrid

    if not drives or not all(isinstance(d, Drive) for d in drives):
        raise ParameterError("drives must be a non-empty list of Drive (see load_drives)")
    d0 = drives[0]
    base = ExperimentConfig()
    gamma = base.gamma if gamma is None else gamma
    band_low_hz = base.band_low_hz if band_low_hz is None else band_low_hz
    fs, speed = d0.sample_rate, d0.speed
    if not band_low_hz < fs / 2:
        raise ParameterError(f"{d0.csv_path}: expected a sample rate above {2 * band_low_hz:g} Hz (twice the "
                             f"{band_low_hz:g} Hz band edge), got {fs:.9g} Hz")
    n = min(d.n_samples for d in drives)
    grid = SegmentGrid(n, fs, band_low_hz=band_low_hz)
    Wgt = grid.weight[:, None]

    def band(X):
        return grid.irfft(Wgt * X, n)

    noise_models: dict[float, object] = {}
    cars = []
    for j, d in enumerate(drives):
        if d.sensor_noise_std not in noise_models:
            try:
                cfg = ExperimentConfig(speed=speed, sample_rate=fs, sensor_noise_std=d.sensor_noise_std,
                                       gamma=gamma, band_low_hz=band_low_hz)
            except ParameterError as err:
                raise ParameterError(f"{d.params_path}: {err}") from None
            noise_models[d.sensor_noise_std] = cfg.noise_model()
        vehicle = Vehicle(index=j, true_params=d.params, estimated_params=d.params)
        cars.append(CollaborativeEstimator(vehicle, noise_models[d.sensor_noise_std], grid, gamma=gamma))
    ys = [d.accel[:n] for d in drives]
    Ys = [grid.rfft(y) for y in ys]
    plain = Relay(cars, "none").run(ys, spectra=Ys)
    fused = Relay(cars, "fused").run(ys, spectra=Ys)
    out = {"single": [band(s.result.W_obs) for s in plain],
           "collaborative": [band(s.result.W_hat) for s in plain],
           "fused": [band(s.estimate_spectrum) for s in fused]}
    velocity = {k: np.array(v) for k, v in out.items()}
    elevation = {k: np.array([integrate_elevation(x, fs) for x in v]) for k, v in velocity.items()}
    t = np.arange(n) / fs
    return DriveEstimates(drives=list(drives), sample_rate=fs, speed=speed, start_m=d0.start_m, n_samples=n, time=t,
                          positions=d0.start_m + speed * t, velocity=velocity, elevation=elevation, gamma=float(gamma),
                          band_low_hz=float(band_low_hz))


ANOMALY_COLUMNS = ["estimator", "vehicle", "position_m", "side", "kind", "depth_m", "confidence"]


def find_anomalies(est: DriveEstimates, spec=None) -> list[dict]:
    """Anomalies in every band-limited estimate of every drive.

    One call of :func:`roadcollab.detection.detector.detect_anomalies` per (estimator, drive).

    Returns
    -------
    list of dict
        Rows with :data:`ANOMALY_COLUMNS`: estimator, vehicle (1-based drive number), position_m
        (center), side, kind, depth_m, confidence.
    """
    from ..detection.detector import DetectorSpec, detect_anomalies

    spec = DetectorSpec() if spec is None else spec
    rows = []
    for name in ESTIMATORS:
        for j, w in enumerate(est.velocity[name]):
            for det in detect_anomalies(w, positions=est.positions, speed=est.speed, sample_rate=est.sample_rate,
                                        spec=spec):
                rows.append({"estimator": name, "vehicle": j + 1, "position_m": float(det.position),
                             "side": det.side, "kind": det.kind, "depth_m": float(det.depth),
                             "confidence": float(det.confidence)})
    return rows


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


def _estimate_rows(est: DriveEstimates) -> tuple[list[dict], list[str]]:
    cols = ["position_m", "time_s"]
    series = []
    for kind, data in (("w", est.velocity), ("elevation", est.elevation)):
        for j in range(len(est.drives)):
            for name in ESTIMATORS:
                for c, side in enumerate(("left", "right")):
                    cols.append(f"{kind}_{name}_v{j + 1}_{side}")
                    series.append(data[name][j, :, c])
    table = np.column_stack([est.positions, est.time] + series)
    rows = [dict(zip(cols, map(float, r))) for r in table]
    return rows, cols


def _final_rows(est: DriveEstimates) -> tuple[list[dict], list[str]]:
    cols = ["position_m", "time_s"]
    series = []
    for kind, data in (("w", est.velocity), ("elevation", est.elevation)):
        for name in ("collaborative", "fused"):
            for c, side in enumerate(("left", "right")):
                cols.append(f"{kind}_{name}_{side}")
                series.append(data[name][-1, :, c])
    table = np.column_stack([est.positions, est.time] + series)
    return [dict(zip(cols, map(float, r))) for r in table], cols


def _zoom_window(est: DriveEstimates, width_m: float = 20.0) -> tuple[float, float] | None:
    """A ``width_m`` stretch around the largest fused road velocity of the last drive (away from the
    window edges), for the figures' zoom column; None if the window is not much longer."""
    pos = est.positions
    length = pos[-1] - pos[0]
    if length < 3 * width_m:
        return None
    w = np.max(np.abs(est.velocity["fused"][-1]), axis=1)
    inner = (pos >= pos[0] + width_m) & (pos <= pos[-1] - width_m)
    center = float(pos[inner][np.argmax(w[inner])])
    return center - width_m / 2, center + width_m / 2


def write_estimates(est: DriveEstimates, out, *, command: str, anomalies: list[dict] | None,
                    anomaly_note: str | None = None, elapsed: float | None = None) -> dict:
    """Write every output of ``roadcollab estimate`` to the folder ``out``; returns the summary.

    Files: ``road_estimates.csv`` (wide: ``position_m, time_s``, then
    ``w_<estimator>_v<k>_<side>`` in m/s and ``elevation_<estimator>_v<k>_<side>`` in m for every
    drive ``k`` (1-based, driving order), estimator single/collaborative/fused and side left/right),
    ``final_estimate.csv`` (the last drive's collaborative and fused estimates:
    ``w_<estimator>_<side>``, ``elevation_<estimator>_<side>``), ``anomalies.csv``,
    ``road_velocity.png``, ``elevation.png``, ``config.json`` and ``report.md``.

    Parameters
    ----------
    est : DriveEstimates
        From :func:`estimate_drives`.
    out : str or Path
        Output folder (created with its parents if missing; files in it are overwritten).
    command : str
        The command line, recorded in ``config.json`` and ``report.md``.
    anomalies : list of dict or None
        Rows of :func:`find_anomalies` (:data:`ANOMALY_COLUMNS`); None if detection was not run
        (``anomalies.csv`` then holds the header only and the report says so).
    anomaly_note : str, optional
        Note for the report and ``config.json`` (e.g. why detection was not run).
    elapsed : float, optional
        Wall time of reading, estimating and detecting, s (recorded if given).

    Returns
    -------
    dict
        Summary: ``out_dir``, ``n_drives``, ``sample_rate_hz`` (Hz), ``speed_mps`` (m/s), ``start_m``
        (m), ``n_samples``, ``samples_per_drive``, ``truncated``, ``duration_s`` (s), ``length_m`` (m),
        ``n_anomalies`` (``{estimator: count}`` summed over drives; None if ``anomalies`` is None),
        ``notes`` and ``files``.
    """
    from ..reporting import plotting_drives
    from ..reporting.records import markdown_table, write_config, write_csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    V = len(est.drives)
    rows, cols = _estimate_rows(est)
    write_csv(out / "road_estimates.csv", rows, cols)
    rows, cols = _final_rows(est)
    write_csv(out / "final_estimate.csv", rows, cols)
    anomaly_rows = anomalies or []
    write_csv(out / "anomalies.csv", anomaly_rows, ANOMALY_COLUMNS)
    last = {name: est.velocity[name][-1] for name in ESTIMATORS}
    labels = {"single": f"single vehicle (drive {V})", "collaborative": f"collaborative, Algorithm 1 (drive {V})",
              "fused": f"fused (average of drives 1-{V})"}
    zoom = _zoom_window(est)
    plotting_drives.plot_tracks(est.positions, {labels[k]: v for k, v in last.items()}, out / "road_velocity.png",
                                ylabel="road velocity (m/s)", zoom=zoom,
                                title=f"Band-limited road-velocity estimates (from {est.band_low_hz:g} Hz)")
    plotting_drives.plot_tracks(est.positions, {labels[k]: est.elevation[k][-1] for k in ESTIMATORS},
                                out / "elevation.png", ylabel="elevation (m)", zoom=zoom,
                                title=f"Elevation estimates (mean removed; wavelengths above "
                                      f"{est.speed / est.band_low_hz:g} m not observed)")
    counts = {name: [sum(1 for r in anomaly_rows if r["estimator"] == name and r["vehicle"] == j + 1)
                     for j in range(V)] for name in ESTIMATORS}
    lengths = [d.n_samples for d in est.drives]
    notes = []
    if est.truncated:
        notes.append(f"Drives have {', '.join(map(str, lengths))} samples; all were truncated to the shortest, "
                     f"{est.n_samples} samples ({est.n_samples / est.sample_rate:.6g} s).")
    duration = est.n_samples / est.sample_rate
    if duration < 4.0 / est.band_low_hz:
        notes.append(f"The common window ({duration:.6g} s) is shorter than two periods of the {est.band_low_hz:g} Hz "
                     "band edge: the estimates are dominated by window-edge effects; log longer drives.")
    if anomaly_note:
        notes.append(anomaly_note)
    from ..experiments.reproduction import ExperimentConfig

    design = ExperimentConfig()
    config = {
        "drives": [d.describe() for d in est.drives],
        "sample_rate_hz": est.sample_rate, "speed_mps": est.speed, "start_m": est.start_m,
        "n_samples_used": est.n_samples, "truncated": est.truncated,
        "gamma": est.gamma, "band_low_hz": est.band_low_hz,
        "estimator_design": {"iso_class": design.iso_class, "anomaly_density": design.anomaly_density,
                             "note": "noise model of ExperimentConfig(speed, sample_rate, sensor_noise_std)"},
        "anomaly_detector": _detector_config(),
    }
    extra = {"notes": notes}
    if elapsed is not None:
        extra["elapsed_s"] = elapsed
    write_config(out / "config.json", command=command, seed=None, config=config, extra=extra)

    drive_rows = [{"drive": j + 1, "csv": d.csv_path.name, "params": d.params_path.name, "samples": d.n_samples,
                   "noise": d.sensor_noise_std, "m_b": d.params.sprung_mass, "I_x": d.params.roll_inertia,
                   "L1": d.params.left_arm, "L2": d.params.right_arm, "k_s": d.params.stiffness,
                   "c_s": d.params.damping} for j, d in enumerate(est.drives)]
    count_rows = [{"drive": j + 1, **{name: counts[name][j] for name in ESTIMATORS}} for j in range(V)]
    final = [r for r in anomaly_rows if r["vehicle"] == V and r["estimator"] in ("collaborative", "fused")]
    length = est.speed * est.n_samples / est.sample_rate
    lines = [
        "# roadcollab estimate: road input, elevation and anomalies from recorded drives",
        "",
        f"Command: `{command}`  ",
        f"{V} drive(s) in this order; {est.sample_rate:.9g} Hz; {est.speed:g} m/s; {est.n_samples} samples "
        f"({est.n_samples / est.sample_rate:.6g} s, road {est.start_m:g} to {est.start_m + length:.6g} m)"
        + (f"; read, estimated and searched in {elapsed:.1f} s." if elapsed is not None else "."),
        "",
    ]
    if notes:
        lines += ["**Notes.**", ""] + [f"- {n}" for n in notes] + [""]
    lines += [
        "## Inputs",
        "",
        "Estimated vehicle parameters (SI units: kg, kg m^2, m, N/m, N s/m) and sensor noise (m/s^2):",
        "",
        markdown_table(drive_rows, list(drive_rows[0])),
        "",
        "## What was computed",
        "",
        f"- Per drive k: **single** = the vehicle's own road-input observer (gamma {est.gamma:g}); **collaborative** "
        "= Algorithm 1 with the message of drive k-1 (drive 1: observer only, equal to single); **fused** = the "
        "running average of the band-limited model inversions of drives 1..k.",
        "- The estimators are designed (Lemma 1) for an ISO 8608 class C road with the default pothole statistics "
        "at this speed and each drive's sensor noise; only the *estimated* vehicle parameters are used.",
        f"- All road velocities are band-limited from {est.band_low_hz:g} Hz (W(f) = 1 / (1 + ({est.band_low_hz:g} Hz "
        "/ f)^8)): accelerometers cannot see a constant road velocity (DC), so it is not estimated.",
        f"- Elevation = the integral of the band-limited road velocity, mean removed. It is defined only up to a "
        f"slow drift: wavelengths above {est.speed / est.band_low_hz:g} m (speed / {est.band_low_hz:g} Hz) are not "
        "observed.",
        "- The first and last second or so of every estimate carry window-edge effects of the offline filters.",
        "- `road_estimates.csv`: `position_m`, `time_s` (since each drive's first sample), then "
        "`w_<estimator>_v<k>_<left|right>` (m/s) and `elevation_<estimator>_v<k>_<left|right>` (m) for every "
        "drive k and estimator single/collaborative/fused. `final_estimate.csv`: the last drive's collaborative "
        "and fused estimates. `anomalies.csv`: every detection of every estimator and drive.",
        "",
        f"## Road velocity, drive {V}",
        "",
        "Single vehicle, collaborative and fused estimates of the last drive"
        + (f"; right: a zoom on {zoom[0]:.1f}-{zoom[1]:.1f} m, around the largest fused road velocity." if zoom
           else "."),
        "",
        "![road velocity](road_velocity.png)",
        "",
        f"## Elevation, drive {V}",
        "",
        "![elevation](elevation.png)",
        "",
        "## Anomalies (`anomalies.csv`)",
        "",
    ]
    if anomalies is None:
        lines += ["Anomaly detection was not run.", ""]
    else:
        lines += ["Detections per drive and estimator:", "", markdown_table(count_rows, ["drive", *ESTIMATORS]), "",
                  f"Detections in drive {V}'s collaborative and fused estimates (position = center):", ""]
        lines += [markdown_table(final, ANOMALY_COLUMNS) if final else "None.", ""]
    (out / "report.md").write_text("\n".join(lines))
    return {
        "out_dir": str(out), "n_drives": V, "sample_rate_hz": est.sample_rate, "speed_mps": est.speed,
        "start_m": est.start_m, "n_samples": est.n_samples, "samples_per_drive": lengths,
        "truncated": est.truncated, "duration_s": est.n_samples / est.sample_rate, "length_m": length,
        "n_anomalies": {name: sum(counts[name]) for name in ESTIMATORS} if anomalies is not None else None,
        "notes": notes,
        "files": ["road_estimates.csv", "final_estimate.csv", "anomalies.csv", "road_velocity.png", "elevation.png",
                  "config.json", "report.md"],
    }


def _detector_config() -> dict | None:
    try:
        from ..detection.detector import DetectorSpec
    except ImportError:
        return None
    return asdict(DetectorSpec())


def estimate_command(drive_paths: list[str], out_dir, *, command: str) -> dict:
    """Everything ``roadcollab estimate`` does: read, estimate, detect, write.

    Parameters
    ----------
    drive_paths : list of str
        The drive CSVs in driving order (parameters files beside them).
    out_dir : str or Path
        Output folder (created).
    command : str
        The command line, recorded in ``config.json`` and ``report.md``.

    Returns
    -------
    dict
        Summary: ``out_dir``, ``n_drives``, ``sample_rate_hz``, ``speed_mps``, ``start_m``,
        ``n_samples``, ``samples_per_drive``, ``truncated``, ``duration_s``, ``length_m``,
        ``n_anomalies`` (per estimator, summed over drives; None if detection was not run),
        ``notes`` and ``files``.

    Raises
    ------
    ParameterError
        Bad input files (nothing is written then).
    """
    t0 = _time.perf_counter()
    drives = load_drives(drive_paths)
    est = estimate_drives(drives)
    note = None
    try:
        anomalies = find_anomalies(est)
    except ImportError as err:  # anomaly module not available in this build
        anomalies, note = None, f"Anomaly detection was not run: {err}."
    except ParameterError as err:  # e.g. a window shorter than the longest template
        anomalies, note = None, f"Anomaly detection was not run: {err}."
    return write_estimates(est, out_dir, command=command, anomalies=anomalies, anomaly_note=note,
                           elapsed=_time.perf_counter() - t0)


def add_estimate_arguments(parser) -> None:
    """Options of ``roadcollab estimate``: ``--drive FILE`` (repeatable, in driving order) and ``--out DIR``."""
    parser.add_argument("--drive", action="append", required=True, metavar="FILE",
                        help="drive CSV 'time_s,accel_left,accel_right' (m/s^2) with FILE's stem + .toml or .json "
                             "beside it (speed_mps, [vehicle] estimated parameters); repeat in driving order")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
