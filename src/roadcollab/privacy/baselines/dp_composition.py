"""Composition of the Gaussian mechanism over a vehicle's messages.

The ``dp`` baseline (:mod:`.dp`) calibrates the Gaussian mechanism per message: it protects one
change of at most ``rho`` (l2, m/s^2) in one record. A vehicle's parameters are the same in
every segment it reports, so what it exposes about them composes over its messages. This module
accounts for that with a real accountant (the ``dp-accounting`` package: privacy-loss
distributions, Meiser and Mohammadi 2018 / Koskela et al. 2020; or Renyi DP, Mironov 2017) and
with the exact closed form for the Gaussian mechanism:

.. math:: \\text{n-fold composition of } \\mathcal N(0, \\sigma^2) \\text{ at sensitivity } \\Delta
          \\equiv \\text{one Gaussian mechanism with } \\sigma / \\sqrt{n},

whose exact (epsilon, delta) curve is that of Balle and Wang (ICML 2018), which
:func:`~roadcollab.privacy.baselines.dp.gaussian_sigma` inverts.

Each message is a Gaussian mechanism of noise multiplier ``sigma / Delta`` (noise standard
deviation over the l2 sensitivity); the accountant sees ``GaussianDpEvent(sigma / Delta)``
composed ``n`` times (the Gaussian's privacy loss is symmetric, so add/remove and replace
adjacency with the same ``Delta`` agree).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import math

import dp_accounting
import scipy.optimize
from dp_accounting import pld, rdp

from ..._validation import check_int, check_positive
from ...errors import ParameterError
from .dp import DPSpec, _check_delta, gaussian_sigma

__all__ = ["composed_epsilon", "gaussian_epsilon", "composition_table", "ACCOUNTANTS"]

#: Accountants :func:`composed_epsilon` offers.
ACCOUNTANTS = ("pld", "rdp", "exact")


def gaussian_epsilon(noise_multiplier: float, delta: float) -> float:
    """Exact epsilon of one Gaussian mechanism (Balle and Wang 2018): the inverse of
    :func:`~roadcollab.privacy.baselines.dp.gaussian_sigma` in ``epsilon``.

    Parameters
    ----------
    noise_multiplier : float
        ``sigma / Delta`` (> 0): noise standard deviation over the l2 sensitivity.
    delta : float
        In (0, 1).

    Returns
    -------
    float
        The smallest ``epsilon >= 0`` for which the mechanism is (epsilon, delta)-DP (0 if it is
        (0, delta)-DP already).
    """
    m = check_positive("noise_multiplier", noise_multiplier)
    delta = _check_delta(delta)

    # gaussian_sigma(eps) decreases in eps: find eps with gaussian_sigma(eps, delta, 1) = m.
    def f(eps: float) -> float:
        return math.log(gaussian_sigma(eps, delta, 1.0)) - math.log(m)

    lo = 1e-12
    if f(lo) <= 0.0:
        return 0.0
    hi = 1.0
    while f(hi) > 0.0:
        hi *= 2.0
        if hi > 1e8:  # pragma: no cover - only for absurdly small noise
            return math.inf
    return float(scipy.optimize.brentq(f, lo, hi, xtol=1e-14, rtol=1e-12, maxiter=500))


def composed_epsilon(sigma_over_sensitivity: float, n_messages: int, delta: float, *,
                     accountant: str = "pld", discretization: float = 1e-4) -> float:
    """Total epsilon of ``n_messages`` Gaussian mechanisms on the same vehicle.

    .. math:: \\epsilon_{total}(n) = \\epsilon_{Gauss}(\\sigma/(\\Delta\\sqrt{n}), \\delta)\\quad(\\text{exact})

    Parameters
    ----------
    sigma_over_sensitivity : float
        Noise multiplier ``sigma / Delta`` of each message (> 0).
    n_messages : int
        Messages composed (>= 1), e.g. the segments one vehicle reports.
    delta : float
        Total ``delta`` of the composition, in (0, 1).
    accountant : {"pld", "rdp", "exact"}
        ``"pld"``: the privacy-loss-distribution accountant of ``dp-accounting`` (tight up to
        its discretisation, an upper bound); ``"rdp"``: its Renyi-DP accountant (looser upper
        bound); ``"exact"``: the closed form above (Balle and Wang's curve at ``sigma / sqrt(n)``).
    discretization : float
        Value-discretisation interval of the PLD accountant (> 0; smaller is tighter and slower).

    Returns
    -------
    float
        Total epsilon (dimensionless).

    Raises
    ------
    ParameterError
        If an argument is out of range or ``accountant`` is not one of :data:`ACCOUNTANTS`.

    Examples
    --------
    >>> round(composed_epsilon(1.0, 1, 1e-5, accountant="exact"), 3)
    4.377
    """
    m = check_positive("sigma_over_sensitivity", sigma_over_sensitivity)
    n = check_int("n_messages", n_messages, low=1)
    delta = _check_delta(delta)
    discretization = check_positive("discretization", discretization)
    if accountant not in ACCOUNTANTS:
        raise ParameterError(f"accountant must be one of {ACCOUNTANTS}, got {accountant!r}")
    if accountant == "exact":
        return gaussian_epsilon(m / math.sqrt(n), delta)
    event = dp_accounting.SelfComposedDpEvent(dp_accounting.GaussianDpEvent(m), n)
    acc = (pld.PLDAccountant(value_discretization_interval=discretization) if accountant == "pld"
           else rdp.RdpAccountant())
    return float(acc.compose(event).get_epsilon(delta))


def composition_table(spec: DPSpec = DPSpec(), segments: Sequence[int] = (1, 10, 100), *,
                      accountant: str = "pld") -> list[dict[str, Any]]:
    """Total epsilon of each per-message level of ``spec`` after ``n`` segments of one vehicle.

    The per-message noise multiplier is ``gaussian_sigma(epsilon, delta, 1)`` (the ``dp``
    baseline's calibration; independent of the sensitivity, which cancels), composed at the
    same ``delta``.

    Parameters
    ----------
    spec : DPSpec
        Per-message privacy levels and ``delta``.
    segments : sequence of int
        Numbers of composed messages (each >= 1).
    accountant : {"pld", "rdp", "exact"}
        See :func:`composed_epsilon`.

    Returns
    -------
    list of dict
        One row per (level, n): ``epsilon_per_message``, ``delta``, ``noise_multiplier``,
        ``segments``, ``epsilon_total`` and ``accountant``.
    """
    if not isinstance(spec, DPSpec):
        raise ParameterError(f"spec must be a DPSpec, got {type(spec).__name__}")
    ns = [check_int("segments[]", n, low=1) for n in segments]
    rows = []
    for eps in spec.epsilons:
        m = gaussian_sigma(eps, spec.delta, 1.0)
        for n in ns:
            rows.append({"epsilon_per_message": eps, "delta": spec.delta, "noise_multiplier": m, "segments": n,
                         "epsilon_total": composed_epsilon(m, n, spec.delta, accountant=accountant),
                         "accountant": accountant})
    return rows
