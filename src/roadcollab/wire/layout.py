"""Byte layout of the wire format: codes, ``struct`` headers, array order and sizes.

Described in full in :mod:`roadcollab.wire.protocol`. This module only states the layout;
whether a header's values are acceptable is decided in :mod:`.limits`.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "MESSAGE_TYPE_EXCHANGE",
    "MESSAGE_TYPE_INVERSION",
    "TYPE_NAMES",
    "MECHANISM_CODES",
    "MECHANISM_NAMES",
    "MECHANISM_TYPE",
    "COMMON_STRUCT",
    "EXCHANGE_EXT_STRUCT",
    "INVERSION_EXT_STRUCT",
    "COMMON_HEADER_NBYTES",
    "EXCHANGE_HEADER_NBYTES",
    "INVERSION_HEADER_NBYTES",
    "F8",
    "FLOAT_NBYTES",
    "CHANNELS",
    "exchange_nbytes",
    "inversion_nbytes",
    "Header",
    "payload_shapes",
]

MAGIC = b"RCOL"
FORMAT_VERSION = 1

MESSAGE_TYPE_EXCHANGE = 1
MESSAGE_TYPE_INVERSION = 2
TYPE_NAMES = {MESSAGE_TYPE_EXCHANGE: "exchange", MESSAGE_TYPE_INVERSION: "inversion"}

# Codes start at 1 so that an all-zero header can never be a valid message.
MECHANISM_CODES = {"none": 1, "paper": 2, "hardened": 3, "fused": 4}
MECHANISM_NAMES = {code: name for name, code in MECHANISM_CODES.items()}
MECHANISM_TYPE = {"none": MESSAGE_TYPE_EXCHANGE, "paper": MESSAGE_TYPE_EXCHANGE,
                  "hardened": MESSAGE_TYPE_INVERSION, "fused": MESSAGE_TYPE_INVERSION}

COMMON_STRUCT = struct.Struct("<4sBBBBdIIQ")
EXCHANGE_EXT_STRUCT = struct.Struct("<IIdd")
INVERSION_EXT_STRUCT = struct.Struct("<II")

COMMON_HEADER_NBYTES = COMMON_STRUCT.size                                # 32
EXCHANGE_HEADER_NBYTES = COMMON_STRUCT.size + EXCHANGE_EXT_STRUCT.size   # 56
INVERSION_HEADER_NBYTES = COMMON_STRUCT.size + INVERSION_EXT_STRUCT.size  # 40

F8 = np.dtype("<f8")
FLOAT_NBYTES = F8.itemsize
CHANNELS = 2  # every system is 2x2 and every signal has two channels (left, right track)


def _system_floats(order: int) -> int:
    """Entries of A, B, C, D of a 2x2 system of the given order: ``(order + 2)**2``."""
    return (order + CHANNELS) ** 2


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
    floats = _system_floats(order_T) + _system_floats(order_S) + 2 * CHANNELS * length
    return EXCHANGE_HEADER_NBYTES + FLOAT_NBYTES * floats


def inversion_nbytes(length: int) -> int:
    """Encoded size of an :class:`InversionMessage` with ``z`` of ``length`` rows: ``40 + 16 * length``.

    Parameters
    ----------
    length : int
        Rows ``L`` of ``z``.

    Returns
    -------
    int
        Bytes.
    """
    return INVERSION_HEADER_NBYTES + FLOAT_NBYTES * CHANNELS * length


class Header(NamedTuple):
    """All header fields, for both message types (unused ones are 0).

    Parameters
    ----------
    msg_type : int
        ``MESSAGE_TYPE_EXCHANGE`` or ``MESSAGE_TYPE_INVERSION``.
    mechanism : str
        A key of ``MECHANISM_CODES``.
    sample_rate : float
        Hz.
    n_samples : int
        Samples in the recorded window.
    length : int
        Rows ``L`` of every (L, 2) signal.
    payload_nbytes : int
        Payload byte count as declared (decode) or implied by the dimensions (encode).
    order_T, order_S : int
        State dimensions of ``T`` and ``S`` (exchange only).
    dt_T, dt_S : float
        Sample times of ``T`` and ``S``, s (exchange only).
    count : int
        Vehicles whose inversions ``z`` averages (inversion only).
    """

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
        """Size of the full header (common part and type extension), bytes."""
        return EXCHANGE_HEADER_NBYTES if self.msg_type == MESSAGE_TYPE_EXCHANGE else INVERSION_HEADER_NBYTES

    def expected_payload_nbytes(self) -> int:
        """Payload size implied by the dimensions, bytes."""
        if self.msg_type == MESSAGE_TYPE_EXCHANGE:
            return exchange_nbytes(self.order_T, self.order_S, self.length) - EXCHANGE_HEADER_NBYTES
        return inversion_nbytes(self.length) - INVERSION_HEADER_NBYTES


def payload_shapes(h: Header) -> list[tuple[str, tuple[int, int]]]:
    """Names and shapes of the payload arrays, in wire order.

    Parameters
    ----------
    h : Header

    Returns
    -------
    list of (str, (int, int))
        ``"T.A"``, ..., ``"S.D"``, ``"e"``, ``"wf"`` for an exchange message, ``"z"`` for an
        inversion message.
    """
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return [("z", (h.length, CHANNELS))]
    shapes = []
    for name, n in (("T", h.order_T), ("S", h.order_S)):
        shapes += [(f"{name}.A", (n, n)), (f"{name}.B", (n, CHANNELS)),
                   (f"{name}.C", (CHANNELS, n)), (f"{name}.D", (CHANNELS, CHANNELS))]
    return shapes + [("e", (h.length, CHANNELS)), ("wf", (h.length, CHANNELS))]
