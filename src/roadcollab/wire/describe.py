"""An in-memory message described as the codec sees it: header and float64 payload arrays.

:func:`message_fields` checks the Python types and array shapes of a message (raising
:class:`~roadcollab.errors.MessageError`); :func:`validate_message` adds every limit and
content check of :func:`~roadcollab.wire.protocol.decode`. Messages run it when they are
constructed, so a message that exists can be encoded and decoded. It does not import the
message classes (they import it); it recognises them by their ``WIRE_TYPE``.
"""

from __future__ import annotations

from numbers import Integral, Real
from typing import Any

import numpy as np

from .._validation import is_frozen
from ..errors import MessageError
from ..lti.realisation import StateSpaceData
from .layout import (CHANNELS, FLOAT_NBYTES, KEY_NBYTES, MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION,
                     MESSAGE_TYPE_KEY_ADVERT, MESSAGE_TYPE_MASKED_INPUT, MESSAGE_TYPE_SEALED_SHARES, SEALED_NBYTES,
                     SECAGG_TYPES, TYPE_NAMES, Header, SecAggHeader)
from .limits import check_header, check_mechanism, check_payload

__all__ = ["message_fields", "validate_message"]


def _as_int(name: str, value: object) -> int:
    """``value`` as an int; bools and non-integers are refused."""
    if type(value) is int:          # the common case, without the abstract-class checks below
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Integral, np.integer)):
        raise MessageError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    return int(value)


def _as_float(name: str, value: object) -> float:
    """``value`` as a float; bools and non-real numbers are refused."""
    if type(value) is float:
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise MessageError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)


_F8 = np.dtype(np.float64)


def _as_f8(name: str, value: Any, shape: tuple[int | None, int | None]) -> np.ndarray:
    """``value`` as a float64 array of the given shape (None = any), never losing precision."""
    if type(value) is np.ndarray and value.dtype == _F8 and value.ndim == 2:
        # The common case (every decoded or library-built message) without the conversions below:
        # a message is described twice per paper vehicle-segment, ten arrays each.
        rows, cols = shape
        if (rows is None or rows == value.shape[0]) and (cols is None or cols == value.shape[1]):
            return value
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


def _exchange_fields(message: Any, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
    """Dimensions, sample times and arrays of T, S, e and wf added to the common fields ``base``."""
    arrays: dict[str, np.ndarray] = {}
    orders: dict[str, int] = {}
    dts: dict[str, float] = {}
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
    # One construction instead of NamedTuple._replace (1.3 us each, twice per message described).
    h = Header(base.msg_type, base.mechanism, base.sample_rate, base.n_samples, length, 0,
               orders["T"], orders["S"], dts["T"], dts["S"])
    return h, arrays


def _inversion_fields(message: Any, base: Header) -> tuple[Header, dict[str, np.ndarray]]:
    """Length, count and the array ``z`` added to the common fields ``base``."""
    z = _as_f8("z", message.z, (None, CHANNELS))
    return base._replace(length=z.shape[0], count=_as_int("count", message.count)), {"z": z}


def _as_bytes(name: str, value: object, nbytes: int) -> bytes:
    """``value`` if it is ``bytes`` of exactly ``nbytes``."""
    if not isinstance(value, bytes) or len(value) != nbytes:
        got = f"{len(value)} bytes" if isinstance(value, bytes) else type(value).__name__
        raise MessageError(f"{name} must be {nbytes} bytes, got {got}")
    return value


def _as_shares(name: str, value: object) -> list[tuple[int, int]]:
    """A dict ``{owner: share}`` of ints as ``(owner, share)`` pairs sorted by owner (the wire order)."""
    if not isinstance(value, dict):
        raise MessageError(f"{name} must be a dict of owner id to share, got {type(value).__name__}")
    pairs = [(_as_int(f"{name}: owner", o), _as_int(f"{name}: share", y)) for o, y in value.items()]
    return sorted(pairs)


def _secagg_fields(message: Any, msg_type: int) -> tuple[SecAggHeader, dict[str, Any]]:
    """Header and payload fields of a secure-aggregation message, with types and lengths checked."""
    kind = TYPE_NAMES[msg_type]
    session = _as_bytes(f"{kind}: session", message.session, 16)
    if msg_type == MESSAGE_TYPE_KEY_ADVERT:
        h = SecAggHeader(msg_type, session, 0, _as_int("vehicle", message.vehicle))
        fields: dict[str, Any] = {"c_pk": _as_bytes("c_pk", message.c_pk, KEY_NBYTES),
                  "s_pk": _as_bytes("s_pk", message.s_pk, KEY_NBYTES)}
    elif msg_type == MESSAGE_TYPE_SEALED_SHARES:
        h = SecAggHeader(msg_type, session, 0, _as_int("sender", message.sender),
                         _as_int("recipient", message.recipient))
        fields = {"ciphertext": _as_bytes("ciphertext", message.ciphertext, SEALED_NBYTES)}
    elif msg_type == MESSAGE_TYPE_MASKED_INPUT:
        vehicle, y = _as_int("vehicle", message.vehicle), message.y
        if not isinstance(y, np.ndarray) or y.dtype != np.uint64 or y.ndim != 2 or y.shape[1] != CHANNELS:
            raise MessageError(f"masked input of vehicle {vehicle}: y must be a (L, 2) uint64 array, got "
                               f"{getattr(y, 'dtype', type(y).__name__)} {getattr(y, 'shape', '')}")
        h, fields = SecAggHeader(msg_type, session, 0, vehicle, y.shape[0]), {"y": y}
    else:
        fields = {"self_mask_shares": _as_shares("self_mask_shares", message.self_mask_shares),
                  "key_shares": _as_shares("key_shares", message.key_shares)}
        h = SecAggHeader(msg_type, session, 0, _as_int("vehicle", message.vehicle),
                         len(fields["self_mask_shares"]), len(fields["key_shares"]))
    return h._replace(payload_nbytes=h.expected_payload_nbytes()), fields


def message_fields(message: Any) -> tuple[Header | SecAggHeader, dict[str, Any]]:
    """Header and arrays of an in-memory message, with types and shapes checked.

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal
        Any object; everything but a well-typed message is refused.

    Returns
    -------
    header : Header | SecAggHeader
        With ``payload_nbytes`` the size the dimensions imply. The values are not yet
        checked against the limits (:func:`~.limits.check_header`).
    arrays : dict
        float64 arrays by wire name (see :func:`~.layout.payload_shapes`); (L, 2) signals and
        the A, B, C, D matrices of ``T`` and ``S``. For secure aggregation: ``c_pk``, ``s_pk``
        (key advert), ``ciphertext`` (sealed shares), ``y`` (masked input, uint64), or
        ``self_mask_shares`` and ``key_shares`` as ``(owner, share)`` lists sorted by owner (reveal).

    Raises
    ------
    MessageError
        If ``message`` is not a message or a field has a wrong type or shape.
    """
    msg_type = getattr(type(message), "WIRE_TYPE", None)
    if msg_type in SECAGG_TYPES:
        return _secagg_fields(message, msg_type)
    if msg_type not in (MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION):
        raise MessageError(f"message must be an ExchangeMessage or InversionMessage (or a secure-aggregation "
                           f"message), got {type(message).__name__}")
    mechanism = check_mechanism(message.mechanism)
    sample_rate = _as_float("sample_rate", message.sample_rate)
    n_samples = _as_int("n_samples", message.n_samples)
    base = Header(msg_type, mechanism, sample_rate, n_samples, 0, 0)
    if msg_type == MESSAGE_TYPE_EXCHANGE:
        h, arrays = _exchange_fields(message, base)
    else:
        h, arrays = _inversion_fields(message, base)
    return Header(*h[:5], h.expected_payload_nbytes(), *h[6:]), arrays      # _replace, without its cost


def _message_arrays(message: Any) -> list[np.ndarray]:
    """The array attributes of an exchange or inversion message (its systems' matrices included)."""
    out: list[np.ndarray] = []
    for name in ("e", "wf", "z"):
        arr = getattr(message, name, None)
        if arr is not None:
            out.append(arr)
    for name in ("T", "S"):
        sys = getattr(message, name, None)
        if isinstance(sys, StateSpaceData):
            out += [sys.A, sys.B, sys.C, sys.D]
    return out


def validate_message(message: Any) -> tuple[Header | SecAggHeader, dict[str, Any]]:
    """Every check :func:`~roadcollab.wire.protocol.decode` applies, on an in-memory message.

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal

    Returns
    -------
    header : Header | SecAggHeader
    arrays : dict
        As :func:`message_fields`.

    Raises
    ------
    MessageError
        If the message is malformed, out of the limits, non-finite or has unstable dynamics.
    """
    memo = message.__dict__.get("_validated") if hasattr(message, "__dict__") else None
    if memo is not None:
        # Validated before and nothing can have changed since: the same array objects, all frozen
        # (encoding a message built a moment ago re-checked 80 us of content per segment, measured).
        ids, result = memo
        result_typed: tuple[Header | SecAggHeader, dict[str, Any]] = result
        held = _message_arrays(message)
        if ids == tuple(map(id, held)) and all(map(is_frozen, held)):
            return result_typed
    h, arrays = message_fields(message)
    check_header(h)
    # The systems' own memo of their certificate (keyed by A's content): building a message and
    # encoding it certify each system once.
    systems = {name: getattr(message, name) for name in ("T", "S") if hasattr(message, name)}
    check_payload(h, arrays, certificates={name: sys.stability for name, sys in systems.items()
                                           if isinstance(sys, StateSpaceData)})
    held = _message_arrays(message)
    if held and hasattr(message, "__dict__"):
        # Freeze what was checked (arrays that own their data; views stay as they are, and a
        # message holding one is simply validated again when encoded).
        for arr in held:
            if isinstance(arr, np.ndarray) and arr.base is None:
                arr.setflags(write=False)
        if all(map(is_frozen, held)):
            object.__setattr__(message, "_validated", (tuple(map(id, held)), (h, arrays)))
    return h, arrays
