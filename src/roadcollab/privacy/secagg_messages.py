"""Parameters and messages of secure aggregation (:mod:`.secure_aggregation` runs the protocol).

The messages that travel (:class:`KeyAdvert`, :class:`SealedShares`, :class:`MaskedInput`,
:class:`Reveal`) live in the wire layer, :mod:`roadcollab.wire.secagg`, with their binary encoding
(:func:`roadcollab.wire.protocol.encode` / ``decode``); they are re-exported here. Every message a
vehicle or the aggregator receives is untrusted: construction runs the codec's checks and raises
:class:`roadcollab.errors.MessageError`. ``nbytes`` counts the fields that travel (without the 48-byte
header). This module holds what never travels: the public parameters, a vehicle's secrets, the result.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .._validation import check_int, check_real
from ..errors import MessageError, ParameterError
from ..wire.secagg import KeyAdvert, MaskedInput, Reveal, SealedShares

__all__ = ["AggregationRefused", "SecAggSpec", "session_id", "VehicleSecrets", "KeyAdvert", "SealedShares",
           "MaskedInput", "Reveal", "AggregateResult"]


class AggregationRefused(MessageError):
    """Unmasking refused: fewer surviving inputs than ``k`` (or than the Shamir threshold ``t``)."""


@dataclass(frozen=True)
class SecAggSpec:
    """Public parameters of secure aggregation.

    Attributes
    ----------
    min_inputs : int
        ``k``: the smallest number of inputs whose sum may be revealed (>= 2).
    threshold : int
        ``t``: Shamir threshold; any ``t`` vehicles' shares recover a secret, ``t - 1`` reveal
        nothing. Privacy holds against the aggregator plus ``c < t`` vehicles; unmasking needs
        ``t`` vehicles to answer in round 3. ``t <= k`` is required.
    clip : float
        Public bound on every contribution, m/s: values are clipped to ``[-clip, clip]`` at the
        source (this also bounds what a malicious vehicle can add to the sum).
    frac_bits : int
        Fixed-point fraction bits ``f``: resolution ``2^-f`` m/s (default 40: 9.1e-13 m/s).
    max_colluders : int
        ``c``: vehicles that may collude with an *active* aggregator (:mod:`.secagg_active`). The
        active protocol holds for ``c < t`` and rosters of ``n <= 2t - c - 1`` vehicles
        (:attr:`max_roster`): two disjoint groups of honest vehicles that each complete a
        threshold with the colluders cannot exist, so equivocation gains nothing.
    """

    min_inputs: int = 5
    threshold: int = 5
    clip: float = 16.0
    frac_bits: int = 40
    max_colluders: int = 0

    def __post_init__(self) -> None:
        k = check_int("min_inputs", self.min_inputs, low=2)
        check_int("threshold", self.threshold, low=1, high=k)
        f = check_int("frac_bits", self.frac_bits, low=8, high=52)
        check_real("clip", self.clip, low=0.0, low_open=True, high=float(2 ** (53 - f)))
        check_int("max_colluders", self.max_colluders, low=0, high=self.threshold - 1)

    @property
    def max_roster(self) -> int:
        """Largest roster the active protocol accepts: ``2t - c - 1`` (so that ``2t > n + c``)."""
        return 2 * self.threshold - self.max_colluders - 1

    @property
    def resolution(self) -> float:
        """Fixed-point resolution ``2^-frac_bits``, m/s (rounding error per value <= half of it)."""
        return 2.0 ** -self.frac_bits

    def check_fleet(self, n: int) -> int:
        """``n`` if ``n`` vehicles fit: ``n >= k`` and ``n * clip * 2^f < 2^63`` (no wrap of the sum).

        Parameters
        ----------
        n : int
            Vehicles in the session.

        Returns
        -------
        int
            ``n``.
        """
        n = check_int("n_vehicles", n, low=self.min_inputs)
        if n * self.clip * 2.0 ** self.frac_bits >= 2.0 ** 63:
            raise ParameterError(f"n_vehicles * clip * 2^frac_bits must be < 2^63, got {n} * {self.clip:g} * "
                                 f"2^{self.frac_bits}")
        return n


def session_id(segment: int, round_: int) -> bytes:
    """Domain-separation label of one aggregation: 16 bytes (segment, round), bound into every derived key.

    Parameters
    ----------
    segment : int
        Segment index (>= 0).
    round_ : int
        Aggregation round on that segment (>= 0).

    Returns
    -------
    bytes
    """
    return struct.pack("<QQ", check_int("segment", segment, low=0), check_int("round_", round_, low=0))


@dataclass(frozen=True, repr=False)
class VehicleSecrets:
    """One vehicle's secrets for one session (never sent). ``repr`` hides them.

    Attributes
    ----------
    vehicle : int
        Id (>= 1).
    session : bytes
        From :func:`session_id`.
    c_sk, s_sk, b_seed, share_seed : bytes
        Sealing key, mask-seed key, self-mask seed and Shamir coefficient seed, 32 bytes each.
    """

    vehicle: int
    session: bytes
    c_sk: bytes
    s_sk: bytes
    b_seed: bytes
    share_seed: bytes

    def __repr__(self) -> str:
        return f"VehicleSecrets(vehicle={self.vehicle}, <secret>)"


@dataclass(frozen=True)
class AggregateResult:
    """What the aggregator obtains: the sum over the surviving vehicles and who they are.

    Attributes
    ----------
    total : (L, 2) ndarray
        ``sum_{U_2} clip(z_i)`` to the fixed-point resolution, m/s.
    survivors, dropped : tuple of int
        ``U_2`` and ``U_1 \\ U_2``.
    """

    total: np.ndarray
    survivors: tuple[int, ...]
    dropped: tuple[int, ...]

    @property
    def average(self) -> np.ndarray:
        """The fused estimate ``total / |U_2|``, m/s."""
        return self.total / len(self.survivors)
