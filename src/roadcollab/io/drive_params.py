"""A recorded drive's parameters file (TOML or JSON): speed, sensor noise, start and the vehicle's
estimated half-car parameters (keys and units in :mod:`roadcollab.io.drives`).

Every error is a :class:`~roadcollab.errors.ParameterError` whose message starts with the file's
path and names the key, the expected and the found value.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields
from pathlib import Path

from ..errors import ParameterError
from ..models.vehicle import HalfCarParameters

__all__ = ["DEFAULT_SENSOR_NOISE_STD", "params_path_for", "read_drive_params", "write_drive_params"]

DEFAULT_SENSOR_NOISE_STD = 0.05
_VEHICLE_KEYS = tuple(f.name for f in fields(HalfCarParameters))
_VEHICLE_UNITS = {"sprung_mass": "kg", "roll_inertia": "kg m^2", "left_arm": "m", "right_arm": "m",
                  "stiffness": "N/m", "damping": "N s/m"}
_TOP_KEYS = ("speed_mps", "vehicle", "sensor_noise_std", "start_m")


def read_text(path: Path, what: str) -> str:
    """A UTF-8 text file (a leading BOM is dropped), with errors that name the file.

    Parameters
    ----------
    path : Path
    what : str
        What the file is, for the error message (e.g. ``"parameters file"``).

    Returns
    -------
    str
    """
    if not path.is_file():
        raise ParameterError(f"{path}: {what} not found (expected an existing file)")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise ParameterError(f"{path}: expected a UTF-8 text file, got undecodable bytes ({err.reason} at byte "
                             f"{err.start})") from None
    except OSError as err:
        raise ParameterError(f"{path}: cannot read {what}: {err.strerror or err}") from None


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
        raise ParameterError(f"{csv_path}: parameters file not found: expected {candidates[0]} or {candidates[1]} "
                             "beside the CSV (speed_mps and the [vehicle] parameters)")
    if len(found) > 1:
        raise ParameterError(f"{csv_path}: ambiguous parameters: both {found[0]} and {found[1]} exist; keep one")
    return found[0]


def _load_mapping(path: Path) -> dict:
    text = read_text(path, "parameters file")
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

    Parameters
    ----------
    path : str or Path

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
