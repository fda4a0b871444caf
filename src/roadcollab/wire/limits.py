"""Limits of the wire format and the single validation path shared by encode and decode.

:func:`check_header` decides from the header alone, before any array is allocated, whether
the declared message is acceptable; :func:`check_payload` then checks the arrays (finite
values, stable dynamics). The table of limits is in :mod:`roadcollab.wire.protocol`. Every
refusal is a :class:`~roadcollab.errors.MessageError`.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from ..errors import MessageError
from ..lti.stability import LYAPUNOV_RTOL, spectral_radius_and_gain
from .layout import (MECHANISM_CODES, MECHANISM_TYPE, MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_KEY_ADVERT,
                     MESSAGE_TYPE_MASKED_INPUT, MESSAGE_TYPE_REVEAL, MESSAGE_TYPE_SEALED_SHARES, SECAGG_MECHANISM,
                     TYPE_NAMES, Header, SecAggHeader, exchange_nbytes, inversion_nbytes)

__all__ = [
    "MAX_ORDER",
    "MAX_SIGNAL_LENGTH",
    "MAX_MESSAGE_BYTES",
    "MAX_SAMPLE_RATE",
    "MAX_COUNT",
    "DT_RTOL",
    "RADIUS_MARGIN",
    "MAX_TRANSIENT_GAIN",
    "LYAPUNOV_RTOL",
    "check_mechanism",
    "check_header",
    "check_payload",
    "MAX_VEHICLES",
    "MAX_VEHICLE_ID",
    "SHARE_MODULUS",
]

MAX_ORDER = 64
MAX_SIGNAL_LENGTH = 2 ** 20
MAX_SAMPLE_RATE = 1e6
MAX_COUNT = 10 ** 6
DT_RTOL = 1e-12
#: Computed spectral radius of A must be below ``1 - RADIUS_MARGIN`` (per sample).
RADIUS_MARGIN = 1e-6
#: Largest certified transient gain ``sup_k ||A^k||_2 <= sqrt(cond X)`` (Lyapunov certificate).
MAX_TRANSIENT_GAIN = 1e8
# LYAPUNOV_RTOL (largest relative residual of the Lyapunov solution) lives with the kernel in lti.stability.

#: Secure aggregation: most vehicles in one session, so most shares in one reveal.
MAX_VEHICLES = 10_000
#: Vehicle ids are uint32 on the wire; 0 is never an id (it is a Shamir evaluation point: the secret).
MAX_VEHICLE_ID = 2 ** 32 - 1
#: A Shamir share is an element of GF(p), p = 2^521 - 1: 0 <= share < SHARE_MODULUS.
SHARE_MODULUS = 2 ** 521 - 1

_SECAGG_MAX = (SecAggHeader(MESSAGE_TYPE_MASKED_INPUT, bytes(16), 0, 1, MAX_SIGNAL_LENGTH),
               SecAggHeader(MESSAGE_TYPE_REVEAL, bytes(16), 0, 1, MAX_VEHICLES))
# The largest valid message bounds what decode will even look at.
MAX_MESSAGE_BYTES = max(exchange_nbytes(MAX_ORDER, MAX_ORDER, MAX_SIGNAL_LENGTH),
                        inversion_nbytes(MAX_SIGNAL_LENGTH),
                        *(h.header_nbytes + h.expected_payload_nbytes() for h in _SECAGG_MAX))


def check_mechanism(mechanism: object) -> str:
    """``mechanism`` if it is one of the names of ``MECHANISM_CODES``.

    Parameters
    ----------
    mechanism : object
        ``"none"``, ``"paper"``, ``"hardened"``, ``"fused"`` or ``"secure_aggregation"``.

    Returns
    -------
    str
        ``mechanism`` unchanged.

    Raises
    ------
    MessageError
        For anything else (also for non-strings).
    """
    if not isinstance(mechanism, str) or mechanism not in MECHANISM_CODES:
        raise MessageError(f"mechanism must be one of {sorted(MECHANISM_CODES)}, got {mechanism!r}")
    return mechanism


def _check_exchange_header(h: Header) -> None:
    """Orders and sample times of T and S against ``MAX_ORDER`` and ``1 / sample_rate``."""
    dt = 1.0 / h.sample_rate
    if not math.isfinite(dt):
        # A subnormal sample_rate makes 1/sample_rate overflow, and inf would pass the dt test.
        raise MessageError(f"sample_rate {h.sample_rate!r} is too small: 1/sample_rate is not finite")
    for name, order, sys_dt in (("T", h.order_T, h.dt_T), ("S", h.order_S, h.dt_S)):
        if not 0 <= order <= MAX_ORDER:
            raise MessageError(f"oversized: order of {name} must be in [0, {MAX_ORDER}] (MAX_ORDER), got {order}")
        if not abs(sys_dt - dt) <= DT_RTOL * dt:
            raise MessageError(f"{name}.dt must equal 1/sample_rate = {dt!r} to {DT_RTOL:g} relative, "
                               f"got {sys_dt!r}")


def _check_inversion_header(h: Header) -> None:
    """``count`` within ``[1, MAX_COUNT]``, and exactly 1 for a "hardened" message."""
    if not 1 <= h.count <= MAX_COUNT:
        raise MessageError(f"count must be in [1, {MAX_COUNT}], got {h.count}")
    if h.mechanism == "hardened" and h.count != 1:
        # A "hardened" message is one vehicle's own inversion by definition.
        raise MessageError(f"count must be 1 for mechanism 'hardened', got {h.count}")


def check_header(h: Header | SecAggHeader) -> None:
    """Check every header field against the limits; uses no payload, allocates nothing.

    Parameters
    ----------
    h : Header | SecAggHeader
        Fields of a message, with ``mechanism`` a key of ``MECHANISM_CODES`` and
        ``msg_type`` a key of ``TYPE_NAMES``.

    Raises
    ------
    MessageError
        If a field is out of its limits, the mechanism does not fit the message type, or
        ``payload_nbytes`` differs from the size the dimensions imply.
    """
    if isinstance(h, SecAggHeader):
        _check_secagg_header(h)
        return
    expected_type = MECHANISM_TYPE[h.mechanism]
    if h.mechanism == SECAGG_MECHANISM:
        raise MessageError(f"mechanism {SECAGG_MECHANISM!r} requires a secure-aggregation message (types 3-6), "
                           f"got an {TYPE_NAMES[h.msg_type]} message")
    if h.msg_type != expected_type:
        raise MessageError(
            f"mechanism {h.mechanism!r} requires an {TYPE_NAMES[expected_type]} message, "
            f"got an {TYPE_NAMES[h.msg_type]} message")
    # Written as "not (ok)" so that NaN fails every check.
    if not (math.isfinite(h.sample_rate) and 0.0 < h.sample_rate <= MAX_SAMPLE_RATE):
        raise MessageError(f"sample_rate must be finite and in (0, {MAX_SAMPLE_RATE:g}] Hz, got {h.sample_rate!r}")
    if not 1 <= h.length <= MAX_SIGNAL_LENGTH:
        raise MessageError(f"oversized or empty: signal length must be in [1, {MAX_SIGNAL_LENGTH}] "
                           f"(MAX_SIGNAL_LENGTH), got {h.length}")
    if not 1 <= h.n_samples <= h.length:
        raise MessageError(f"n_samples must be in [1, signal length {h.length}], got {h.n_samples}")
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        _check_exchange_header(h)
    else:
        _check_inversion_header(h)
    expected = h.expected_payload_nbytes()
    if h.payload_nbytes != expected:
        raise MessageError(f"header declares {h.payload_nbytes} payload bytes but its dimensions imply {expected}")


def _check_finite(name: str, arr: np.ndarray) -> None:
    """MessageError naming ``name`` unless every entry of ``arr`` is finite."""
    if not np.isfinite(arr).all():
        bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        raise MessageError(f"{name} must be finite, got {bad} non-finite entries (NaN or inf)")


#: An exchange message's arrays in the order their finiteness is reported.
_FINITE_ORDER = ("T.A", "T.B", "T.C", "T.D", "S.A", "S.B", "S.C", "S.D", "e", "wf")


def _all_finite(arrays: dict[str, np.ndarray]) -> bool:
    """Whether every entry of an exchange message's arrays is finite: the eight system matrices in one
    check of their concatenation, ``e`` and ``wf`` one each (7 instead of 13 us per message, measured;
    a message is checked twice per ``paper`` vehicle-segment)."""
    small = np.concatenate([arrays[name].ravel() for name in _FINITE_ORDER[:8]])
    return bool(np.isfinite(small).all() and np.isfinite(arrays["e"]).all() and np.isfinite(arrays["wf"]).all())


def _check_system(name: str, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
                  certify: Callable[[], tuple[float, float]] | None = None, *, finite_checked: bool = False) -> None:
    """Finite entries and a discrete-time stable A: a margin on the computed spectral radius and a
    Lyapunov certificate of bounded transient growth (which non-normal matrices cannot fool:
    a 64x64 Jordan block with a 1e-16 corner computes as radius 0.99 but has none).
    ``certify`` returns ``(radius, gain)`` of this ``A`` (a memo held by the system object,
    :meth:`~roadcollab.lti.realisation.StateSpaceData.stability`); by default they are computed.
    ``finite_checked``: the caller has checked that every entry is finite."""
    if not finite_checked:
        for part, arr in (("A", A), ("B", B), ("C", C), ("D", D)):
            _check_finite(f"{name}.{part}", arr)
    if A.shape[0] == 0:
        return
    try:
        radius, gain = certify() if certify is not None else spectral_radius_and_gain(A)
    except (np.linalg.LinAlgError, ValueError) as err:
        raise MessageError(f"{name}.A: eigenvalues could not be computed ({err})") from err
    if not radius < 1.0 - RADIUS_MARGIN:
        raise MessageError(f"{name} must be discrete-time stable (spectral radius of A < 1 - {RADIUS_MARGIN:g}), "
                           f"got {radius:.6g}")
    if not gain <= MAX_TRANSIENT_GAIN:
        raise MessageError(f"{name} must be discrete-time stable with a Lyapunov certificate: {name}.A has no "
                           f"certified bound sup_k ||A^k|| <= {MAX_TRANSIENT_GAIN:g} (got {gain:.3g}); "
                           f"a non-normal A whose computed eigenvalues mislead")


def check_payload(h: Header | SecAggHeader, arrays: dict[str, Any], *,
                  certificates: dict[str, Callable[[], tuple[float, float]]] | None = None) -> None:
    """Check the arrays of a message whose header passed :func:`check_header`.

    Parameters
    ----------
    h : Header | SecAggHeader
    arrays : dict of str to numpy.ndarray
        The payload arrays by wire name (see :func:`~.layout.payload_shapes`), float64; for secure
        aggregation the fields of :func:`~.describe.message_fields`.
    certificates : dict of str to callable, optional
        ``{"T": f, "S": g}``: each returns ``(radius, gain)`` of that system's ``A`` (the memo of
        :meth:`~roadcollab.lti.realisation.StateSpaceData.stability`); missing ones are computed.

    Raises
    ------
    MessageError
        If an entry is NaN or infinite, or ``T`` or ``S`` is not discrete-time stable: computed
        spectral radius not below ``1 - RADIUS_MARGIN``, or no Lyapunov certificate bounding
        ``sup_k ||A^k||`` by ``MAX_TRANSIENT_GAIN``. For secure aggregation, a reveal with shares
        out of order, duplicated across its two lists or outside ``GF(2^521 - 1)``.
    """
    if isinstance(h, SecAggHeader):
        _check_secagg_payload(h, arrays)
        return
    if h.msg_type == MESSAGE_TYPE_EXCHANGE:
        if not _all_finite(arrays):
            for name in _FINITE_ORDER:          # name the first non-finite field
                _check_finite(name, arrays[name])
        for name in ("T", "S"):
            A, B, C, D = (arrays[f"{name}.{p}"] for p in "ABCD")
            _check_system(name, A, B, C, D, certify=None if certificates is None else certificates.get(name),
                          finite_checked=True)
    else:
        _check_finite("z", arrays["z"])


def _check_id(name: str, value: int) -> None:
    """A vehicle id in ``[1, MAX_VEHICLE_ID]``."""
    if not 1 <= value <= MAX_VEHICLE_ID:
        raise MessageError(f"{name} must be a positive int vehicle id <= {MAX_VEHICLE_ID}, got {value}")


def _check_secagg_header(h: SecAggHeader) -> None:
    """:func:`check_header` of a secure-aggregation message.

    Refused: the mechanism is not ``"secure_aggregation"``, the session is not 16 bytes, an id is
        out of ``[1, MAX_VEHICLE_ID]``, a sealed share is addressed to its sender, ``L`` is out of
        ``[1, MAX_SIGNAL_LENGTH]``, a reveal carries no share or more than ``MAX_VEHICLES``, an
    unused or reserved field is not 0, or ``payload_nbytes`` differs from the size implied.
    """
    kind = TYPE_NAMES[h.msg_type]
    if h.mechanism != SECAGG_MECHANISM:
        raise MessageError(f"a {kind} message requires mechanism {SECAGG_MECHANISM!r}, got {h.mechanism!r}")
    if not isinstance(h.session, bytes) or len(h.session) != 16:
        raise MessageError(f"session must be 16 bytes (segment, round), got {h.session!r:.40}")
    if h.reserved != 0:
        raise MessageError(f"reserved secure-aggregation header field must be 0, got {h.reserved}")
    _check_id("vehicle", h.vehicle)
    unused = {MESSAGE_TYPE_KEY_ADVERT: (h.n1, h.n2), MESSAGE_TYPE_REVEAL: ()}.get(h.msg_type, (h.n2,))
    if any(unused):
        raise MessageError(f"unused {kind} header fields must be 0, got {unused}")
    if h.msg_type == MESSAGE_TYPE_SEALED_SHARES:
        _check_id("recipient", h.n1)
        if h.n1 == h.vehicle:
            raise MessageError(f"sealed shares of vehicle {h.vehicle} are addressed to itself")
    elif h.msg_type == MESSAGE_TYPE_MASKED_INPUT and not 1 <= h.n1 <= MAX_SIGNAL_LENGTH:
        raise MessageError(f"oversized or empty: masked input length must be in [1, {MAX_SIGNAL_LENGTH}] "
                           f"(MAX_SIGNAL_LENGTH), got {h.n1}")
    elif h.msg_type == MESSAGE_TYPE_REVEAL and not 1 <= h.n1 + h.n2 <= MAX_VEHICLES:
        raise MessageError(f"oversized or empty: a reveal must carry 1 to {MAX_VEHICLES} shares (MAX_VEHICLES), "
                           f"got {h.n1} + {h.n2}")
    expected = h.expected_payload_nbytes()
    if h.payload_nbytes != expected:
        raise MessageError(f"header declares {h.payload_nbytes} payload bytes but its dimensions imply {expected}")


def _check_shares(name: str, entries: list[tuple[int, int]]) -> None:
    """Owner ids strictly increasing (the canonical order) and shares in ``[0, SHARE_MODULUS)``."""
    previous = 0
    for owner, share in entries:
        _check_id(f"{name}: owner", owner)
        if owner <= previous:
            raise MessageError(f"{name}: owner ids must be strictly increasing, got {owner} after {previous}")
        if not 0 <= share < SHARE_MODULUS:
            raise MessageError(f"{name}: share of owner {owner} lies outside GF(2^521 - 1)")
        previous = owner


def _check_secagg_payload(h: SecAggHeader, fields: dict[str, Any]) -> None:
    """:func:`check_payload` of a secure-aggregation message.

    ``fields`` as from :func:`~.describe.message_fields`, a reveal's ``self_mask_shares`` and
    ``key_shares`` as lists of ``(owner, share)`` in wire order. Refused: a reveal whose owner ids are not strictly increasing within a list, not vehicle ids, or
    appear in both lists (a vehicle reveals ``b_i`` or ``s_i``, never both), or whose shares lie
    outside ``GF(2^521 - 1)``. Keys, ciphertexts and ring elements take any value.
    """
    if h.msg_type != MESSAGE_TYPE_REVEAL:
        return
    _check_shares("self_mask_shares", fields["self_mask_shares"])
    _check_shares("key_shares", fields["key_shares"])
    both = {o for o, _ in fields["self_mask_shares"]} & {o for o, _ in fields["key_shares"]}
    if both:
        raise MessageError(f"reveal of vehicle {h.vehicle} carries both shares of owners {sorted(both)[:5]}")
