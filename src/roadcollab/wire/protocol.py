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
         5     1  uint8     message type: 1 = ExchangeMessage, 2 = InversionMessage,
                            3-6 = secure aggregation (own 48-byte header, below)
         6     1  uint8     mechanism: 1 = "none", 2 = "paper", 3 = "hardened", 4 = "fused",
                            5 = "secure_aggregation" (only with types 3-6, below)
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
stable: the computed spectral radius of A below ``1 - RADIUS_MARGIN`` (1e-6), and a Lyapunov
certificate (``A^T X A - X = -I`` solved, residual verified to ``LYAPUNOV_RTOL`` = 1e-8
relative, ``X`` positive definite) bounding every power, ``||A^k||_2 <= sqrt(cond X) <=
MAX_TRANSIENT_GAIN`` (1e8). The certificate does not rest on computed eigenvalues, which a
non-normal A can fool (a 64x64 Jordan block, eigenvalue 0.99, corner 1e-16: true radius 1.55,
computed 0.99). Honest messages measured (default fleet, all mechanisms): radius <= 0.99959,
``sqrt(cond X)`` <= 4.4e3. A message whose eigenvalues or certificate cannot be computed is
refused too.

:func:`encode` runs exactly the same checks, so it never produces a message that
:func:`decode` would refuse.

Secure aggregation
------------------
The four rounds of :mod:`roadcollab.privacy.secure_aggregation` (vehicle <-> aggregator) share
the first 8 bytes above (magic, version, type, mechanism 5 = "secure_aggregation", reserved 0)
and then have their own 48-byte header (``"<4sBBBB16sQIIII"``)::

    offset  size  type      field
    ------  ----  --------  -----------------------------------------------------------
         0     8            prefix as above; type 3, 4, 5 or 6; mechanism 5
         8    16  2 uint64  session: segment, round (``session_id``)
        24     8  uint64    payload byte count (everything after the 48-byte header)
        32     4  uint32    vehicle: the sender's id, >= 1
        36     4  uint32    n1: type 4 recipient id; type 5 L; type 6 entries of b shares; else 0
        40     4  uint32    n2: type 6 entries of s shares; else 0
        44     4  uint32    reserved, must be 0
        48        payload   by type:

    type  message       payload                                                   bytes
    ----  ------------  --------------------------------------------------------  ---------------
       3  KeyAdvert     c_pk (32), s_pk (32): raw X25519 public keys               64
       4  SealedShares  ChaCha20-Poly1305 ciphertext of (sender u32, recipient     156
                        u32, share of s_sk 66, share of b 66) + 16-byte tag
       5  MaskedInput   y (L, 2) '<u8', row-major: ring elements mod 2^64          16 L
       6  Reveal        n1 + n2 entries (owner u32, share 66 bytes little-endian):  70 (n1 + n2)
                        first the shares of b_i (survivors), then of s_i
                        (dropped), each list by strictly increasing owner id

Limits: ids in ``[1, 2**32 - 1]``, a sealed share not addressed to its sender, ``1 <= L <=
MAX_SIGNAL_LENGTH``, ``1 <= n1 + n2 <= MAX_VEHICLES`` (10,000), unused counts 0, shares in
``[0, 2**521 - 1)`` and no owner in both lists of a reveal. Keys, ciphertexts and ring elements
take any value: their validity is cryptographic and checked by the protocol (X25519, the AEAD
tag, Shamir consistency), which raises ``MessageError`` too. The encoding is canonical:
whatever :func:`decode` accepts, :func:`encode` reproduces byte for byte.

Modules
-------
This module is the public entry point. The layout (codes, ``struct`` headers, sizes) is
stated in :mod:`.layout`, the limits and the checks above in :mod:`~roadcollab.wire.limits`, the byte-level
framing in :mod:`.framing` (secure aggregation: :mod:`.secagg_framing`), the message objects in
:mod:`~roadcollab.wire.message` and :mod:`.secagg`, and the conversion between message objects and header plus
arrays in :mod:`.describe` and :mod:`.fields`.
"""

from __future__ import annotations

import struct
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import MessageError
from .examples import example_message
from .describe import message_fields, validate_message
from ..lti.realisation import SystemCache
from .fields import Message, build_message
from .framing import as_buffer, check_frame_size, pack_message, read_header
# _decode calls it through this module's namespace, so a test can replace protocol._read_array
# to prove that an oversized header is refused before any payload array is read.
from .framing import read_array as _read_array
from .layout import (COMMON_HEADER_NBYTES, EXCHANGE_HEADER_NBYTES, FLOAT_NBYTES, FORMAT_VERSION,
                     INVERSION_HEADER_NBYTES, MAGIC, MECHANISM_CODES, MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION,
                     SECAGG_HEADER_NBYTES, SecAggHeader, exchange_nbytes, inversion_nbytes, payload_shapes)
from .limits import (DT_RTOL, MAX_COUNT, MAX_MESSAGE_BYTES, MAX_ORDER, MAX_SAMPLE_RATE, MAX_SIGNAL_LENGTH,
                     MAX_VEHICLES, check_header, check_payload)
from .secagg_framing import read_secagg_fields

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
    "SECAGG_HEADER_NBYTES",
    "MAX_VEHICLES",
    "encode",
    "decode",
    "exchange_nbytes",
    "inversion_nbytes",
    "message_nbytes",
    "example_message",
    "write_example",
]


def message_nbytes(message: Message) -> int:
    """Size in bytes of ``encode(message)``, from the array shapes (nothing is encoded).

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal

    Returns
    -------
    int
        Header plus payload bytes.

    Raises
    ------
    MessageError
        If ``message`` is not a message or its arrays have wrong types or shapes.
    """
    h, _ = message_fields(message)
    return h.header_nbytes + h.payload_nbytes


def encode(message: Message) -> bytes:
    """Serialise a message to the binary wire format (see the module docstring).

    Parameters
    ----------
    message : ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal

    Returns
    -------
    bytes
        ``message_nbytes(message)`` bytes.

    Raises
    ------
    MessageError
        If the message is malformed, out of the limits, non-finite or has unstable dynamics:
        it runs the checks of :func:`decode`, so only decodable bytes are ever produced.

    Examples
    --------
    >>> from roadcollab.wire.examples import example_message
    >>> data = encode(example_message("hardened"))
    >>> decode(data).mechanism
    'hardened'
    >>> decode(data[:-1])
    Traceback (most recent call last):
        ...
    roadcollab.errors.MessageError: ...
    """
    h, arrays = validate_message(message)
    return pack_message(h, arrays)


def _decode(data: object, systems: SystemCache | None = None) -> Message:
    """:func:`decode` without the final conversion of unexpected exceptions."""
    buf = as_buffer(data)
    h = read_header(buf)
    check_header(h)
    check_frame_size(h, len(buf))
    if isinstance(h, SecAggHeader):
        fields = read_secagg_fields(buf, h)
        check_payload(h, fields)     # the wire order of a reveal's shares, before they become dicts
        return build_message(h, fields)
    arrays: dict[str, np.ndarray] = {}
    offset = h.header_nbytes
    for name, shape in payload_shapes(h):
        arrays[name] = _read_array(buf, offset, shape)
        offset += FLOAT_NBYTES * shape[0] * shape[1]
    # The message validates its content on construction (check_payload, once).
    return build_message(h, arrays, systems=systems)


def decode(data: bytes | bytearray | memoryview, *, systems: SystemCache | None = None) -> Message:
    """Parse and validate an untrusted byte string produced by :func:`encode`.

    Parameters
    ----------
    data : bytes | bytearray | memoryview
        The received bytes. Nothing is allocated from the declared sizes until the header has
        passed every limit check and the byte count matches it exactly.
    systems : SystemCache, optional
        The receiver's cache of systems by content (:class:`~roadcollab.lti.realisation.SystemCache`):
        a ``T`` or ``S`` with exactly the bytes of one decoded before is that same object, so its
        stability certificate is not computed again (every check still runs on it).

    Returns
    -------
    ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal
        Arrays are owned, read-only float64 (``y``: uint64) copies (never views into ``data``).
        A receiver that expects one type checks it (``isinstance``): every type decodes here.

    Raises
    ------
    MessageError
        For every input that is not a valid message (wrong type, magic, version, message type
        or mechanism; truncated; trailing bytes; oversized; wrong dimensions; non-finite
        values; unstable dynamics). No other exception escapes, whatever the input.
    """
    try:
        return _decode(data, systems)
    except MessageError:
        raise
    except (struct.error, ValueError, TypeError, IndexError, OverflowError, MemoryError,
            np.linalg.LinAlgError, FloatingPointError) as err:
        # Defence in depth: the checks above should make these unreachable, but a hostile
        # input must never surface as anything other than a refused message.
        raise MessageError(f"malformed message: {type(err).__name__}: {err}") from err


def write_example(path: str | PathLike[str], mechanism: str = "paper", seed: int = 0) -> int:
    """Encode ``example_message(mechanism, rng=seed)`` to ``path``.

    Parameters
    ----------
    path : str | os.PathLike
        Output file (overwritten).
    mechanism : {"none", "paper", "hardened", "fused", "secure_aggregation"}
        ``"secure_aggregation"`` writes a masked input (:class:`~.secagg.MaskedInput`).
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
