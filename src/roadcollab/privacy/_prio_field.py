"""The prime field of :mod:`.secagg_flp`: elements, XOF expansion and NTTs.

``F_p``, ``p = 2^64 - 2^32 + 1`` (Goldilocks, 2-adicity 32) by default; small fields in tests.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..errors import MessageError, ParameterError
from . import _goldilocks

__all__ = ["Field", "GOLDILOCKS"]


@dataclass(frozen=True)
class Field:
    """A prime field ``F_p`` with a large power-of-two subgroup (for NTTs).

    Attributes
    ----------
    p : int
        The prime.
    generator : int
        A generator of the multiplicative group ``F_p^*``.
    """

    p: int
    generator: int

    @property
    def nbytes(self) -> int:
        """Bytes of one element on the wire."""
        return (self.p.bit_length() + 7) // 8

    def root(self, n: int) -> int:
        """A primitive ``n``-th root of unity (``n`` a power of two dividing ``p - 1``).

        Parameters
        ----------
        n : int
            Order.
        """
        if n & (n - 1) or (self.p - 1) % n:
            raise ParameterError(f"the field has no primitive {n}-th root of unity (p = {self.p})")
        return pow(self.generator, (self.p - 1) // n, self.p)

    def inv(self, a: int) -> int:
        """``a^-1`` in ``F_p``.

        Parameters
        ----------
        a : int
            Non-zero element.
        """
        return pow(int(a), self.p - 2, self.p)

    def elements(self, seed: bytes, label: bytes, n: int) -> np.ndarray:
        """``n`` pseudo-random elements from SHAKE128 (16 bytes each, reduced: bias ``< p / 2^128``).

        Parameters
        ----------
        seed : bytes
            XOF seed.
        label : bytes
            Domain separation.
        n : int
            Elements.
        """
        data = hashlib.shake_128(b"roadcollab-prio/" + label + b"/" + seed).digest(16 * n)
        words = np.frombuffer(data, dtype="<u8").astype(object).reshape(n, 2)
        out: np.ndarray = (words[:, 0] << 64 | words[:, 1]) % self.p
        return out

    def to_bytes(self, a: np.ndarray) -> bytes:
        """Fixed-width little-endian encoding of a vector of elements.

        Parameters
        ----------
        a : (n,) object ndarray
            Elements in ``[0, p)``.
        """
        w = self.nbytes
        if w == 8:      # Goldilocks: one numpy conversion (a phase-1 upload holds 376,000 elements)
            return np.asarray(a).astype("<u8").tobytes()
        return b"".join(int(v).to_bytes(w, "little") for v in a)

    def from_bytes(self, data: bytes, n: int, what: str) -> np.ndarray:
        """The ``n`` elements of :meth:`to_bytes` output from an untrusted sender.

        Parameters
        ----------
        data : bytes
        n : int
            Expected elements.
        what : str
            Named in the error.

        Returns
        -------
        (n,) object ndarray

        Raises
        ------
        MessageError
            Another length, or an element not in ``[0, p)``.
        """
        w = self.nbytes
        data = bytes(data)
        if len(data) != n * w:
            raise MessageError(f"{what}: expected {n} field elements ({n * w} bytes), got {len(data)} bytes")
        if w == 8:
            out = np.frombuffer(data, dtype="<u8").astype(object)
        else:
            out = np.array([int.from_bytes(data[k:k + w], "little") for k in range(0, len(data), w)], dtype=object)
        if n and max(out) >= self.p:
            raise MessageError(f"{what}: an element is not in F_p")
        return out.reshape(n)


GOLDILOCKS = Field(2 ** 64 - 2 ** 32 + 1, 7)


def _ntt(a: np.ndarray, w: int, p: int) -> np.ndarray:
    """Evaluations at ``w^0, ..., w^(n-1)`` of the polynomials whose coefficients are the rows of ``a``."""
    n = a.shape[-1]
    if p == _goldilocks.P and n > 1:
        return _goldilocks.ntt(np.asarray(a).astype(np.uint64), w).astype(object)
    if n == 1:
        return a
    even, odd = _ntt(a[..., 0::2], w * w % p, p), _ntt(a[..., 1::2], w * w % p, p)
    tw = np.array([pow(w, k, p) for k in range(n // 2)], dtype=object)
    t = odd * tw % p
    return np.concatenate([(even + t) % p, (even - t) % p], axis=-1)


def _intt(a: np.ndarray, w: int, f: Field) -> np.ndarray:
    """Coefficients of the polynomials whose values at ``w^0, ..., w^(n-1)`` are the rows of ``a``."""
    n = a.shape[-1]
    return _ntt(a, f.inv(w), f.p) * f.inv(n) % f.p
