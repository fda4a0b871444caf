"""Paillier as it would be deployed: gmpy2 arithmetic, offline randomness, many fixed-point values per ciphertext.

A plaintext of a ``key_bits``-bit modulus ``n`` holds ``slots = floor((key_bits - 1) / w)`` slots of ``w``
bits. A value ``x`` is stored as ``q = round(x / precision) + 2^(v-1)`` (``v`` value bits, the offset makes it
non-negative); ``w = 8 * ceil((v + h) / 8)`` leaves ``h = ceil(log2(n_summands))`` bits of headroom, so
the homomorphic sum of up to ``n_summands`` ciphertexts never carries into the next slot (the receiver
subtracts ``n_summands * 2^(v-1)`` per slot). With the defaults (1e-13 of full scale: ``v = 45``; 16
summands: ``h = 4``) ``w = 56`` bits and a 2048-bit key carries 36 values per ciphertext.

Encryption with ``g = n + 1`` is ``c = (1 + m n) r^n mod n^2``. The factor ``r^n mod n^2`` does not depend
on the message, so a vehicle computes a pool of them offline (while idle; each is used once) and the online
cost is one multiplication mod ``n^2`` per ciphertext. Decryption uses ``phe``'s CRT decryption (gmpy2
when installed). ``gmpy2`` and ``phe`` are imported only when a cost is measured.
"""

from __future__ import annotations

import math
import secrets
import time
from typing import Any

import numpy as np

__all__ = ["slot_layout", "pack", "unpack", "precompute_rn", "encrypt_packed", "packed_cost"]


def slot_layout(scale: float, precision: float, key_bits: int, n_summands: int) -> tuple[int, int, int]:
    """``(value_bits v, slot_bits w, slots per ciphertext)`` for values within ``[-scale, scale]``.

    Parameters
    ----------
    scale : float
        Full scale ``max|x|``, units of the values.
    precision : float
        Absolute fixed-point resolution, same units.
    key_bits : int
        Modulus length, bits.
    n_summands : int
        Ciphertexts that may be added homomorphically (headroom ``ceil(log2(n_summands))`` bits).

    Returns
    -------
    (int, int, int)
    """
    v = math.ceil(math.log2(2.0 * scale / precision + 2.0)) + 1
    w = 8 * math.ceil((v + math.ceil(math.log2(max(n_summands, 1)))) / 8)
    return v, w, (key_bits - 1) // w


def pack(x: np.ndarray, precision: float, value_bits: int, slot_bits: int, slots: int) -> list[int]:
    """Fixed-point values ``x`` (n,) packed into ``ceil(n / slots)`` plaintext integers (slot 0 lowest).

    Parameters
    ----------
    x : (n,) ndarray
        The values.
    precision : float
        Resolution.
    value_bits, slot_bits, slots : int
        From :func:`slot_layout`.

    Returns
    -------
    list of int
    """
    q = (np.rint(x / precision).astype(np.int64) + (1 << (value_bits - 1))).astype("<u8")
    nb = slot_bits // 8
    pad = (-q.size) % slots
    raw = np.zeros((q.size + pad, nb), dtype=np.uint8)
    raw[:q.size, :min(nb, 8)] = q.view(np.uint8).reshape(-1, 8)[:, :min(nb, 8)]
    rows = raw.reshape(-1, slots * nb)
    return [int.from_bytes(r.tobytes(), "little") for r in rows]


def unpack(plain: list[int], count: int, precision: float, value_bits: int, slot_bits: int, slots: int,
           n_summands: int = 1) -> np.ndarray:
    """The first ``count`` values from plaintexts made by :func:`pack` (or a sum of ``n_summands`` of them).

    Parameters
    ----------
    plain : list of int
        Decrypted plaintexts.
    count : int
        Values to return.
    precision : float
        Resolution.
    value_bits, slot_bits, slots : int
        From :func:`slot_layout`.
    n_summands : int
        Plaintexts that were added (their offsets are removed).

    Returns
    -------
    (count,) ndarray
    """
    nb = slot_bits // 8
    raw = np.frombuffer(b"".join(int(m).to_bytes(slots * nb, "little") for m in plain), dtype=np.uint8)
    raw = raw.reshape(-1, nb)[:count]
    q = np.zeros((count, 8), dtype=np.uint8)
    q[:, :min(nb, 8)] = raw[:, :min(nb, 8)]
    ints = q.view("<u8").ravel().astype(np.int64) - n_summands * (1 << (value_bits - 1))
    return ints.astype(float) * precision


def precompute_rn(pub: Any, count: int) -> list[Any]:
    """Offline phase: ``count`` values ``r^n mod n^2`` (``r`` uniform in ``[1, n)`` from :mod:`secrets`).

    Parameters
    ----------
    pub : phe.paillier.PaillierPublicKey
        The recipient's public key.
    count : int
        Ciphertexts to prepare; each value must be used once.

    Returns
    -------
    list of gmpy2.mpz
    """
    import gmpy2

    n, n2 = gmpy2.mpz(pub.n), gmpy2.mpz(pub.nsquare)
    return [gmpy2.powmod(gmpy2.mpz(secrets.randbelow(pub.n - 1) + 1), n, n2) for _ in range(count)]


def encrypt_packed(pub: Any, plain: list[int], rn: list[Any]) -> list[Any]:
    """Online phase: ``c = (1 + m n) r^n mod n^2`` for each plaintext, with a precomputed ``r^n`` each.

    Parameters
    ----------
    pub : phe.paillier.PaillierPublicKey
    plain : list of int
        Plaintexts ``m < n``.
    rn : list
        At least ``len(plain)`` values from :func:`precompute_rn` (consumed in order).

    Returns
    -------
    list of gmpy2.mpz
    """
    import gmpy2

    n, n2 = gmpy2.mpz(pub.n), gmpy2.mpz(pub.nsquare)
    return [(1 + gmpy2.mpz(m) * n) * r % n2 for m, r in zip(plain, rn)]


def packed_cost(x: np.ndarray, pub: Any, priv: Any, precision: float, scale: float, *, n_summands: int, sample: int,
                rng: np.random.Generator) -> dict[str, Any]:
    """Time one message the deployed way (see the module docstring); the round trip is checked.

    Online encryption is timed on every ciphertext; the offline ``r^n`` and decryption (modular
    exponentiations, the slow part) on ``min(sample, n_ciphertexts)`` of them and extrapolated.

    Parameters
    ----------
    x : (n,) ndarray
        The message's values.
    pub, priv : phe PaillierPublicKey, PaillierPrivateKey
        Keys.
    precision, scale : float
        Resolution and full scale (units of ``x``).
    n_summands : int
        Homomorphic additions the slots must absorb.
    sample : int
        Ciphertexts on which offline and decryption time are measured.
    rng : numpy.random.Generator
        Chooses the sampled ciphertexts.

    Returns
    -------
    dict
        Keys as in :func:`roadcollab.privacy.baselines.paillier_cost`.
    """
    key_bits = pub.n.bit_length()
    v, w, slots = slot_layout(scale, precision, key_bits, n_summands)
    t0 = time.perf_counter()
    plain = pack(x, precision, v, w, slots)
    pack_ms = (time.perf_counter() - t0) * 1e3
    k = len(plain)
    m = min(sample, k)
    t0 = time.perf_counter()
    rn = precompute_rn(pub, m)
    offline_ms = (time.perf_counter() - t0) * 1e3 / m
    rn = (rn * math.ceil(k / m))[:k]       # timing only: reused here, never in deployment
    t0 = time.perf_counter()
    cts = encrypt_packed(pub, plain, rn)
    online_ms = (time.perf_counter() - t0) * 1e3
    idx = np.sort(rng.choice(k, size=m, replace=False))
    t0 = time.perf_counter()
    dec = [priv.raw_decrypt(int(cts[i])) for i in idx]
    dec_ms = (time.perf_counter() - t0) * 1e3 / m
    back = unpack(dec, m * slots, precision, v, w, slots)
    want = np.concatenate([x[i * slots:(i + 1) * slots] for i in idx])
    err = np.abs(back[:want.size] - want)
    if not np.all(err <= max(1e-12 * scale, precision)):
        raise RuntimeError(f"Paillier round trip lost precision: error {float(err.max()):.3g}")
    ct_bytes = 2 * ((key_bits + 7) // 8)
    return {"ms_per_message": pack_ms + online_ms, "offline_ms_per_message": offline_ms * k,
            "decrypt_ms_per_message": dec_ms * k, "bytes_per_message": ct_bytes * k, "n_ciphertexts": k,
            "values_per_ciphertext": slots, "slot_bits": w, "value_bits": v, "n_summands": n_summands,
            "decrypt_ms_per_value": dec_ms / slots, "ms_per_value": (pack_ms + online_ms) / x.size,
            "bytes_per_value": ct_bytes * k / x.size, "extrapolated_from": m if m < k else None}
