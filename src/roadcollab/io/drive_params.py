"""A recorded drive's parameters file (TOML or JSON): speed, sensor noise, start and the vehicle's
estimated half-car parameters (keys and units in :mod:`roadcollab.io.drives`).

Every error is a :class:`~roadcollab.errors.FileFormatError` (a ``ParameterError``) whose message
starts with the file's path and names the key, the expected and the found value. Every value must
lie in its physical range (:data:`PARAMETER_RANGES`); a key given twice is an error in JSON as in
TOML; the file may be at most 1 MB.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import fields
from pathlib import Path

from ..errors import FileFormatError, ParameterError
from ..models.vehicle import HalfCarParameters
from .limits import PARAMS_MAX_BYTES, check_file_size, short_repr

__all__ = ["VEHICLE_ID", "DEFAULT_SENSOR_NOISE_STD", "ACCEL_UNITS", "STANDARD_GRAVITY", "PARAMETER_RANGES", "params_path_for",
           "read_drive_params", "write_drive_params"]

DEFAULT_SENSOR_NOISE_STD = 0.05
STANDARD_GRAVITY = 9.80665          # m/s^2 per g (CGPM 1901, the value accelerometer vendors use)
#: Accepted ``accel_unit`` values and their factor to m/s^2.
ACCEL_UNITS = {"m/s^2": 1.0, "g": STANDARD_GRAVITY}
_VEHICLE_KEYS = tuple(f.name for f in fields(HalfCarParameters))
#: Accepted range (low, high, unit) of every key. The vehicle ranges are about 4x wider on either side
#: than the published sets: quarter cars from 208 kg / 13.1 kN/m / 350 N s/m (small car, CTMS bus
#: damper) to 4500 kg / 300 kN/m / 20 kN s/m (bus) per corner, so 416-9000 kg per front half-car
#: (gislas3/quartercar ``cars.py``; U. Michigan CTMS suspension example); Jazar's Example 508 car has
#: I_x = 820 kg m^2 and arms of 0.70 / 0.75 m (/work/shared/data/realdata/reference_models/PROVENANCE.md);
#: the packaged default is 750 kg, 550 kg m^2, 0.75 m, 22 kN/m, 1.8 kN s/m.
PARAMETER_RANGES = {
    "speed_mps": (0.5, 70.0, "m/s"),
    "sensor_noise_std": (0.0, 20.0, "m/s^2"),
    "start_m": (-1e7, 1e7, "m"),
    "vehicle.sprung_mass": (100.0, 20_000.0, "kg"),
    "vehicle.roll_inertia": (10.0, 100_000.0, "kg m^2"),
    "vehicle.left_arm": (0.2, 2.0, "m"),
    "vehicle.right_arm": (0.2, 2.0, "m"),
    "vehicle.stiffness": (2_000.0, 1_500_000.0, "N/m"),
    "vehicle.damping": (50.0, 100_000.0, "N s/m"),
}
_TOP_KEYS = ("speed_mps", "vehicle", "sensor_noise_std", "start_m", "accel_unit", "vehicle_id")
#: A ``vehicle_id``: 1-64 characters, letters, digits and ``._-`` (it names the vehicle in calibration.csv).
VEHICLE_ID = re.compile(r"[A-Za-z0-9._-]{1,64}")


def read_text(path: Path, what: str, max_bytes: int = PARAMS_MAX_BYTES, flag: str | None = None) -> str:
    """A UTF-8 text file (a leading BOM is dropped), with errors that name the file.

    Parameters
    ----------
    path : Path
    what : str
        What the file is, for the error message (e.g. ``"parameters file"``).
    max_bytes : int
        Largest accepted size, bytes, checked before reading.
    flag : str or None
        The option that raises ``max_bytes``, named in the error.

    Returns
    -------
    str
    """
    check_file_size(path, what, max_bytes, flag)
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise FileFormatError(f"{path}: expected a UTF-8 text file, got undecodable bytes ({err.reason} at byte "
                              f"{err.start})") from None
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read {what}: {err.strerror or err}") from None


def params_path_for(csv_path) -> Path:
    """The parameters file beside ``csv_path``: same stem, ``.toml`` or ``.json`` (exactly one).

    Parameters
    ----------
    csv_path : str or Path

    Returns
    -------
    Path
    """
    csv_path = Path(csv_path)
    candidates = [csv_path.with_suffix(s) for s in (".toml", ".json")]
    found = [p for p in candidates if p.is_file()]
    if not found:
        raise FileFormatError(f"{csv_path}: parameters file not found: expected {candidates[0]} or {candidates[1]} "
                              "beside the CSV (speed_mps and the [vehicle] parameters)")
    if len(found) > 1:
        raise FileFormatError(f"{csv_path}: ambiguous parameters: both {found[0]} and {found[1]} exist; keep one")
    return found[0]


def _unique_keys(path: Path):
    """``object_pairs_hook`` for :func:`json.loads` that refuses a key given twice in one object."""
    def hook(pairs):
        seen = {}
        for k, v in pairs:
            if k in seen:
                raise FileFormatError(f"{path}: duplicate key {short_repr(k)} (each key may appear once)")
            seen[k] = v
        return seen
    return hook


def _load_mapping(path: Path) -> dict:
    text = read_text(path, "parameters file")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:  # tomllib is in the standard library only from Python 3.11: import it where TOML is read
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            raise FileFormatError(f"{path}: reading TOML needs Python >= 3.11 (tomllib); write the parameters as "
                                  f"JSON in {path.with_suffix('.json')} instead") from None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise FileFormatError(f"{path}: expected valid TOML, got a syntax error: {err}") from None
        except RecursionError:
            raise FileFormatError(f"{path}: expected a flat TOML file, got arrays or tables nested too deeply "
                                  "to parse") from None
        except ValueError as err:  # an integer beyond Python's digit limit for str -> int
            raise FileFormatError(f"{path}: expected numbers of at most 20 digits, got {err}") from None
    elif suffix == ".json":
        try:
            data = json.loads(text, object_pairs_hook=_unique_keys(path))
        except json.JSONDecodeError as err:
            raise FileFormatError(f"{path} line {err.lineno}: expected valid JSON, got a syntax error: {err.msg} "
                                  f"(column {err.colno})") from None
        except FileFormatError:
            raise
        except RecursionError:
            raise FileFormatError(f"{path}: expected a flat JSON object, got arrays or objects nested too deeply "
                                  "to parse") from None
        except ValueError as err:  # an integer beyond Python's digit limit for str -> int
            raise FileFormatError(f"{path}: expected numbers of at most 20 digits, got {err}") from None
        if not isinstance(data, dict):
            raise FileFormatError(f"{path}: expected a JSON object {{\"speed_mps\": ..., \"vehicle\": {{...}}}}, "
                                  f"got a {type(data).__name__}")
    else:
        raise FileFormatError(f"{path}: expected a .toml or .json parameters file, got suffix {path.suffix!r}")
    return data


def _number(path: Path, key: str, value) -> float:
    """``value`` as a float in the physical range :data:`PARAMETER_RANGES` ``[key]``; FileFormatError otherwise."""
    low, high, unit = PARAMETER_RANGES[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FileFormatError(f"{path}: key '{key}' must be a number ({unit}), got {short_repr(value)} "
                              f"({type(value).__name__})")
    if isinstance(value, int) and abs(value) > 10 ** 15:
        raise FileFormatError(f"{path}: key '{key}' must lie in [{low:g}, {high:g}] {unit}, got an integer of "
                              f"{len(str(abs(value))) if abs(value) < 10 ** 4000 else 'over 4000'} digits")
    v = float(value)
    if not math.isfinite(v):
        raise FileFormatError(f"{path}: key '{key}' must be a finite number ({unit}), got {v!r}")
    if not low <= v <= high:
        raise FileFormatError(f"{path}: key '{key}' must lie in [{low:g}, {high:g}] {unit} (the physical range), "
                              f"got {v:g}")
    return v


def _check_keys(path: Path, mapping: dict, allowed: tuple[str, ...], required: tuple[str, ...], where: str) -> None:
    unknown = [short_repr(where + k, 40) for k in mapping if k not in allowed]
    if unknown:
        raise FileFormatError(f"{path}: unknown key(s) {', '.join(unknown[:5])}; expected only "
                              f"{', '.join(where + k for k in allowed)}")
    missing = [k for k in required if k not in mapping]
    if missing:
        raise FileFormatError(f"{path}: missing required key(s) {', '.join(repr(where + k) for k in missing)}")


def read_drive_params(path, *, speed_column: str | None = None) -> dict:
    """Read and validate a drive's parameters file (TOML or JSON, keys in the module docstring).

    Parameters
    ----------
    path : str or Path
    speed_column : str or None
        ``"speed_mps"`` or ``"distance_m"`` if the drive's CSV carries that column: ``speed_mps``
        must then be absent from the file (one source of speed); None: it is required.

    Returns
    -------
    dict
        ``speed`` (m/s; None with ``speed_column``), ``sensor_noise_std`` (m/s^2), ``start_m`` (m), ``params``
        (:class:`~roadcollab.models.vehicle.HalfCarParameters`), ``accel_unit`` (a key of :data:`ACCEL_UNITS`;
        default ``"m/s^2"``), ``vehicle_id`` (str or None: the vehicle that recorded the drive, the same in
        every drive it recorded; :mod:`roadcollab.experiments.drives.gain_calibration`).

    Raises
    ------
    FileFormatError
        ``"<path>: ..."``: larger than 1 MB, not UTF-8, a syntax error, nesting too deep to parse,
        a duplicate, unknown or missing key, or a value that is not a number within
        :data:`PARAMETER_RANGES`.
    """
    path = Path(path)
    data = _load_mapping(path)
    _check_keys(path, data, _TOP_KEYS, ("vehicle",) if speed_column else ("speed_mps", "vehicle"), "")
    if speed_column and "speed_mps" in data:
        raise FileFormatError(f"{path}: key 'speed_mps' must be absent: the drive's CSV carries a {speed_column} "
                              "column (one source of speed per drive); remove one of them")
    speed = None if speed_column else _number(path, "speed_mps", data["speed_mps"])
    noise = _number(path, "sensor_noise_std", data.get("sensor_noise_std", DEFAULT_SENSOR_NOISE_STD))
    start = _number(path, "start_m", data.get("start_m", 0.0))
    unit = data.get("accel_unit", "m/s^2")
    if not isinstance(unit, str) or unit not in ACCEL_UNITS:
        raise FileFormatError(f"{path}: key 'accel_unit' must be one of {', '.join(repr(u) for u in ACCEL_UNITS)} "
                              f"(the unit of the CSV's accel_left and accel_right), got {short_repr(unit)}")
    vid = data.get("vehicle_id")
    if vid is not None and not (isinstance(vid, str) and VEHICLE_ID.fullmatch(vid)):
        raise FileFormatError(f"{path}: key 'vehicle_id' must be 1-64 letters, digits, '.', '_' or '-' (the same "
                              f"for every drive of one vehicle), got {short_repr(vid)}")
    veh = data["vehicle"]
    if not isinstance(veh, dict):
        raise FileFormatError(f"{path}: key 'vehicle' must be a table ([vehicle] in TOML, an object in JSON) of "
                              f"{', '.join(_VEHICLE_KEYS)}, got {short_repr(veh)} ({type(veh).__name__})")
    _check_keys(path, veh, _VEHICLE_KEYS, _VEHICLE_KEYS, "vehicle.")
    values = {k: _number(path, f"vehicle.{k}", veh[k]) for k in _VEHICLE_KEYS}
    return {"speed": speed, "sensor_noise_std": noise, "start_m": start, "params": HalfCarParameters(**values),
            "accel_unit": unit, "vehicle_id": vid}


def write_drive_params(path, *, speed: float | None, params: HalfCarParameters, sensor_noise_std: float | None = None,
                       start_m: float | None = None, accel_unit: str | None = None,
                       vehicle_id: str | None = None) -> Path:
    """Write a parameters file (``.toml`` or ``.json`` by suffix), full precision.

    Values are not validated here; :func:`read_drive_params` checks them.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten); the suffix ``.toml`` or ``.json`` (any case) picks the format.
    speed : float or None
        ``speed_mps``, m/s; None omits the key (a drive whose CSV carries its speed or distance).
    params : HalfCarParameters
        The vehicle's estimated parameters, written as the ``vehicle`` table (SI units).
    sensor_noise_std : float, optional
        m/s^2; the key is omitted if None (readers then use 0.05).
    start_m : float, optional
        Road distance of the first sample, m; the key is omitted if None (readers then use 0).
    accel_unit : str, optional
        ``"m/s^2"`` or ``"g"``; the key is omitted if None (readers then use m/s^2).
    vehicle_id : str, optional
        The vehicle that recorded the drive; the key is omitted if None (each drive is then its own vehicle).

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
    top: dict[str, float | str] = {} if speed is None else {"speed_mps": float(speed)}
    if sensor_noise_std is not None:
        top["sensor_noise_std"] = float(sensor_noise_std)
    if start_m is not None:
        top["start_m"] = float(start_m)
    if accel_unit is not None:
        top["accel_unit"] = str(accel_unit)
    if vehicle_id is not None:
        top["vehicle_id"] = str(vehicle_id)
    veh = {k: float(v) for k, v in params.as_dict().items()}
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps({**top, "vehicle": veh}, indent=2) + "\n")
    elif path.suffix.lower() == ".toml":
        lines = [f"{k} = {v!r}" for k, v in top.items()] + ["", "[vehicle]"] + [f"{k} = {v!r}" for k, v in veh.items()]
        path.write_text("\n".join(lines) + "\n")
    else:
        raise ParameterError(f"{path}: expected a .toml or .json suffix, got {path.suffix!r}")
    return path
