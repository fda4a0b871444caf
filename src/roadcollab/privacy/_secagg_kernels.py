"""Kernels of secure aggregation: the fixed-point ring, Shamir sharing, key agreement and the PRG.

Pure functions on bytes, integers and arrays; :mod:`.secure_aggregation` builds the protocol on them.

- **Ring** ``Z_(2^64)``: a value ``x`` (m/s) is clipped to ``[-clip, clip]`` and stored as
  ``round(x * 2^f) mod 2^64`` (two's complement); numpy ``uint64`` arithmetic wraps exactly mod 2^64.
- **Shamir** sharing of 32-byte secrets over ``GF(p)``, ``p = 2^521 - 1`` (a Mersenne prime, so
  every 256-bit secret is a field element); a share is ``(x, y)`` with ``x`` the holder's id, ``y``
  66 bytes.
- **Seeds**: X25519 key agreement, then HKDF-SHA256 whose ``info`` binds the protocol version, the
  session (segment and round), the purpose and the vehicle ids (domain separation).
- **PRG**: the ChaCha20 key stream under a 32-byte seed, read as little-endian ``uint64``.

References
----------
K. Bonawitz et al., "Practical Secure Aggregation for Privacy-Preserving Machine Learning",
ACM CCS 2017, Sec. 4 (the protocol) and Sec. 6 (security).
"""

from __future__ import annotations

import struct

import numpy as np
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.ciphers import Cipher, algorithms
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from ..errors import MessageError
from ..wire.layout import KEY_NBYTES, SHARE_NBYTES
from ..wire.limits import SHARE_MODULUS

__all__ = ["RING_BITS", "SHAMIR_PRIME", "SHARE_NBYTES", "KEY_NBYTES", "DOMAIN", "encode_fixed", "decode_sum",
           "prg_ring", "derive", "expand", "shamir_split", "shamir_combine", "x25519_keypair", "x25519_agree"]

RING_BITS = 64
SHAMIR_PRIME = SHARE_MODULUS   # 2^521 - 1; a share takes SHARE_NBYTES = ceil(521 / 8) = 66 bytes on the wire
DOMAIN = b"roadcollab/secagg/v1"
_CHACHA_NONCE = bytes(16)  # every seed keys exactly one stream (seeds are derived per purpose and session)
_ID = struct.Struct("<I")


def encode_fixed(x: np.ndarray, clip: float, frac_bits: int) -> np.ndarray:
    """``round(clip(x) * 2^frac_bits) mod 2^64`` as ``uint64`` (same shape as ``x``).

    ``clip * 2^frac_bits < 2^53`` (checked by the caller's spec) keeps the rounding exact.
    """
    q = np.rint(np.clip(x, -clip, clip) * float(2 ** frac_bits)).astype(np.int64)
    out: np.ndarray = q.view(np.uint64)
    return out


def decode_sum(total: np.ndarray, frac_bits: int) -> np.ndarray:
    """A ring sum back to float: the ``uint64`` total read as two's complement, times ``2^-frac_bits``."""
    return total.view(np.int64).astype(float) * 2.0 ** -frac_bits


def expand(seed: bytes, nbytes: int) -> bytes:
    """``nbytes`` of the ChaCha20 key stream under the 32-byte ``seed``."""
    enc = Cipher(algorithms.ChaCha20(seed, _CHACHA_NONCE), mode=None).encryptor()
    return enc.update(bytes(nbytes))


def prg_ring(seed: bytes, shape: tuple[int, ...]) -> np.ndarray:
    """A mask of ring elements: ``prod(shape)`` little-endian ``uint64`` of the key stream of ``seed``."""
    size = int(np.prod(shape))
    return np.frombuffer(expand(seed, 8 * size), dtype="<u8").astype(np.uint64).reshape(shape)


def derive(secret: bytes, purpose: bytes, session: bytes, *ids: int) -> bytes:
    """A 32-byte key: HKDF-SHA256 of ``secret`` with ``info = DOMAIN | purpose | session | ids``."""
    info = b"|".join([DOMAIN, purpose, session, b"".join(_ID.pack(i) for i in ids)])
    return HKDF(algorithm=hashes.SHA256(), length=KEY_NBYTES, salt=None, info=info).derive(secret)


def shamir_split(secret: bytes, holders: list[int], threshold: int, coeff_seed: bytes) -> dict[int, int]:
    """Shamir shares of a 32-byte ``secret``: ``{x: f(x)}`` for every holder id ``x`` (all >= 1).

    ``f(X) = secret + a_1 X + ... + a_(t-1) X^(t-1) mod p`` with the coefficients drawn from the
    ChaCha20 stream of ``coeff_seed`` (80 bytes each, reduced mod p: bias below 2^-119).
    Any ``threshold`` shares determine ``secret``; fewer reveal nothing about it.
    """
    p = SHAMIR_PRIME
    stream = expand(coeff_seed, 80 * (threshold - 1))
    coeffs = [int.from_bytes(secret, "little")] + [
        int.from_bytes(stream[80 * i:80 * (i + 1)], "little") % p for i in range(threshold - 1)]
    out = {}
    for x in holders:
        y = 0
        for a in reversed(coeffs):        # Horner
            y = (y * x + a) % p
        out[x] = y
    return out


def _lagrange_at(points: list[tuple[int, int]], at: int) -> int:
    """The interpolating polynomial through ``points`` evaluated at ``at``, mod p."""
    p = SHAMIR_PRIME
    total = 0
    for j, (xj, yj) in enumerate(points):
        num, den = 1, 1
        for m, (xm, _) in enumerate(points):
            if m != j:
                num = num * (at - xm) % p
                den = den * (xj - xm) % p
        total = (total + yj * num * pow(den, -1, p)) % p
    return total


def shamir_combine(shares: dict[int, int], threshold: int, what: str) -> bytes:
    """The 32-byte secret from ``>= threshold`` shares ``{x: y}``; extra shares are checked.

    Raises
    ------
    MessageError
        Fewer than ``threshold`` shares, a share out of the field, extra shares off the polynomial,
        or a secret that does not fit 32 bytes (``what`` names the secret in the message).
    """
    if len(shares) < threshold:
        raise MessageError(f"{what}: {len(shares)} shares received, threshold {threshold} required")
    pts = sorted(shares.items())
    if any(not 0 < x < SHAMIR_PRIME or not 0 <= y < SHAMIR_PRIME for x, y in pts):
        raise MessageError(f"{what}: a share lies outside GF(2^521 - 1)")
    base = pts[:threshold]
    for x, y in pts[threshold:]:
        if _lagrange_at(base, x) != y:
            raise MessageError(f"{what}: share of holder {x} is inconsistent with the others")
    secret = _lagrange_at(base, 0)
    if secret >= 2 ** (8 * KEY_NBYTES):
        raise MessageError(f"{what}: reconstructed value does not fit {KEY_NBYTES} bytes (bad shares)")
    return secret.to_bytes(KEY_NBYTES, "little")


def x25519_keypair(seed: bytes) -> tuple[bytes, bytes]:
    """``(private, public)`` raw 32-byte X25519 keys from a 32-byte ``seed`` (clamped by X25519)."""
    sk = X25519PrivateKey.from_private_bytes(seed)
    return seed, sk.public_key().public_bytes_raw()


def x25519_agree(private: bytes, public: bytes, who: str) -> bytes:
    """The X25519 shared secret; :class:`MessageError` if ``public`` (untrusted) is not a valid key."""
    try:
        return X25519PrivateKey.from_private_bytes(private).exchange(X25519PublicKey.from_public_bytes(public))
    except (ValueError, TypeError) as err:
        raise MessageError(f"{who}: invalid X25519 public key ({err})") from err
