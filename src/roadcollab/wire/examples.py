"""Small valid messages with random content, for demonstrations, tests and the CLI."""

from __future__ import annotations

import numpy as np

from ..lti.realisation import StateSpaceData
from .fields import Message
from .layout import CHANNELS, MECHANISM_TYPE, MESSAGE_TYPE_INVERSION, SECAGG_MECHANISM
from .limits import check_mechanism
from .message import ExchangeMessage, InversionMessage
from .secagg import DEFAULT_SESSION, MaskedInput

__all__ = ["example_message"]

_EXAMPLE_SAMPLE_RATE = 200.0
_EXAMPLE_N_SAMPLES = 400
# 600 = 1.5 * 400 is what SegmentGrid's default padding gives for N = 400; only ">= n_samples" matters here.
_EXAMPLE_LENGTH = 600
_EXAMPLE_ORDERS = (4, 6)


def _random_stable_system(order: int, dt: float, rng: np.random.Generator) -> StateSpaceData:
    """A random 2x2 system whose A is scaled to spectral radius 0.9."""
    A = rng.standard_normal((order, order))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
    return StateSpaceData(A, rng.standard_normal((order, CHANNELS)), rng.standard_normal((CHANNELS, order)),
                          rng.standard_normal((CHANNELS, CHANNELS)), dt)


def example_message(mechanism: str = "paper", *, rng: np.random.Generator | int | None = None) -> Message:
    """A small valid message of the given mechanism, with random content.

    Parameters
    ----------
    mechanism : {"none", "paper", "hardened", "fused", "secure_aggregation"}
    rng : numpy.random.Generator | int | None
        Random source or seed (None: fresh entropy).

    Returns
    -------
    ExchangeMessage | InversionMessage | MaskedInput
        ``sample_rate`` 200 Hz, ``n_samples`` 400, signals of 600 rows; for exchange
        mechanisms ``T`` of order 4 and ``S`` of order 6 with spectral radius 0.9; for
        "fused" ``count`` 3. For "secure_aggregation" the masked input of vehicle 1 in session
        (segment 0, round 0): 600 x 2 uniform ``uint64`` ring elements, which is what a masked
        ``z`` looks like to anyone without the masks.
    """
    check_mechanism(mechanism)
    rng = np.random.default_rng(rng)
    fs, n, L = _EXAMPLE_SAMPLE_RATE, _EXAMPLE_N_SAMPLES, _EXAMPLE_LENGTH
    if mechanism == SECAGG_MECHANISM:
        y = rng.integers(0, 2 ** 64, size=(L, CHANNELS), dtype=np.uint64)
        return MaskedInput(1, y, session=DEFAULT_SESSION)
    if MECHANISM_TYPE[mechanism] == MESSAGE_TYPE_INVERSION:
        return InversionMessage(mechanism=mechanism, sample_rate=fs, n_samples=n,
                                z=rng.standard_normal((L, CHANNELS)), count=1 if mechanism == "hardened" else 3)
    T, S = (_random_stable_system(order, 1.0 / fs, rng) for order in _EXAMPLE_ORDERS)
    return ExchangeMessage(mechanism=mechanism, sample_rate=fs, n_samples=n, T=T, S=S,
                           e=rng.standard_normal((L, CHANNELS)), wf=rng.standard_normal((L, CHANNELS)))
