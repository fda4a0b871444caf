"""The fleet's relay key: the waiting message of a segment sealed so that only fleet vehicles read it.

Under secure aggregation the service must not learn any vehicle's inversion (that is what the rounds
hide), yet the inversion is also the message the next vehicle on the segment learns from (Algorithm 1).
The service stores and forwards that message without being able to read it: the vehicle encrypts it
to the fleet's relay key, an X25519 key pair that ``roadcollab enroll`` writes into every vehicle's
folder (``relay.key``, mode 0600) and into no service folder.

Each message: an ephemeral X25519 key, HKDF-SHA256 of the shared secret with ``info`` binding the
version and the topic, and ChaCha20-Poly1305 with the topic as associated data (one key per message,
so a fixed nonce). Wire form ``eph_pub (32) | ciphertext + tag``.

What it holds against (docs/network.md, threat model): the service and anyone on the broker without a
vehicle's folder read no relayed inversion. Any enrolled vehicle can open every relayed message it is
given; a service colluding with one vehicle reads them all (the paper's relay gives each vehicle its
predecessor's message by design; a per-recipient key would need the next vehicle known when the
previous one drives).
"""

from __future__ import annotations

import os
from pathlib import Path

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from ..errors import FileFormatError, MessageError

__all__ = ["RelayKey", "seal_to"]

_INFO = b"roadcollab/relay/v1|"
_NONCE = bytes(12)


def _key(shared: bytes, topic: str) -> bytes:
    return HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=_INFO + topic.encode()).derive(shared)


def seal_to(public: bytes, topic: str, data: bytes) -> bytes:
    """``data`` encrypted to the holder of the X25519 key ``public`` for ``topic`` (module docstring's form).

    Parameters
    ----------
    public : bytes
        Raw 32-byte X25519 public key of the recipient.
    topic : str
        Bound as associated data and into the key.
    data : bytes

    Raises
    ------
    MessageError
        ``public`` is not a valid X25519 key.
    """
    eph = X25519PrivateKey.generate()
    try:
        k = _key(eph.exchange(X25519PublicKey.from_public_bytes(bytes(public))), topic)
    except ValueError as err:
        raise MessageError(f"{topic}: invalid X25519 public key of the recipient ({err})") from None
    pub = eph.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return pub + ChaCha20Poly1305(k).encrypt(_NONCE, bytes(data), topic.encode())


class RelayKey:
    """The fleet's relay key pair.

    Parameters
    ----------
    private_key : X25519PrivateKey
    """

    def __init__(self, private_key: X25519PrivateKey) -> None:
        self._sk = private_key
        self.public = private_key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)

    @classmethod
    def generate(cls) -> "RelayKey":
        return cls(X25519PrivateKey.generate())

    def save(self, path) -> Path:
        """Write the private key (raw 32 bytes, mode 0600; an existing file is never replaced).

        Parameters
        ----------
        path : str or Path
        """
        path = Path(path)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(self._sk.private_bytes(serialization.Encoding.Raw, serialization.PrivateFormat.Raw,
                                            serialization.NoEncryption()))
        return path

    @classmethod
    def load(cls, path) -> "RelayKey":
        """Read ``relay.key``.

        Parameters
        ----------
        path : str or Path

        Raises
        ------
        FileFormatError
            Missing or not 32 bytes.
        """
        path = Path(path)
        try:
            raw = path.read_bytes()
        except OSError as err:
            raise FileFormatError(f"{path}: cannot read the fleet relay key ({err.strerror}); secure aggregation "
                                  "needs the relay.key that 'roadcollab enroll' writes") from None
        if len(raw) != 32:
            raise FileFormatError(f"{path}: expected a 32-byte X25519 key, got {len(raw)} bytes")
        return cls(X25519PrivateKey.from_private_bytes(raw))

    def seal(self, topic: str, data: bytes) -> bytes:
        """``data`` encrypted to the fleet for ``topic``.

        Parameters
        ----------
        topic : str
            Bound as associated data (a message moved to another topic does not open).
        data : bytes
        """
        return seal_to(self.public, topic, data)

    def agree(self, public: bytes, info: bytes) -> bytes:
        """A 32-byte key shared with the holder of ``public``: HKDF-SHA256 of the X25519 secret with ``info``.

        Parameters
        ----------
        public : bytes
            The peer's raw X25519 public key (untrusted bytes: checked).
        info : bytes
            Domain separation (protocol, session).

        Raises
        ------
        MessageError
            ``public`` is not a valid X25519 key.
        """
        try:
            shared = self._sk.exchange(X25519PublicKey.from_public_bytes(bytes(public)))
        except ValueError as err:
            raise MessageError(f"invalid X25519 public key ({err})") from None
        return HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=bytes(info)).derive(shared)

    def open(self, topic: str, blob: bytes) -> bytes:
        """The plaintext of :meth:`seal`.

        Parameters
        ----------
        topic : str
        blob : bytes

        Raises
        ------
        MessageError
            Too short, or not sealed to this fleet for this topic.
        """
        blob = bytes(blob)
        if len(blob) < 32 + 16:
            raise MessageError(f"{topic}: sealed relay message too short ({len(blob)} bytes)")
        try:
            k = _key(self._sk.exchange(X25519PublicKey.from_public_bytes(blob[:32])), topic)
            return ChaCha20Poly1305(k).decrypt(_NONCE, blob[32:], topic.encode())
        except (InvalidTag, ValueError):
            raise MessageError(f"{topic}: the relay message does not open with the fleet's relay key") from None
