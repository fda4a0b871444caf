"""Per-message-type fields: an in-memory message to and from its header and payload arrays.

:func:`build_message` is the decoding side: it assembles the message from a checked header and
its arrays. The encoding side, :func:`~.describe.message_fields`, lives in :mod:`.describe`.
"""

from __future__ import annotations

from typing import Any, Union

from ..lti.realisation import StateSpaceData, SystemCache
from .layout import (MESSAGE_TYPE_INVERSION, MESSAGE_TYPE_KEY_ADVERT, MESSAGE_TYPE_MASKED_INPUT,
                     MESSAGE_TYPE_SEALED_SHARES, Header, SecAggHeader)
from .message import ExchangeMessage, InversionMessage
from .secagg import KeyAdvert, MaskedInput, Reveal, SealedShares

__all__ = ["Message", "build_message"]

Message = Union[ExchangeMessage, InversionMessage, KeyAdvert, SealedShares, MaskedInput, Reveal]


def _build_secagg(h: SecAggHeader, fields: dict[str, Any]) -> Message:
    """The secure-aggregation message of a checked header and its payload fields."""
    if h.msg_type == MESSAGE_TYPE_KEY_ADVERT:
        return KeyAdvert(h.vehicle, fields["c_pk"], fields["s_pk"], session=h.session)
    if h.msg_type == MESSAGE_TYPE_SEALED_SHARES:
        return SealedShares(h.vehicle, h.n1, fields["ciphertext"], session=h.session)
    if h.msg_type == MESSAGE_TYPE_MASKED_INPUT:
        return MaskedInput(h.vehicle, fields["y"], session=h.session)
    return Reveal(h.vehicle, dict(fields["self_mask_shares"]), dict(fields["key_shares"]), session=h.session)


def build_message(h: Header | SecAggHeader, arrays: dict[str, Any], *, systems: SystemCache | None = None) -> Message:
    """The message described by a checked header and its payload arrays.

    Parameters
    ----------
    h : Header | SecAggHeader
    arrays : dict
        Payload arrays (or secure-aggregation fields) by wire name, as read from the bytes.
    systems : SystemCache, optional
        The receiver's systems by content: ``T`` and ``S`` identical to bytes seen before come back
        as the same objects, with their stability certificate memoised.

    Returns
    -------
    ExchangeMessage | InversionMessage | KeyAdvert | SealedShares | MaskedInput | Reveal
        Holding the given arrays (not copies).
    """
    if isinstance(h, SecAggHeader):
        return _build_secagg(h, arrays)
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                                z=arrays["z"], count=h.count)
    make = StateSpaceData if systems is None else systems.get
    T, S = (make(arrays[f"{name}.A"], arrays[f"{name}.B"], arrays[f"{name}.C"], arrays[f"{name}.D"], dt)
            for name, dt in (("T", h.dt_T), ("S", h.dt_S)))
    return ExchangeMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                           T=T, S=S, e=arrays["e"], wf=arrays["wf"])
