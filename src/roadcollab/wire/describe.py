"""An in-memory message described as the codec sees it: header and float64 payload arrays.

:func:`message_fields` checks the Python types and array shapes of a message (raising
:class:`~roadcollab.errors.MessageError`); :func:`validate_message` adds every limit and
content check of :func:`~roadcollab.wire.protocol.decode`. Messages run it when they are
constructed, so a message that exists can be encoded and decoded. It does not import the
message classes (they import it); it recognises them by their ``WIRE_TYPE``.
"""

from __future__ import annotations

from numbers import Integral, Real

import numpy as np

from ..errors import MessageError
from ..lti.realisation import StateSpaceData
from .layout import CHANNELS, FLOAT_NBYTES, MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION, Header
from .limits import check_header, check_mechanism, check_payload

__all__ = ["message_fields", "validate_message"]


def _as_int(name: str, value) -> int:
    """``value`` as an int; bools and non-integers are refused."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Integral, np.integer)):
        raise MessageError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    return int(value)


def _as_float(name: str, value) -> float:
    """``value`` as a float; bools and non-real numbers are refused."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise MessageError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)


def _as_f8(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    """``value`` as a float64 array of the given shape (None = any), never losing precision."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu":
        raise MessageError(f"{name} must be a real float array, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and arr.dtype.itemsize > FLOAT_NBYTES:
        # float64 is the wire precision; converting a long double would silently round.
        raise MessageError(f"{name} must be at most float64 (the wire precision), got dtype {arr.dtype}")
    if arr.ndim != 2 or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        want = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
        raise MessageError(f"{name} must have shape {want}, got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def _exchange_fields(message, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
    """Dimensions, sample times and arrays of T, S, e and wf added to the common fields ``base``."""
    arrays: dict[str, np.ndarray] = {}
    orders, dts = {}, {}
    for name in ("T", "S"):
        sys = getattr(message, name)
        if not isinstance(sys, StateSpaceData):
            raise MessageError(f"{name} must be a StateSpaceData, got {type(sys).__name__}")
        A = _as_f8(f"{name}.A", sys.A, (None, None))
        n = A.shape[0]
        arrays[f"{name}.A"] = _as_f8(f"{name}.A", A, (n, n))
        arrays[f"{name}.B"] = _as_f8(f"{name}.B", sys.B, (n, CHANNELS))
        arrays[f"{name}.C"] = _as_f8(f"{name}.C", sys.C, (CHANNELS, n))
        arrays[f"{name}.D"] = _as_f8(f"{name}.D", sys.D, (CHANNELS, CHANNELS))
        orders[name], dts[name] = n, _as_float(f"{name}.dt", sys.dt)
    arrays["e"] = _as_f8("e", message.e, (None, CHANNELS))
    length = arrays["e"].shape[0]
    arrays["wf"] = _as_f8("wf", message.wf, (length, CHANNELS))
    h = base._replace(length=length, order_T=orders["T"], order_S=orders["S"], dt_T=dts["T"], dt_S=dts["S"])
    return h, arrays


def _inversion_fields(message, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
    """Length, count and the array ``z`` added to the common fields ``base``."""
    z = _as_f8("z", message.z, (None, CHANNELS))
    return base._replace(length=z.shape[0], count=_as_int("count", message.count)), {"z": z}


def message_fields(message) -> tuple[Header, dict[str, np.ndarray]]:
    """Header and arrays of an in-memory message, with types and shapes checked.

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage
        Any object; everything but a well-typed message is refused.

    Returns
    -------
    header : Header
        With ``payload_nbytes`` the size the dimensions imply. The values are not yet
        checked against the limits (:func:`~.limits.check_header`).
    arrays : dict of str to numpy.ndarray
        float64 arrays by wire name (see :func:`~.layout.payload_shapes`); (L, 2) signals and
        the A, B, C, D matrices of ``T`` and ``S``.

    Raises
    ------
    MessageError
        If ``message`` is not a message or a field has a wrong type or shape.
    """
    msg_type = getattr(type(message), "WIRE_TYPE", None)
    if msg_type not in (MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION):
        raise MessageError(f"message must be an ExchangeMessage or InversionMessage, got {type(message).__name__}")
    mechanism = check_mechanism(message.mechanism)
    sample_rate = _as_float("sample_rate", message.sample_rate)
    n_samples = _as_int("n_samples", message.n_samples)
    base = Header(msg_type, mechanism, sample_rate, n_samples, 0, 0)
    if msg_type == MESSAGE_TYPE_EXCHANGE:
        h, arrays = _exchange_fields(message, base)
    else:
        h, arrays = _inversion_fields(message, base)
    return h._replace(payload_nbytes=h.expected_payload_nbytes()), arrays


def validate_message(message) -> tuple[Header, dict[str, np.ndarray]]:
    """Every check :func:`~roadcollab.wire.protocol.decode` applies, on an in-memory message.

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage

    Returns
    -------
    header : Header
    arrays : dict of str to numpy.ndarray
        As :func:`message_fields`.

    Raises
    ------
    MessageError
        If the message is malformed, out of the limits, non-finite or has unstable dynamics.
    """
    h, arrays = message_fields(message)
    check_header(h)
    check_payload(h, arrays)
    return h, arrays
