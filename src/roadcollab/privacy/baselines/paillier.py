"""Paillier homomorphic encryption baseline (:mod:`phe` keys, gmpy2 arithmetic).

:func:`paillier_cost` measures what it costs to send one message: key generation, encryption and
decryption time (with the round trip checked) and the ciphertext bytes. Two ways:

- ``packing=True`` (default, as deployed; :mod:`.paillier_packed`): 36 fixed-point values per 2048-bit
  ciphertext with headroom for homomorphic sums, ``r^n mod n^2`` precomputed offline, gmpy2 arithmetic;
- ``packing=False`` (the earlier baseline, kept for comparison): ``phe``'s ``encrypt`` per value, one
  ciphertext per number and ``r^n`` computed online.

``phe``/``gmpy2`` are imported only when a cost is measured; obfuscators come from the operating
system's secure randomness (intended, cannot be seeded).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..._validation import check_int, check_matrix, check_positive
from ...errors import ParameterError
from ...wire.message import InversionMessage
from .paillier_packed import packed_cost
from .timing import median_ms

__all__ = ["PAILLIER_REL_PRECISION", "paillier_cost"]

PAILLIER_REL_PRECISION = 1e-13
"""Default fixed-point resolution of :func:`paillier_cost`, relative to the message's peak magnitude."""

# Bytes that travel with each ciphertext besides the integer c mod n^2: its fixed-point exponent.
_EXPONENT_NBYTES = 4


def _message_values(values: Any) -> np.ndarray:
    """The numbers of one message, flattened to shape (n,) with n >= 1 (``z`` of an InversionMessage)."""
    if isinstance(values, InversionMessage):
        values = values.z
    arr = check_matrix("values", values, None).ravel()
    if arr.size == 0:
        raise ParameterError("values must contain at least one number, got 0")
    return arr


def _scale_and_precision(x: np.ndarray, precision: float | None) -> tuple[float, float]:
    """Full scale ``max|x|`` (1 for an all-zero message) and the absolute fixed-point resolution.

    Parameters
    ----------
    x : numpy.ndarray
        The values, shape (n,), units of the message.
    precision : float or None
        The caller's absolute resolution; None gives ``PAILLIER_REL_PRECISION * scale``.

    Returns
    -------
    scale, precision : float
        Both in the units of ``x``.
    """
    scale = float(np.max(np.abs(x)))
    if scale == 0.0:
        scale = 1.0
    if precision is None:
        precision = PAILLIER_REL_PRECISION * scale
    return scale, check_positive("precision", precision)


def _choose_sample(x: np.ndarray, sample: int, rng: np.random.Generator) -> tuple[list[float], bool]:
    """The values to encrypt: all of ``x`` (n,), or ``sample`` of them drawn without replacement.

    Returns
    -------
    chosen : list of float
        In the order they appear in ``x``.
    extrapolated : bool
        True when ``x`` has more than ``sample`` values, so totals must be extrapolated.
    """
    gen = np.random.default_rng(rng)
    n = x.size
    extrapolated = n > sample
    chosen = x[np.sort(gen.choice(n, size=sample, replace=False))] if extrapolated else x
    return [float(v) for v in chosen], extrapolated


def _check_keypair(keypair: object, key_bits: int) -> tuple[Any, Any]:
    """``(public, private)`` of a caller's keypair whose modulus has ``key_bits`` bits."""
    from phe import paillier

    if (not isinstance(keypair, tuple) or len(keypair) != 2
            or not isinstance(keypair[0], paillier.PaillierPublicKey)
            or not isinstance(keypair[1], paillier.PaillierPrivateKey)):
        raise ParameterError("keypair must be a (PaillierPublicKey, PaillierPrivateKey) tuple, "
                             f"got {type(keypair).__name__}")
    pub, priv = keypair
    if priv.public_key != pub:
        raise ParameterError("keypair: the private key does not belong to the public key")
    if pub.n.bit_length() != key_bits:
        raise ParameterError(f"keypair has a {pub.n.bit_length()}-bit modulus, key_bits is {key_bits}")
    return pub, priv


def _keypair(keypair: object, key_bits: int) -> tuple[Any, Any, float]:
    """``(public, private, keygen_ms)``: a fresh timed key pair, or the caller's (keygen_ms NaN)."""
    from phe import paillier

    if keypair is not None:
        pub, priv = _check_keypair(keypair, key_bits)
        return pub, priv, float("nan")
    t0 = time.perf_counter()
    pub, priv = paillier.generate_paillier_keypair(n_length=key_bits)
    return pub, priv, (time.perf_counter() - t0) * 1e3


def _time_encryption(pub: Any, chosen: list[float], precision: float) -> tuple[list[Any], float]:
    """Encrypt every chosen value once; returns the ciphertexts and the median ms per value."""
    encrypted: list[Any] = []
    it = iter(chosen)
    enc_ms = median_ms(lambda: encrypted.append(pub.encrypt(next(it), precision=precision)), len(chosen))
    return encrypted, enc_ms


def _time_decryption(priv: Any, encrypted: list[Any]) -> tuple[list[float], float]:
    """Decrypt every ciphertext once; returns the plaintexts and the median ms per value."""
    decrypted: list[float] = []
    it_c = iter(encrypted)
    dec_ms = median_ms(lambda: decrypted.append(priv.decrypt(next(it_c))), len(encrypted))
    return decrypted, dec_ms


def _check_round_trip(decrypted: list[float], chosen: list[float], tol: float) -> None:
    """RuntimeError unless every decrypted value is within ``tol`` of the original."""
    err = np.abs(np.asarray(decrypted, dtype=float) - np.asarray(chosen))
    if not np.all(err <= tol):
        raise RuntimeError(f"Paillier round trip lost precision: error {float(err.max()):.3g} > tolerance {tol:.3g}")


def _ciphertext_nbytes(encrypted: list[Any]) -> np.ndarray:
    """Wire size of each ciphertext, bytes, shape (len(encrypted),): ``c mod n^2`` plus its exponent."""
    return np.array([(c.ciphertext(be_secure=False).bit_length() + 7) // 8 + _EXPONENT_NBYTES for c in encrypted])


def _message_nbytes(sizes: np.ndarray, n: int, extrapolated: bool) -> int:
    """Bytes of all ``n`` ciphertexts: the sum of ``sizes``, or their mean times ``n`` when sampled."""
    return int(sizes.sum()) if not extrapolated else int(round(sizes.mean() * n))


def _per_value_cost(x: np.ndarray, pub: Any, priv: Any, precision: float, scale: float, sample: int,
                    gen: np.random.Generator) -> dict[str, Any]:
    """The earlier baseline: ``phe``'s ``encrypt`` per value on ``sample`` values, extrapolated to ``x``."""
    chosen, extrapolated = _choose_sample(x, sample, gen)
    encrypted, enc_ms = _time_encryption(pub, chosen, precision)
    decrypted, dec_ms = _time_decryption(priv, encrypted)
    _check_round_trip(decrypted, chosen, max(1e-12 * scale, precision))
    sizes = _ciphertext_nbytes(encrypted)
    n = x.size
    return {"ms_per_message": enc_ms * n, "bytes_per_message": _message_nbytes(sizes, n, extrapolated),
            "ms_per_value": enc_ms, "decrypt_ms_per_value": dec_ms, "bytes_per_value": float(sizes.mean()),
            "extrapolated_from": len(chosen) if extrapolated else None}


def paillier_cost(values: Any, *, key_bits: int = 2048, sample: int = 32,
                  rng: int | np.random.Generator | None = None, keypair: object = None,
                  precision: float | None = None, packing: bool = True, n_summands: int = 16) -> dict[str, Any]:
    """Cost of sending a message as Paillier ciphertexts: packed as deployed, or one per number.

    ``packing=True``: see :mod:`.paillier_packed` (slot layout, offline ``r^n``); the online time is
    ``ms_per_message``, the offline precomputation ``offline_ms_per_message``. ``packing=False``:
    every value is encrypted separately with ``public_key.encrypt(x, precision=p)``, which
    stores ``round(x / 16**e)`` with the fixed exponent ``e = floor(log16(p))`` (resolution
    ``16**e <= p``). A ciphertext travels as the integer ``c`` modulo ``n^2`` plus its
    exponent: ``(c.bit_length() + 7) // 8 + 4`` bytes.

    Parameters
    ----------
    values : array_like or InversionMessage
        The numbers of one message (any shape, flattened; ``z`` of an InversionMessage).
    key_bits : int
        Modulus length, bits (2048 for the reported cost; 512 keeps tests fast).
    sample : int
        If there are more values (``packing=False``) or ciphertexts (offline phase and decryption of
        ``packing=True``) than this, time ``sample`` of them chosen at random (without replacement) and
        extrapolate to the whole message.
    rng : None, int or numpy.random.Generator
        Chooses the sample (numpy). Encryption itself draws its obfuscator with ``phe``'s
        secure randomness (:class:`random.SystemRandom`), which is intended and not seeded.
    keypair : (PaillierPublicKey, PaillierPrivateKey), optional
        Precomputed keys (2048-bit generation takes seconds); its modulus must have
        ``key_bits`` bits. Key generation is then not timed.
    precision : float, optional
        Absolute fixed-point resolution, units of ``values``. Default
        ``PAILLIER_REL_PRECISION * max|values|`` (1e-13 of the message's full scale, i.e.
        about 43 bits, plenty for double-precision signals).
    packing : bool
        Several values per ciphertext with offline randomness (True), or ``phe`` per value (False).
    n_summands : int
        ``packing=True``: ciphertexts whose homomorphic sum the slots must hold without overflow (>= 1).

    Returns
    -------
    dict
        ``ms_per_message`` (float, ms to encrypt every value), ``bytes_per_message`` (int),
        ``keygen_ms`` (float, ms; NaN when ``keypair`` was given), ``ms_per_value`` (median
        encryption time of one value, ms), ``decrypt_ms_per_value`` (median, ms),
        ``bytes_per_value`` (mean over the encrypted values),
        ``n_values`` (int), ``extrapolated_from`` (number of values actually encrypted if
        the totals were extrapolated, else None), ``key_bits``, ``precision`` (absolute),
        ``gmpy2`` (bool: whether ``phe`` uses gmpy2 for modular arithmetic; pure-Python
        ``pow`` is several times slower), ``packing`` (bool). With ``packing=True`` also
        ``offline_ms_per_message`` (precomputing every ``r^n``), ``decrypt_ms_per_message``,
        ``n_ciphertexts``, ``values_per_ciphertext``, ``slot_bits``, ``value_bits``, ``n_summands``;
        ``extrapolated_from`` then counts ciphertexts.

    Raises
    ------
    ParameterError
        For bad arguments.
    RuntimeError
        If a decrypted sample value differs from the original by more than
        ``max(1e-12 * max|values|, precision)`` (the round trip is checked on every sample).
    """
    # Imported first so that a missing phe fails before any argument is looked at.
    from phe import util

    x = _message_values(values)
    key_bits = check_int("key_bits", key_bits, low=256, high=16384)
    sample = check_int("sample", sample, low=1)
    scale, precision = _scale_and_precision(x, precision)
    if not isinstance(packing, bool):
        raise ParameterError(f"packing must be a bool, got {packing!r}")
    n_summands = check_int("n_summands", n_summands, low=1, high=2 ** 16)
    pub, priv, keygen_ms = _keypair(keypair, key_bits)
    gen = np.random.default_rng(rng)
    if packing:
        out = packed_cost(x, pub, priv, precision, scale, n_summands=n_summands, sample=sample, rng=gen)
    else:
        out = _per_value_cost(x, pub, priv, precision, scale, sample, gen)
    return {**out, "keygen_ms": keygen_ms, "n_values": int(x.size), "key_bits": key_bits,
            "precision": precision, "gmpy2": bool(util.HAVE_GMP), "packing": packing}
