"""Data objects that cross the network between consecutive vehicles.

They hold plain numpy arrays and scalars only, so :mod:`roadcollab.wire.protocol` can serialise
them without pickle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lti.realisation import StateSpaceData
from .describe import validate_message
from .layout import MESSAGE_TYPE_EXCHANGE, MESSAGE_TYPE_INVERSION

__all__ = ["ExchangeMessage", "InversionMessage"]


@dataclass(frozen=True, eq=False)
class ExchangeMessage:
    """What vehicle ``j`` sends to ``j+1`` in Algorithm 1 (and, obfuscated, eq. 17).

    Attributes
    ----------
    mechanism : str
        ``"none"`` (Algorithm 1 in the clear) or ``"paper"`` (Algorithm 2).
    sample_rate : float
        Hz; fixes the grid together with ``n_samples`` and the signal length.
    n_samples : int
        Samples in the recorded window ``N``.
    T, S : StateSpaceData
        ``T_j`` and ``S_j`` (or ``Psi1 T_j`` and ``Psi1 S_j Psi2``), 2x2 discrete systems.
    e, wf : (nfft, 2) ndarray
        ``e_j`` and ``w^f_j`` (or ``Psi1 e_j`` and ``Psi2^-1 w^f_j``) on the padded periodic
        grid of ``nfft`` samples.

    Raises
    ------
    MessageError
        On construction, if the message fails any check the codec applies (types, shapes, limits,
        finite values, stable dynamics): a message that exists can be encoded and decoded.

    Notes
    -----
    Once checked, the arrays it holds that own their data (``e``, ``wf`` and the systems' matrices)
    are made read-only, and :func:`~roadcollab.wire.protocol.encode` reuses the check while the
    message holds those same frozen arrays; a message holding a view of a writable array is
    checked again at every encode.
    """

    WIRE_TYPE = MESSAGE_TYPE_EXCHANGE     # class attribute (not a field): the codec's message type

    mechanism: str
    sample_rate: float
    n_samples: int
    T: StateSpaceData
    S: StateSpaceData
    e: np.ndarray
    wf: np.ndarray

    def __post_init__(self) -> None:
        validate_message(self)


@dataclass(frozen=True, eq=False)
class InversionMessage:
    """Hardened exchange: the band-limited road-input estimate only, no dynamics.

    With the optimal learning filters, everything vehicle ``j`` needs from vehicle ``j-1`` is
    ``z_{j-1} = W T_{j-1}^-1 (e_{j-1} - S_{j-1} w^f_{j-1})``, which equals
    ``W P_hat_{j-1}^-1 y_{j-1}`` (with nominal ``T``); ``w^f_j = -S_j^-1 T_j z_{j-1}``.

    Attributes
    ----------
    mechanism : str
        ``"hardened"`` (Algorithm 1 with only ``z`` sent) or ``"fused"`` (running average).
    sample_rate : float
        Hz.
    n_samples : int
        Samples in the recorded window.
    z : (nfft, 2) ndarray
        ``z`` on the padded periodic grid, m/s.
    count : int
        Number of vehicles whose inversions ``z`` averages (1 for ``hardened``).

    Raises
    ------
    MessageError
        On construction, if the message fails any check the codec applies.

    Notes
    -----
    ``z`` is made read-only once checked, as for :class:`ExchangeMessage`.
    """

    WIRE_TYPE = MESSAGE_TYPE_INVERSION    # class attribute (not a field): the codec's message type

    mechanism: str
    sample_rate: float
    n_samples: int
    z: np.ndarray
    count: int = 1

    def __post_init__(self) -> None:
        validate_message(self)
