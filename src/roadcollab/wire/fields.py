"""Per-message-type fields: an in-memory message to and from its header and payload arrays.

:func:`message_fields` is the encoding side: it checks the Python types and array shapes of
an :class:`ExchangeMessage` or :class:`InversionMessage` (raising
:class:`~roadcollab.errors.MessageError`) and returns the :class:`~.layout.Header` and the
float64 arrays by wire name. :func:`build_message` is the decoding side: it assembles the
message from a checked header and its arrays.
"""

from __future__ import annotations

from numbers import Integral, Real
from typing import Union

import numpy as np

from ..errors import MessageError
from ..lti.realisation import StateSpaceData
from .layout import CHANNELS, FLOAT_NBYTES, MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION, Header
from .limits import check_mechanism
from .message import ExchangeMessage, InversionMessage

__all__ = ["Message", "message_fields", "build_message"]

Message = Union[ExchangeMessage, InversionMessage]


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


def _exchange_fields(message: ExchangeMessage, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
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


def _inversion_fields(message: InversionMessage, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
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
    if isinstance(message, ExchangeMessage):
        msg_type = MESSAGE_TYPE_EXCHANGE
    elif isinstance(message, InversionMessage):
        msg_type = MESSAGE_TYPE_INVERSION
    else:
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


def build_message(h: Header, arrays: dict[str, np.ndarray]) -> Message:
    """The message described by a checked header and its payload arrays.

    Parameters
    ----------
    h : Header
    arrays : dict of str to numpy.ndarray
        Payload arrays by wire name, as read from the bytes.

    Returns
    -------
    ExchangeMessage | InversionMessage
        Holding the given arrays (not copies).
    """
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                                z=arrays["z"], count=h.count)
    T, S = (StateSpaceData(*(arrays[f"{name}.{p}"] for p in "ABCD"), dt=dt)
            for name, dt in (("T", h.dt_T), ("S", h.dt_S)))
    return ExchangeMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                           T=T, S=S, e=arrays["e"], wf=arrays["wf"])
