"""Versioned binary wire format for the messages exchanged between consecutive vehicles.

A received message is untrusted, possibly hostile input. :func:`decode` therefore accepts
nothing but this fixed, fully declared layout and raises :class:`~roadcollab.errors.MessageError`
(and no other exception) for any byte string that is not a valid message. The format is
built from :mod:`struct` headers and raw float64 arrays only: no pickle, no eval, no JSON.
Every float is stored as IEEE-754 binary64, so a message round-trips bit-exactly.

Byte layout
-----------
All integers are unsigned and all fields little-endian. Offsets are in bytes.

Common header (32 bytes, ``struct`` format ``"<4sBBBBdIIQ"``)::

    offset  size  type      field
    ------  ----  --------  -----------------------------------------------------------
         0     4  bytes     magic, b"RCOL"
         4     1  uint8     format version, FORMAT_VERSION (= 1)
         5     1  uint8     message type: 1 = ExchangeMessage, 2 = InversionMessage
         6     1  uint8     mechanism: 1 = "none", 2 = "paper", 3 = "hardened", 4 = "fused"
         7     1  uint8     reserved, must be 0
         8     8  float64   sample_rate, Hz
        16     4  uint32    n_samples, samples in the recorded window N
        20     4  uint32    L, signal length (rows of every (L, 2) signal)
        24     8  uint64    payload byte count (everything after the full header)

Exchange header extension (type 1, 24 bytes, ``"<IIdd"``), full header 56 bytes::

        32     4  uint32    nT, state dimension (order) of T
        36     4  uint32    nS, state dimension (order) of S
        40     8  float64   T.dt, s
        48     8  float64   S.dt, s
        56        payload   T.A (nT, nT), T.B (nT, 2), T.C (2, nT), T.D (2, 2),
                            S.A (nS, nS), S.B (nS, 2), S.C (2, nS), S.D (2, 2),
                            e (L, 2), wf (L, 2)

Inversion header extension (type 2, 8 bytes, ``"<II"``), full header 40 bytes::

        32     4  uint32    count, number of vehicles whose inversions z averages
        36     4  uint32    reserved, must be 0
        40        payload   z (L, 2)

Every payload array is ``'<f8'`` in row-major (C) order, concatenated with no padding. A
system of order ``n`` has ``n*n + 2n + 2n + 4 = (n + 2)**2`` entries, so the total size is

* ExchangeMessage: ``56 + 8 * ((nT + 2)**2 + (nS + 2)**2 + 4 * L)`` bytes,
* InversionMessage: ``40 + 8 * 2 * L`` bytes.

The mechanism byte must agree with the message type ("none"/"paper" only with type 1,
"hardened"/"fused" only with type 2). The payload byte count is redundant with the
dimensions on purpose: it must equal the size the dimensions imply, and the byte string
must be exactly header + payload long (shorter is "truncated", longer is "trailing").

Limits
------
Checked from the header alone, before any array is allocated:

=====================  =====================================================================
``MAX_ORDER``          64: largest state dimension of T and S (0 is allowed: a static gain)
``MAX_SIGNAL_LENGTH``  2**20: largest L
``MAX_MESSAGE_BYTES``  the size of the largest valid message (orders 64, L = 2**20),
                       33,624,184 bytes (about 32 MiB); anything longer is refused at once
``sample_rate``        finite, 0 < sample_rate <= ``MAX_SAMPLE_RATE`` (1e6 Hz)
``n_samples``          1 <= n_samples <= L
``count``              1 <= count <= ``MAX_COUNT`` (10**6)
``dt``                 T.dt and S.dt equal 1 / sample_rate to ``DT_RTOL`` (1e-12) relative
=====================  =====================================================================

Checked on the payload: every float finite (no NaN, no inf), and T and S discrete-time
stable, i.e. the spectral radius of A below 1 (a message whose eigenvalues cannot be
computed is refused too).

:func:`encode` runs exactly the same checks, so it never produces a message that
:func:`decode` would refuse.
"""

from __future__ import annotations

import math
import struct
from numbers import Integral, Real
from os import PathLike
from pathlib import Path
from typing import NamedTuple, Union

import numpy as np

from ..errors import MessageError
from .message import ExchangeMessage, InversionMessage
from ..lti.realisation import StateSpaceData

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "MAX_ORDER",
    "MAX_SIGNAL_LENGTH",
    "MAX_MESSAGE_BYTES",
    "MAX_SAMPLE_RATE",
    "MAX_COUNT",
    "DT_RTOL",
    "MECHANISM_CODES",
    "MESSAGE_TYPE_EXCHANGE",
    "MESSAGE_TYPE_INVERSION",
    "COMMON_HEADER_NBYTES",
    "EXCHANGE_HEADER_NBYTES",
    "INVERSION_HEADER_NBYTES",
    "encode",
    "decode",
    "exchange_nbytes",
    "inversion_nbytes",
    "message_nbytes",
    "example_message",
    "write_example",
]

Message = Union[ExchangeMessage, InversionMessage]

MAGIC = b"RCOL"
FORMAT_VERSION = 1

MESSAGE_TYPE_EXCHANGE = 1
MESSAGE_TYPE_INVERSION = 2
_TYPE_NAMES = {MESSAGE_TYPE_EXCHANGE: "exchange", MESSAGE_TYPE_INVERSION: "inversion"}

# Codes start at 1 so that an all-zero header can never be a valid message.
MECHANISM_CODES = {"none": 1, "paper": 2, "hardened": 3, "fused": 4}
_MECHANISM_NAMES = {code: name for name, code in MECHANISM_CODES.items()}
_MECHANISM_TYPE = {"none": MESSAGE_TYPE_EXCHANGE, "paper": MESSAGE_TYPE_EXCHANGE,
                   "hardened": MESSAGE_TYPE_INVERSION, "fused": MESSAGE_TYPE_INVERSION}

MAX_ORDER = 64
MAX_SIGNAL_LENGTH = 2 ** 20
MAX_SAMPLE_RATE = 1e6
MAX_COUNT = 10 ** 6
DT_RTOL = 1e-12

_COMMON = struct.Struct("<4sBBBBdIIQ")
_EXCHANGE_EXT = struct.Struct("<IIdd")
_INVERSION_EXT = struct.Struct("<II")

COMMON_HEADER_NBYTES = _COMMON.size                              # 32
EXCHANGE_HEADER_NBYTES = _COMMON.size + _EXCHANGE_EXT.size       # 56
INVERSION_HEADER_NBYTES = _COMMON.size + _INVERSION_EXT.size     # 40

_F8 = np.dtype("<f8")
_FLOAT_NBYTES = _F8.itemsize
_CHANNELS = 2  # every system is 2x2 and every signal has two channels (left, right track)


def _system_floats(order: int) -> int:
    """Entries of A, B, C, D of a 2x2 system of the given order: ``(order + 2)**2``."""
    return (order + _CHANNELS) ** 2


def exchange_nbytes(order_T: int, order_S: int, length: int) -> int:
    """Encoded size of an :class:`ExchangeMessage`.

    Parameters
    ----------
    order_T, order_S : int
        State dimensions of ``T`` and ``S``.
    length : int
        Rows ``L`` of ``e`` and ``wf``.

    Returns
    -------
    int
        ``56 + 8 * ((order_T + 2)**2 + (order_S + 2)**2 + 4 * length)``.
    """
    floats = _system_floats(order_T) + _system_floats(order_S) + 2 * _CHANNELS * length
    return EXCHANGE_HEADER_NBYTES + _FLOAT_NBYTES * floats


def inversion_nbytes(length: int) -> int:
    """Encoded size of an :class:`InversionMessage` with ``z`` of ``length`` rows: ``40 + 16 * length``."""
    return INVERSION_HEADER_NBYTES + _FLOAT_NBYTES * _CHANNELS * length


# The largest valid message bounds what decode will even look at.
MAX_MESSAGE_BYTES = max(exchange_nbytes(MAX_ORDER, MAX_ORDER, MAX_SIGNAL_LENGTH),
                        inversion_nbytes(MAX_SIGNAL_LENGTH))


class _Header(NamedTuple):
    """All header fields, for both message types (unused ones are 0)."""

    msg_type: int
    mechanism: str
    sample_rate: float
    n_samples: int
    length: int
    payload_nbytes: int
    order_T: int = 0
    order_S: int = 0
    dt_T: float = 0.0
    dt_S: float = 0.0
    count: int = 0

    @property
    def header_nbytes(self) -> int:
        return EXCHANGE_HEADER_NBYTES if self.msg_type == MESSAGE_TYPE_EXCHANGE else INVERSION_HEADER_NBYTES

    def expected_payload_nbytes(self) -> int:
        if self.msg_type == MESSAGE_TYPE_EXCHANGE:
            return exchange_nbytes(self.order_T, self.order_S, self.length) - EXCHANGE_HEADER_NBYTES
        return inversion_nbytes(self.length) - INVERSION_HEADER_NBYTES


# --- the single validation path (shared by encode and decode) ------------------------------------

def _check_header(h: _Header) -> None:
    """Check every header field against the limits; uses no payload, allocates nothing."""
    expected_type = _MECHANISM_TYPE[h.mechanism]
    if h.msg_type != expected_type:
        raise MessageError(
            f"mechanism {h.mechanism!r} requires an {_TYPE_NAMES[expected_type]} message, "
            f"got an {_TYPE_NAMES[h.msg_type]} message")
    # Written as "not (ok)" so that NaN fails every check.
    if not (math.isfinite(h.sample_rate) and 0.0 < h.sample_rate <= MAX_SAMPLE_RATE):
        raise MessageError(f"sample_rate must be finite and in (0, {MAX_SAMPLE_RATE:g}] Hz, got {h.sample_rate!r}")
    if not 1 <= h.length <= MAX_SIGNAL_LENGTH:
        raise MessageError(f"oversized or empty: signal length must be in [1, {MAX_SIGNAL_LENGTH}] "
                           f"(MAX_SIGNAL_LENGTH), got {h.length}")
    if not 1 <= h.n_samples <= h.length:
        raise MessageError(f"n_samples must be in [1, signal length {h.length}], got {h.n_samples}")
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        dt = 1.0 / h.sample_rate
        if not math.isfinite(dt):
            # A subnormal sample_rate makes 1/sample_rate overflow, and inf would pass the dt test.
            raise MessageError(f"sample_rate {h.sample_rate!r} is too small: 1/sample_rate is not finite")
        for name, order, sys_dt in (("T", h.order_T, h.dt_T), ("S", h.order_S, h.dt_S)):
            if not 0 <= order <= MAX_ORDER:
                raise MessageError(f"oversized: order of {name} must be in [0, {MAX_ORDER}] (MAX_ORDER), got {order}")
            if not abs(sys_dt - dt) <= DT_RTOL * dt:
                raise MessageError(f"{name}.dt must equal 1/sample_rate = {dt!r} to {DT_RTOL:g} relative, "
                                   f"got {sys_dt!r}")
    else:
        if not 1 <= h.count <= MAX_COUNT:
            raise MessageError(f"count must be in [1, {MAX_COUNT}], got {h.count}")
        if h.mechanism == "hardened" and h.count != 1:
            # A "hardened" message is one vehicle's own inversion by definition.
            raise MessageError(f"count must be 1 for mechanism 'hardened', got {h.count}")
    expected = h.expected_payload_nbytes()
    if h.payload_nbytes != expected:
        raise MessageError(f"header declares {h.payload_nbytes} payload bytes but its dimensions imply {expected}")


def _check_finite(name: str, arr: np.ndarray) -> None:
    if not np.isfinite(arr).all():
        bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        raise MessageError(f"{name} must be finite, got {bad} non-finite entries (NaN or inf)")


def _check_system(name: str, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> None:
    """Finite entries and a discrete-time stable A (spectral radius < 1)."""
    for part, arr in (("A", A), ("B", B), ("C", C), ("D", D)):
        _check_finite(f"{name}.{part}", arr)
    if A.shape[0] == 0:
        return
    try:
        # Huge but finite entries may overflow inside LAPACK; the result is checked below.
        with np.errstate(all="ignore"):
            radius = float(np.max(np.abs(np.linalg.eigvals(A))))
    except (np.linalg.LinAlgError, ValueError) as err:
        raise MessageError(f"{name}.A: eigenvalues could not be computed ({err})") from err
    if not radius < 1.0:
        raise MessageError(f"{name} must be discrete-time stable (spectral radius of A < 1), got {radius:.6g}")


def _check_payload(h: _Header, arrays: dict[str, np.ndarray]) -> None:
    """Check the arrays of a message whose header passed :func:`_check_header`."""
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        for name in ("T", "S"):
            _check_system(name, *(arrays[f"{name}.{p}"] for p in "ABCD"))
        _check_finite("e", arrays["e"])
        _check_finite("wf", arrays["wf"])
    else:
        _check_finite("z", arrays["z"])


def _payload_shapes(h: _Header) -> list[tuple[str, tuple[int, int]]]:
    """Names and shapes of the payload arrays, in wire order."""
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return [("z", (h.length, _CHANNELS))]
    shapes = []
    for name, n in (("T", h.order_T), ("S", h.order_S)):
        shapes += [(f"{name}.A", (n, n)), (f"{name}.B", (n, _CHANNELS)),
                   (f"{name}.C", (_CHANNELS, n)), (f"{name}.D", (_CHANNELS, _CHANNELS))]
    return shapes + [("e", (h.length, _CHANNELS)), ("wf", (h.length, _CHANNELS))]


# --- encode --------------------------------------------------------------------------------------

def _as_int(name: str, value) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Integral, np.integer)):
        raise MessageError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    return int(value)


def _as_float(name: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise MessageError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)


def _as_f8(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    """``value`` as a float64 array of the given shape (None = any), never losing precision."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu":
        raise MessageError(f"{name} must be a real float array, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and arr.dtype.itemsize > _FLOAT_NBYTES:
        # float64 is the wire precision; converting a long double would silently round.
        raise MessageError(f"{name} must be at most float64 (the wire precision), got dtype {arr.dtype}")
    if arr.ndim != 2 or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        want = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
        raise MessageError(f"{name} must have shape {want}, got {arr.shape}")
    return arr.astype(np.float64, copy=False)


def _fields(message) -> tuple[_Header, dict[str, np.ndarray]]:
    """Header and arrays of an in-memory message, with types and shapes checked."""
    if isinstance(message, ExchangeMessage):
        msg_type = MESSAGE_TYPE_EXCHANGE
    elif isinstance(message, InversionMessage):
        msg_type = MESSAGE_TYPE_INVERSION
    else:
        raise MessageError(f"message must be an ExchangeMessage or InversionMessage, got {type(message).__name__}")
    mechanism = message.mechanism
    if not isinstance(mechanism, str) or mechanism not in MECHANISM_CODES:
        raise MessageError(f"mechanism must be one of {sorted(MECHANISM_CODES)}, got {mechanism!r}")
    sample_rate = _as_float("sample_rate", message.sample_rate)
    n_samples = _as_int("n_samples", message.n_samples)
    arrays: dict[str, np.ndarray] = {}
    if msg_type == MESSAGE_TYPE_EXCHANGE:
        orders, dts = {}, {}
        for name in ("T", "S"):
            sys = getattr(message, name)
            if not isinstance(sys, StateSpaceData):
                raise MessageError(f"{name} must be a StateSpaceData, got {type(sys).__name__}")
            A = _as_f8(f"{name}.A", sys.A, (None, None))
            n = A.shape[0]
            arrays[f"{name}.A"] = _as_f8(f"{name}.A", A, (n, n))
            arrays[f"{name}.B"] = _as_f8(f"{name}.B", sys.B, (n, _CHANNELS))
            arrays[f"{name}.C"] = _as_f8(f"{name}.C", sys.C, (_CHANNELS, n))
            arrays[f"{name}.D"] = _as_f8(f"{name}.D", sys.D, (_CHANNELS, _CHANNELS))
            orders[name], dts[name] = n, _as_float(f"{name}.dt", sys.dt)
        arrays["e"] = _as_f8("e", message.e, (None, _CHANNELS))
        length = arrays["e"].shape[0]
        arrays["wf"] = _as_f8("wf", message.wf, (length, _CHANNELS))
        h = _Header(msg_type, mechanism, sample_rate, n_samples, length, 0,
                    order_T=orders["T"], order_S=orders["S"], dt_T=dts["T"], dt_S=dts["S"])
    else:
        arrays["z"] = _as_f8("z", message.z, (None, _CHANNELS))
        h = _Header(msg_type, mechanism, sample_rate, n_samples, arrays["z"].shape[0], 0,
                    count=_as_int("count", message.count))
    return h._replace(payload_nbytes=h.expected_payload_nbytes()), arrays


def message_nbytes(message: Message) -> int:
    """Size in bytes of ``encode(message)``, from the array shapes (nothing is encoded).

    Raises
    ------
    MessageError
        If ``message`` is not a message or its arrays have wrong types or shapes.
    """
    h, _ = _fields(message)
    return h.header_nbytes + h.payload_nbytes


def encode(message: Message) -> bytes:
    """Serialise a message to the binary wire format (see the module docstring).

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage

    Returns
    -------
    bytes
        ``message_nbytes(message)`` bytes.

    Raises
    ------
    MessageError
        If the message is malformed, out of the limits, non-finite or has unstable dynamics:
        it runs the checks of :func:`decode`, so only decodable bytes are ever produced.
    """
    h, arrays = _fields(message)
    _check_header(h)
    _check_payload(h, arrays)
    head = _COMMON.pack(MAGIC, FORMAT_VERSION, h.msg_type, MECHANISM_CODES[h.mechanism], 0,
                        h.sample_rate, h.n_samples, h.length, h.payload_nbytes)
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        head += _EXCHANGE_EXT.pack(h.order_T, h.order_S, h.dt_T, h.dt_S)
    else:
        head += _INVERSION_EXT.pack(h.count, 0)
    parts = [head] + [np.ascontiguousarray(arrays[name], dtype=_F8).tobytes() for name, _ in _payload_shapes(h)]
    return b"".join(parts)


# --- decode --------------------------------------------------------------------------------------

def _as_buffer(data) -> memoryview:
    """A flat, C-contiguous byte view of ``data`` (bytes, bytearray or memoryview)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"message must be bytes, bytearray or memoryview, got {type(data).__name__}")
    view = memoryview(data)
    if not view.c_contiguous:
        view = memoryview(view.tobytes())
    return view.cast("B")


def _read_header(buf: memoryview) -> _Header:
    """Parse and check the header; refuses everything it can before looking at the payload."""
    size = len(buf)
    if bytes(buf[:len(MAGIC)]) != MAGIC[:min(size, len(MAGIC))]:
        raise MessageError(f"wrong magic: expected {MAGIC!r}, got {bytes(buf[:len(MAGIC)])!r}")
    if size < COMMON_HEADER_NBYTES:
        raise MessageError(f"truncated: the header needs {COMMON_HEADER_NBYTES} bytes, got {size}")
    if size > MAX_MESSAGE_BYTES:
        raise MessageError(f"oversized: {size} bytes exceeds MAX_MESSAGE_BYTES = {MAX_MESSAGE_BYTES}")
    _, version, msg_type, mech_code, reserved, sample_rate, n_samples, length, payload_nbytes = \
        _COMMON.unpack_from(buf, 0)
    if version != FORMAT_VERSION:
        raise MessageError(f"unsupported format version {version}, expected {FORMAT_VERSION}")
    if msg_type not in _TYPE_NAMES:
        raise MessageError(f"unknown message type {msg_type}, expected one of "
                           + ", ".join(f"{k} ({v})" for k, v in _TYPE_NAMES.items()))
    if mech_code not in _MECHANISM_NAMES:
        raise MessageError(f"unknown mechanism code {mech_code}, expected one of "
                           + ", ".join(f"{k} ({v!r})" for k, v in _MECHANISM_NAMES.items()))
    if reserved != 0:
        raise MessageError(f"reserved header byte 7 must be 0, got {reserved}")
    h = _Header(msg_type, _MECHANISM_NAMES[mech_code], sample_rate, n_samples, length, payload_nbytes)
    if size < h.header_nbytes:
        raise MessageError(f"truncated: the {_TYPE_NAMES[msg_type]} header needs {h.header_nbytes} bytes, got {size}")
    if msg_type == MESSAGE_TYPE_EXCHANGE:
        order_T, order_S, dt_T, dt_S = _EXCHANGE_EXT.unpack_from(buf, COMMON_HEADER_NBYTES)
        h = h._replace(order_T=order_T, order_S=order_S, dt_T=dt_T, dt_S=dt_S)
    else:
        count, reserved = _INVERSION_EXT.unpack_from(buf, COMMON_HEADER_NBYTES)
        if reserved != 0:
            raise MessageError(f"reserved inversion header field must be 0, got {reserved}")
        h = h._replace(count=count)
    _check_header(h)
    actual = size - h.header_nbytes
    if actual < h.payload_nbytes:
        raise MessageError(f"truncated: header declares {h.payload_nbytes} payload bytes, got {actual}")
    if actual > h.payload_nbytes:
        raise MessageError(f"trailing data: header declares {h.payload_nbytes} payload bytes, "
                           f"got {actual} ({actual - h.payload_nbytes} extra)")
    return h


def _read_array(buf: memoryview, offset: int, shape: tuple[int, int]) -> np.ndarray:
    """An owned, read-only native float64 copy of ``shape`` floats at ``offset``."""
    count = shape[0] * shape[1]
    # np.array copies, so the result never aliases the caller's (possibly mutable) buffer.
    arr = np.array(np.frombuffer(buf, dtype=_F8, count=count, offset=offset).reshape(shape),
                   dtype=np.float64, order="C")
    arr.setflags(write=False)
    return arr


def _decode(data) -> Message:
    buf = _as_buffer(data)
    h = _read_header(buf)
    arrays: dict[str, np.ndarray] = {}
    offset = h.header_nbytes
    for name, shape in _payload_shapes(h):
        arrays[name] = _read_array(buf, offset, shape)
        offset += _FLOAT_NBYTES * shape[0] * shape[1]
    _check_payload(h, arrays)
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                                z=arrays["z"], count=h.count)
    T, S = (StateSpaceData(*(arrays[f"{name}.{p}"] for p in "ABCD"), dt=dt)
            for name, dt in (("T", h.dt_T), ("S", h.dt_S)))
    return ExchangeMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                           T=T, S=S, e=arrays["e"], wf=arrays["wf"])


def decode(data: bytes | bytearray | memoryview) -> Message:
    """Parse and validate an untrusted byte string produced by :func:`encode`.

    Parameters
    ----------
    data : bytes | bytearray | memoryview
        The received bytes. Nothing is allocated from the declared sizes until the header has
        passed every limit check and the byte count matches it exactly.

    Returns
    -------
    ExchangeMessage | InversionMessage
        Arrays are owned, read-only float64 copies (never views into ``data``).

    Raises
    ------
    MessageError
        For every input that is not a valid message (wrong type, magic, version, message type
        or mechanism; truncated; trailing bytes; oversized; wrong dimensions; non-finite
        values; unstable dynamics). No other exception escapes, whatever the input.
    """
    try:
        return _decode(data)
    except MessageError:
        raise
    except (struct.error, ValueError, TypeError, IndexError, OverflowError, MemoryError,
            np.linalg.LinAlgError, FloatingPointError) as err:
        # Defence in depth: the checks above should make these unreachable, but a hostile
        # input must never surface as anything other than a refused message.
        raise MessageError(f"malformed message: {type(err).__name__}: {err}") from err


# --- examples ------------------------------------------------------------------------------------

_EXAMPLE_SAMPLE_RATE = 200.0
_EXAMPLE_N_SAMPLES = 400
# 600 = 1.5 * 400 is what SegmentGrid's default padding gives for N = 400; only ">= n_samples" matters here.
_EXAMPLE_LENGTH = 600
_EXAMPLE_ORDERS = (4, 6)


def _random_stable_system(order: int, dt: float, rng: np.random.Generator) -> StateSpaceData:
    """A random 2x2 system whose A is scaled to spectral radius 0.9."""
    A = rng.standard_normal((order, order))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
    return StateSpaceData(A, rng.standard_normal((order, _CHANNELS)), rng.standard_normal((_CHANNELS, order)),
                          rng.standard_normal((_CHANNELS, _CHANNELS)), dt)


def example_message(mechanism: str = "paper", *, rng=None) -> Message:
    """A small valid message of the given mechanism, with random content.

    Parameters
    ----------
    mechanism : {"none", "paper", "hardened", "fused"}
    rng : numpy.random.Generator | int | None
        Random source or seed (None: fresh entropy).

    Returns
    -------
    ExchangeMessage | InversionMessage
        ``sample_rate`` 200 Hz, ``n_samples`` 400, signals of 600 rows; for exchange
        mechanisms ``T`` of order 4 and ``S`` of order 6 with spectral radius 0.9; for
        "fused" ``count`` 3.
    """
    if not isinstance(mechanism, str) or mechanism not in MECHANISM_CODES:
        raise MessageError(f"mechanism must be one of {sorted(MECHANISM_CODES)}, got {mechanism!r}")
    rng = np.random.default_rng(rng)
    fs, n, L = _EXAMPLE_SAMPLE_RATE, _EXAMPLE_N_SAMPLES, _EXAMPLE_LENGTH
    if _MECHANISM_TYPE[mechanism] == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=mechanism, sample_rate=fs, n_samples=n,
                                z=rng.standard_normal((L, _CHANNELS)), count=1 if mechanism == "hardened" else 3)
    T, S = (_random_stable_system(order, 1.0 / fs, rng) for order in _EXAMPLE_ORDERS)
    return ExchangeMessage(mechanism=mechanism, sample_rate=fs, n_samples=n, T=T, S=S,
                           e=rng.standard_normal((L, _CHANNELS)), wf=rng.standard_normal((L, _CHANNELS)))


def write_example(path: str | PathLike, mechanism: str = "paper", seed: int = 0) -> int:
    """Encode ``example_message(mechanism, rng=seed)`` to ``path``.

    Parameters
    ----------
    path : str | os.PathLike
        Output file (overwritten).
    mechanism : {"none", "paper", "hardened", "fused"}
    seed : int
        Seed of the random content.

    Returns
    -------
    int
        Number of bytes written.
    """
    data = encode(example_message(mechanism, rng=seed))
    Path(path).write_bytes(data)
    return len(data)
