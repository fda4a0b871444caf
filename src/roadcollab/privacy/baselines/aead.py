"""Authenticated encryption of the channel (eavesdropper model): ChaCha20-Poly1305.

Protects the messages against an eavesdropper only; the receiving vehicle still sees
everything. Keys and nonces come from :func:`os.urandom` (intended, cannot be seeded).
:mod:`cryptography` is imported only when a message is sealed or opened.
"""

from __future__ import annotations

from typing import Any

import os

from ..._validation import check_int
from ...errors import MessageError, ParameterError
from ...wire.message import ExchangeMessage, InversionMessage
from ...wire.protocol import encode
from .timing import median_ms

__all__ = ["AEAD_KEY_BYTES", "AEAD_NONCE_BYTES", "AEAD_TAG_BYTES", "AEAD_OVERHEAD_BYTES", "new_key", "seal",
           "open_sealed", "aead_cost"]

AEAD_KEY_BYTES = 32
AEAD_NONCE_BYTES = 12
AEAD_TAG_BYTES = 16
AEAD_OVERHEAD_BYTES = AEAD_NONCE_BYTES + AEAD_TAG_BYTES   # 28


def _as_bytes(name: str, value: object, error: type[Exception] = ParameterError) -> bytes:
    """``value`` as ``bytes``; ``error`` (ParameterError or, for untrusted input, MessageError) otherwise."""
    if not isinstance(value, (bytes, bytearray, memoryview)):
        raise error(f"{name} must be bytes, got {type(value).__name__}")
    return bytes(value)


def _check_key(key: object) -> bytes:
    """The caller's key as 32 ``bytes`` (a local error, so ParameterError)."""
    key = _as_bytes("key", key)
    if len(key) != AEAD_KEY_BYTES:
        raise ParameterError(f"key must be {AEAD_KEY_BYTES} bytes, got {len(key)}")
    return key


def new_key() -> bytes:
    """A fresh random 32-byte ChaCha20-Poly1305 key (from :func:`os.urandom`)."""
    return os.urandom(AEAD_KEY_BYTES)


def seal(key: bytes, data: bytes, *, associated_data: bytes = b"") -> bytes:
    """Encrypt and authenticate ``data`` with ChaCha20-Poly1305.

    Parameters
    ----------
    key : bytes
        32 bytes, shared by the two vehicles (key agreement is out of scope).
    data : bytes
        Plaintext, e.g. :func:`roadcollab.wire.protocol.encode` of a message.
    associated_data : bytes
        Authenticated but not encrypted (e.g. a segment id); must match on opening.

    Returns
    -------
    bytes
        ``nonce (12 bytes, os.urandom) || ciphertext || tag (16 bytes)``:
        ``len(data) + 28`` bytes. A random 96-bit nonce per message is safe for far more
        messages than a vehicle sends under one key.
    """
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

    key = _check_key(key)
    data = _as_bytes("data", data)
    associated_data = _as_bytes("associated_data", associated_data)
    nonce = os.urandom(AEAD_NONCE_BYTES)
    return nonce + ChaCha20Poly1305(key).encrypt(nonce, data, associated_data)


def open_sealed(key: bytes, blob: bytes, *, associated_data: bytes = b"") -> bytes:
    """Verify and decrypt a blob made by :func:`seal`.

    Parameters
    ----------
    key : bytes
        The 32-byte key (a malformed key is a local error: :class:`ParameterError`).
    blob : bytes
        Untrusted input from the channel.
    associated_data : bytes
        Must equal the value used by :func:`seal`.

    Returns
    -------
    bytes
        The plaintext.

    Raises
    ------
    MessageError
        For anything that is not an authentic blob under this key and associated data:
        wrong key, any modified byte, truncation, non-bytes ``blob``. No other exception
        escapes for untrusted ``blob`` content.
    ParameterError
        If ``key`` is not 32 bytes or ``associated_data`` is not bytes (caller's own values).
    """
    from cryptography.exceptions import InvalidTag
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

    key = _check_key(key)
    associated_data = _as_bytes("associated_data", associated_data)
    blob = _as_bytes("blob", blob, MessageError)
    if len(blob) < AEAD_OVERHEAD_BYTES:
        raise MessageError(f"sealed blob truncated: {len(blob)} bytes, at least {AEAD_OVERHEAD_BYTES} expected")
    try:
        return ChaCha20Poly1305(key).decrypt(blob[:AEAD_NONCE_BYTES], blob[AEAD_NONCE_BYTES:], associated_data)
    except InvalidTag as err:
        raise MessageError("sealed blob failed authentication (wrong key, tampered or truncated)") from err
    except (OverflowError, ValueError) as err:
        raise MessageError(f"sealed blob refused: {err}") from err


def aead_cost(data: bytes, *, repeats: int = 20) -> dict[str, Any]:
    """Cost of sealing one message with ChaCha20-Poly1305 under a fresh key.

    Parameters
    ----------
    data : bytes or ExchangeMessage or InversionMessage
        The wire bytes (a message is encoded with :func:`roadcollab.wire.protocol.encode`).
    repeats : int
        Timed repetitions (>= 1).

    Returns
    -------
    dict
        ``ms_per_message`` (median seal time, ms), ``open_ms_per_message`` (median verify
        and decrypt time, ms), ``bytes_per_message`` (sealed length), ``overhead_bytes``
        (28: 12-byte nonce + 16-byte tag).
    """
    if isinstance(data, (ExchangeMessage, InversionMessage)):
        data = encode(data)
    data = _as_bytes("data", data)
    repeats = check_int("repeats", repeats, low=1)
    key = new_key()
    sealed = seal(key, data)
    if open_sealed(key, sealed) != data:  # pragma: no cover - would be a library bug
        raise RuntimeError("ChaCha20-Poly1305 round trip failed")
    return {
        "ms_per_message": median_ms(lambda: seal(key, data), repeats),
        "open_ms_per_message": median_ms(lambda: open_sealed(key, sealed), repeats),
        "bytes_per_message": len(sealed),
        "overhead_bytes": len(sealed) - len(data),
    }
