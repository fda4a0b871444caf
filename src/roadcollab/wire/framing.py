"""Byte-level framing: header bytes to and from :class:`~.layout.Header`, arrays to and from bytes.

Decoding only parses here: whether the parsed values are acceptable is decided by
:mod:`~roadcollab.wire.limits`, and :mod:`roadcollab.wire.protocol` runs the steps in order so that nothing is
allocated from a declared size before the header has passed every check.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import MessageError
from .layout import (COMMON_HEADER_NBYTES, COMMON_STRUCT, EXCHANGE_EXT_STRUCT, F8, FORMAT_VERSION,
                     INVERSION_EXT_STRUCT, MAGIC, MECHANISM_CODES, MECHANISM_NAMES, MESSAGE_TYPE_EXCHANGE,
                     PREFIX_STRUCT, SECAGG_TYPES, TYPE_NAMES, Header, SecAggHeader, payload_shapes)
from .limits import MAX_MESSAGE_BYTES
from .secagg_framing import pack_secagg, read_secagg_header

__all__ = ["as_buffer", "read_header", "check_frame_size", "read_array", "pack_message"]


def as_buffer(data: object) -> memoryview:
    """A flat, C-contiguous byte view of ``data`` (bytes, bytearray or memoryview).

    Parameters
    ----------
    data : bytes | bytearray | memoryview
        Untrusted input.

    Returns
    -------
    memoryview
        Of format ``"B"``; a copy only when ``data`` is not contiguous.

    Raises
    ------
    MessageError
        For any other type.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"message must be bytes, bytearray or memoryview, got {type(data).__name__}")
    view = memoryview(data)
    if not view.c_contiguous:
        view = memoryview(view.tobytes())
    return view.cast("B")


def _read_prefix(buf: memoryview) -> tuple[int, str]:
    """The 8-byte prefix common to every message type (magic, version, type, mechanism, reserved byte),
    after the size checks: ``(message type, mechanism name)``."""
    size = len(buf)
    if bytes(buf[:len(MAGIC)]) != MAGIC[:min(size, len(MAGIC))]:
        raise MessageError(f"wrong magic: expected {MAGIC!r}, got {bytes(buf[:len(MAGIC)])!r}")
    if size < COMMON_HEADER_NBYTES:
        raise MessageError(f"truncated: the header needs {COMMON_HEADER_NBYTES} bytes, got {size}")
    if size > MAX_MESSAGE_BYTES:
        raise MessageError(f"oversized: {size} bytes exceeds MAX_MESSAGE_BYTES = {MAX_MESSAGE_BYTES}")
    _, version, msg_type, mech_code, reserved = PREFIX_STRUCT.unpack_from(buf, 0)
    if version != FORMAT_VERSION:
        raise MessageError(f"unsupported format version {version}, expected {FORMAT_VERSION}")
    if msg_type not in TYPE_NAMES:
        raise MessageError(f"unknown message type {msg_type}, expected one of "
                           + ", ".join(f"{k} ({v})" for k, v in TYPE_NAMES.items()))
    if mech_code not in MECHANISM_NAMES:
        raise MessageError(f"unknown mechanism code {mech_code}, expected one of "
                           + ", ".join(f"{k} ({v!r})" for k, v in MECHANISM_NAMES.items()))
    if reserved != 0:
        raise MessageError(f"reserved header byte 7 must be 0, got {reserved}")
    return msg_type, MECHANISM_NAMES[mech_code]


def _read_common(buf: memoryview, msg_type: int, mechanism: str) -> Header:
    """The common 32-byte header of an exchange or inversion message whose prefix passed."""
    *_, sample_rate, n_samples, length, payload_nbytes = COMMON_STRUCT.unpack_from(buf, 0)
    return Header(msg_type, mechanism, sample_rate, n_samples, length, payload_nbytes)


def _read_extension(buf: memoryview, h: Header) -> Header:
    """``h`` completed with the fields of its type's header extension."""
    if len(buf) < h.header_nbytes:
        raise MessageError(f"truncated: the {TYPE_NAMES[h.msg_type]} header needs {h.header_nbytes} bytes, "
                           f"got {len(buf)}")
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        order_T, order_S, dt_T, dt_S = EXCHANGE_EXT_STRUCT.unpack_from(buf, COMMON_HEADER_NBYTES)
        return h._replace(order_T=order_T, order_S=order_S, dt_T=dt_T, dt_S=dt_S)
    count, reserved = INVERSION_EXT_STRUCT.unpack_from(buf, COMMON_HEADER_NBYTES)
    if reserved != 0:
        raise MessageError(f"reserved inversion header field must be 0, got {reserved}")
    return h._replace(count=count)


def read_header(buf: memoryview) -> Header | SecAggHeader:
    """Parse the full header, refusing whatever the bytes alone show to be malformed.

    Parameters
    ----------
    buf : memoryview
        From :func:`as_buffer`: the whole received message.

    Returns
    -------
    Header | SecAggHeader
        As declared (a SecAggHeader for the secure-aggregation types); its values are not yet
        checked against the limits.

    Raises
    ------
    MessageError
        Wrong magic, unsupported version, unknown message type or mechanism code, non-zero
        reserved fields (of exchange and inversion headers; a secure-aggregation header's are
        checked by :func:`~.limits.check_header`), a byte string shorter than the header or
        longer than ``MAX_MESSAGE_BYTES``.
    """
    msg_type, mechanism = _read_prefix(buf)
    if msg_type in SECAGG_TYPES:
        return read_secagg_header(buf, mechanism)
    return _read_extension(buf, _read_common(buf, msg_type, mechanism))


def check_frame_size(h: Header | SecAggHeader, size: int) -> None:
    """Refuse a byte string that is not exactly header plus declared payload long.

    Parameters
    ----------
    h : Header | SecAggHeader
        A header that passed :func:`~.limits.check_header`.
    size : int
        Length of the received byte string, bytes.

    Raises
    ------
    MessageError
        "truncated" if it is shorter, "trailing data" if it is longer.
    """
    actual = size - h.header_nbytes
    if actual < h.payload_nbytes:
        raise MessageError(f"truncated: header declares {h.payload_nbytes} payload bytes, got {actual}")
    if actual > h.payload_nbytes:
        raise MessageError(f"trailing data: header declares {h.payload_nbytes} payload bytes, "
                           f"got {actual} ({actual - h.payload_nbytes} extra)")


def read_array(buf: memoryview, offset: int, shape: tuple[int, int]) -> np.ndarray:
    """An owned, read-only native float64 copy of ``shape`` floats at ``offset``.

    Parameters
    ----------
    buf : memoryview
        The received message.
    offset : int
        Byte offset of the first float.
    shape : (int, int)
        Rows and columns, row-major on the wire.

    Returns
    -------
    numpy.ndarray
        float64 of the given shape, never aliasing ``buf``.
    """
    count = shape[0] * shape[1]
    # np.array copies, so the result never aliases the caller's (possibly mutable) buffer.
    arr = np.array(np.frombuffer(buf, dtype=F8, count=count, offset=offset).reshape(shape),
                   dtype=np.float64, order="C")
    arr.setflags(write=False)
    return arr


def pack_message(h: Header | SecAggHeader, arrays: dict[str, Any]) -> bytes:
    """The bytes of a checked message: header, extension, then the arrays in wire order.

    Parameters
    ----------
    h : Header | SecAggHeader
        With ``payload_nbytes`` set; checked by :func:`~.limits.check_header`.
    arrays : dict
        Payload arrays by wire name, as from :func:`~.describe.message_fields`.

    Returns
    -------
    bytes
        ``h.header_nbytes + h.payload_nbytes`` bytes.
    """
    if isinstance(h, SecAggHeader):
        return pack_secagg(h, arrays)
    head = COMMON_STRUCT.pack(MAGIC, FORMAT_VERSION, h.msg_type, MECHANISM_CODES[h.mechanism], 0,
                              h.sample_rate, h.n_samples, h.length, h.payload_nbytes)
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        head += EXCHANGE_EXT_STRUCT.pack(h.order_T, h.order_S, h.dt_T, h.dt_S)
    else:
        head += INVERSION_EXT_STRUCT.pack(h.count, 0)
    parts = [head] + [np.ascontiguousarray(arrays[name], dtype=F8).tobytes() for name, _ in payload_shapes(h)]
    return b"".join(parts)
