"""Byte-level framing of the secure-aggregation messages: 48-byte header and payload fields.

As in :mod:`.framing`, decoding only parses here; :mod:`~roadcollab.wire.limits` decides whether the values are
acceptable and :mod:`roadcollab.wire.protocol` runs the steps in order (nothing is read from the
payload before the header has passed every check and the byte count matches it exactly).
"""

from __future__ import annotations

import numpy as np

from typing import Any

from ..errors import MessageError
from .layout import (CHANNELS, FORMAT_VERSION, KEY_NBYTES, MAGIC, MECHANISM_CODES, MESSAGE_TYPE_KEY_ADVERT,
                     MESSAGE_TYPE_MASKED_INPUT, MESSAGE_TYPE_SEALED_SHARES, SEALED_NBYTES, SECAGG_HEADER_NBYTES,
                     SECAGG_STRUCT, SHARE_ENTRY_NBYTES, SHARE_NBYTES, U8, SecAggHeader)

__all__ = ["read_secagg_header", "read_secagg_fields", "pack_secagg"]

_ID_NBYTES = SHARE_ENTRY_NBYTES - SHARE_NBYTES


def read_secagg_header(buf: memoryview, mechanism: str) -> SecAggHeader:
    """Parse the 48-byte header of a message whose 8-byte prefix named a secure-aggregation type.

    Parameters
    ----------
    buf : memoryview
        The whole received message; its 8-byte prefix passed the checks of
        :func:`~.framing.read_header`.
    mechanism : str
        The mechanism named by the prefix.

    Returns
    -------
    SecAggHeader
        As declared; not yet checked against the limits.

    Raises
    ------
    MessageError
        If ``buf`` is shorter than the header.
    """
    if len(buf) < SECAGG_HEADER_NBYTES:
        raise MessageError(f"truncated: the secure-aggregation header needs {SECAGG_HEADER_NBYTES} bytes, "
                           f"got {len(buf)}")
    _, _, msg_type, _, _, session, payload_nbytes, vehicle, n1, n2, reserved = SECAGG_STRUCT.unpack_from(buf, 0)
    return SecAggHeader(msg_type, session, payload_nbytes, vehicle, n1, n2, reserved, mechanism)


def _read_shares(buf: memoryview, offset: int, count: int) -> list[tuple[int, int]]:
    """``count`` entries (owner uint32, share 66 bytes little-endian) from ``offset``, in wire order."""
    out = []
    for k in range(count):
        at = offset + k * SHARE_ENTRY_NBYTES
        owner = int.from_bytes(buf[at:at + _ID_NBYTES], "little")
        out.append((owner, int.from_bytes(buf[at + _ID_NBYTES:at + SHARE_ENTRY_NBYTES], "little")))
    return out


def read_secagg_fields(buf: memoryview, h: SecAggHeader) -> dict[str, Any]:
    """The payload fields of a message whose header passed the checks and whose size matches it.

    Parameters
    ----------
    buf : memoryview
        The received message.
    h : SecAggHeader
        Its checked header.

    Returns
    -------
    dict
        ``c_pk``, ``s_pk`` (bytes); ``ciphertext`` (bytes); ``y`` (an owned, read-only native
        ``uint64`` (L, 2) copy); or ``self_mask_shares``, ``key_shares`` (lists of ``(owner, share)``).
    """
    at = SECAGG_HEADER_NBYTES
    if h.msg_type == MESSAGE_TYPE_KEY_ADVERT:
        return {"c_pk": bytes(buf[at:at + KEY_NBYTES]), "s_pk": bytes(buf[at + KEY_NBYTES:at + 2 * KEY_NBYTES])}
    if h.msg_type == MESSAGE_TYPE_SEALED_SHARES:
        return {"ciphertext": bytes(buf[at:at + SEALED_NBYTES])}
    if h.msg_type == MESSAGE_TYPE_MASKED_INPUT:
        # np.array copies, so y never aliases the caller's (possibly mutable) buffer.
        y = np.array(np.frombuffer(buf, dtype=U8, count=CHANNELS * h.n1, offset=at).reshape(h.n1, CHANNELS),
                     dtype=np.uint64, order="C")
        y.setflags(write=False)
        return {"y": y}
    return {"self_mask_shares": _read_shares(buf, at, h.n1),
            "key_shares": _read_shares(buf, at + h.n1 * SHARE_ENTRY_NBYTES, h.n2)}


def _pack_shares(entries: list[tuple[int, int]]) -> bytes:
    """Entries (owner, share) as uint32 and 66 little-endian bytes each."""
    return b"".join(o.to_bytes(_ID_NBYTES, "little") + y.to_bytes(SHARE_NBYTES, "little") for o, y in entries)


def pack_secagg(h: SecAggHeader, fields: dict[str, Any]) -> bytes:
    """The bytes of a checked secure-aggregation message: header, then the payload fields.

    Parameters
    ----------
    h : SecAggHeader
        Checked by :func:`~.limits.check_header`, with ``payload_nbytes`` set.
    fields : dict
        As from :func:`~.describe.message_fields` (checked by :func:`~.limits.check_payload`).

    Returns
    -------
    bytes
        ``48 + h.payload_nbytes`` bytes.
    """
    head = SECAGG_STRUCT.pack(MAGIC, FORMAT_VERSION, h.msg_type, MECHANISM_CODES[h.mechanism], 0, h.session,
                              h.payload_nbytes, h.vehicle, h.n1, h.n2, 0)
    if h.msg_type == MESSAGE_TYPE_KEY_ADVERT:
        return head + bytes(fields["c_pk"]) + bytes(fields["s_pk"])
    if h.msg_type == MESSAGE_TYPE_SEALED_SHARES:
        return head + bytes(fields["ciphertext"])
    if h.msg_type == MESSAGE_TYPE_MASKED_INPUT:
        return head + np.ascontiguousarray(fields["y"], dtype=U8).tobytes()
    return head + _pack_shares(fields["self_mask_shares"]) + _pack_shares(fields["key_shares"])
