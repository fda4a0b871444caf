"""Per-message-type fields: an in-memory message to and from its header and payload arrays.

:func:`build_message` is the decoding side: it assembles the message from a checked header and
its arrays. The encoding side, :func:`~.describe.message_fields`, lives in :mod:`.describe`.
"""

from __future__ import annotations

from typing import Union

import numpy as np

from ..lti.realisation import StateSpaceData
from .layout import MESSAGE_TYPE_INVERSION, Header
from .message import ExchangeMessage, InversionMessage

__all__ = ["Message", "build_message"]

Message = Union[ExchangeMessage, InversionMessage]


def build_message(h: Header, arrays: dict[str, np.ndarray]) -> Message:
    """The message described by a checked header and its payload arrays.

    Parameters
    ----------
    h : Header
    arrays : dict of str to numpy.ndarray
        Payload arrays by wire name, as read from the bytes.

    Returns
    -------
    ExchangeMessage | InversionMessage
        Holding the given arrays (not copies).
    """
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                                z=arrays["z"], count=h.count)
    T, S = (StateSpaceData(*(arrays[f"{name}.{p}"] for p in "ABCD"), dt=dt)
            for name, dt in (("T", h.dt_T), ("S", h.dt_S)))
    return ExchangeMessage(mechanism=h.mechanism, sample_rate=h.sample_rate, n_samples=h.n_samples,
                           T=T, S=S, e=arrays["e"], wf=arrays["wf"])
