"""One place for argument validation (python-control ``_ssmatrix`` style).

Every helper raises :class:`roadcollab.errors.ParameterError` (a ``ValueError``) whose
message names the parameter and gives the expected versus the actual value. Validation
happens at construction, never with ``assert``.
"""

from __future__ import annotations

import math
import os
from numbers import Integral, Real
from typing import Union

import numpy as np

from .errors import ParameterError

#: A file path as the functions that open files accept it (``str`` or ``os.PathLike``), for annotations.
StrPath = Union[str, "os.PathLike[str]"]

__all__ = [
    "check_real",
    "check_positive",
    "check_nonnegative",
    "check_int",
    "check_probability",
    "check_matrix",
    "check_signal",
    "check_psd",
    "is_frozen",
    "freeze",
]


def check_real(name: str, value, *, low: float | None = None, high: float | None = None,
               low_open: bool = False, high_open: bool = False) -> float:
    """Return ``value`` as a finite float, checking an optional interval."""
    if isinstance(value, bool) or not isinstance(value, (Real, np.floating, np.integer)):
        raise ParameterError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be finite, got {v!r}")
    if low is not None and (v < low or (low_open and v == low)):
        op = ">" if low_open else ">="
        raise ParameterError(f"{name} must be {op} {low:g}, got {v:g}")
    if high is not None and (v > high or (high_open and v == high)):
        op = "<" if high_open else "<="
        raise ParameterError(f"{name} must be {op} {high:g}, got {v:g}")
    return v


def check_positive(name: str, value) -> float:
    """Return ``value`` as a finite float > 0."""
    return check_real(name, value, low=0.0, low_open=True)


def check_nonnegative(name: str, value) -> float:
    """Return ``value`` as a finite float >= 0."""
    return check_real(name, value, low=0.0)


def check_probability(name: str, value) -> float:
    """Return ``value`` as a float in [0, 1]."""
    return check_real(name, value, low=0.0, high=1.0)


def check_int(name: str, value, *, low: int | None = None, high: int | None = None) -> int:
    """Return ``value`` as an int in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, (Integral, np.integer)):
        raise ParameterError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    v = int(value)
    if low is not None and v < low:
        raise ParameterError(f"{name} must be >= {low}, got {v}")
    if high is not None and v > high:
        raise ParameterError(f"{name} must be <= {high}, got {v}")
    return v


def check_matrix(name: str, value, shape: tuple[int | None, ...] | None = None, *,
                 dtype=float) -> np.ndarray:
    """Return ``value`` as a finite ndarray with the expected shape (``None`` = any size)."""
    try:
        arr = np.array(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ParameterError(f"{name} must be a numeric array, got {type(value).__name__}") from err
    if shape is not None:
        if arr.ndim == 0 and len(shape) == 2 and shape[0] in (1, None) and shape[1] in (1, None):
            arr = arr.reshape(1, 1)
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
            raise ParameterError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be finite, got {int(np.sum(~np.isfinite(arr)))} non-finite entries")
    return arr


def check_signal(name: str, value, channels: int | None = None, *, min_length: int = 1) -> np.ndarray:
    """Return a finite float signal of shape (N, channels)."""
    arr = check_matrix(name, value, (None, channels))
    if arr.shape[0] < min_length:
        raise ParameterError(f"{name} must have at least {min_length} samples, got {arr.shape[0]}")
    return arr


def check_psd(name: str, value, n: int, *, tol: float = 1e-12) -> np.ndarray:
    """Return a symmetric positive semi-definite (n, n) matrix."""
    arr = check_matrix(name, value, (n, n))
    if not np.allclose(arr, arr.T, rtol=1e-10, atol=tol * max(1.0, np.abs(arr).max())):
        raise ParameterError(f"{name} must be symmetric, got asymmetry {np.abs(arr - arr.T).max():.3g}")
    arr = 0.5 * (arr + arr.T)
    lo = float(np.linalg.eigvalsh(arr).min())
    if lo < -tol * max(1.0, np.abs(arr).max()):
        raise ParameterError(f"{name} must be positive semi-definite, got smallest eigenvalue {lo:.3g}")
    return arr


def is_frozen(arr: object) -> bool:
    """True if ``arr`` is an ndarray whose content cannot change through it or any array it views: it and
    every array down its ``base`` chain are read-only, and the chain ends in no buffer or in ``bytes``.

    Not a permanent property: the owner of a buffer may make it writable again, so a memo that relies
    on it checks again on every use.

    Parameters
    ----------
    arr : object

    Returns
    -------
    bool
    """
    while isinstance(arr, np.ndarray):
        if arr.flags.writeable:
            return False
        arr = arr.base
    return arr is None or isinstance(arr, bytes)


def freeze(*arrays: object) -> None:
    """Make the given ndarrays that own their data read-only (views and other objects are left as they
    are): for new arrays whose maker holds the only references, so that memos keyed by their content
    can be found by identity (:func:`is_frozen`).

    Parameters
    ----------
    *arrays : object
    """
    for arr in arrays:
        if isinstance(arr, np.ndarray) and arr.base is None:
            arr.setflags(write=False)
