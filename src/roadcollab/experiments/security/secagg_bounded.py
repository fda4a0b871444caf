"""Bounded influence inside secure aggregation by phased, centred clipping (issue 20, section 2).

The ``secagg_valid`` node of :mod:`.fusion_poisoning` proves every input inside a box that must contain
the road, so one vehicle moves the aggregate by a road-sized ``2 B / n``. Here the same checked set of
vehicles runs ``phases`` validated sessions on one segment (:mod:`roadcollab.privacy.secagg_phased`):

- phase 1: the wide box of ``secagg_valid``; the public result is ``m_1 = mean u_i``;
- phase ``k > 1``: vehicle ``i`` submits ``d_i = u_i - m_{k-1}`` proven inside the l2 ball
  ``||d_i|| <= R_k`` (``R_k = R max(1, grow / 2^(k-2))``: wider balls first work off the phase-1 offset
  in fewer phases, ``grow`` and ``K`` from the largest offset ``2 ||B|| / n``, public; honest vehicles scale ``d_i`` down onto the ball instead of being refused), and
  ``m_k = m_{k-1} + mean d_i`` (centred clipping; Karimireddy, He and Jaggi, ICML 2021, eq. 2).

The radius is public: ``R^2 = kappa2 (1 - 1/n) sum_{k,t} C_kt`` with ``C`` the public expected inversion
error of :func:`~.fusion_poisoning.validity_box` (``E||e_i - e_bar||^2`` for independent errors; the
errors of the fleet are positively correlated, so honest spreads are smaller: measured at most 0.39 of
it). At the fixed point the attacker's deviation moves the aggregate by at most about ``R / (n - 1)``,
error-sized instead of road-sized, whatever it sends in any phase.

The node computes what the protocol reveals (no proofs; they are exercised in
tests/test_secagg_phased.py), then vehicle 1's guard as ``fused_secagg_guarded``. Adaptive strategies
(:data:`ADAPTIVE_STRATEGIES`) spend the attacker's whole ball in one direction in every phase:
``adaptive_anti_road`` (``-m``), ``adaptive_fake`` (a 5 cm pothole's signature where there is none) and
``adaptive_erase`` (minus the signatures of every true anomaly); its phase-1 input is its strategy clipped
into the wide box.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...privacy.secagg_phased import radius_schedule

__all__ = ["ADAPTIVE_STRATEGIES", "BOUNDED_FINAL", "BOUNDED_KAPPA2", "ball_radius", "centred_clipping"]

ADAPTIVE_STRATEGIES = ("adaptive_anti_road", "adaptive_fake", "adaptive_erase")
#: ``kappa2`` of the study node and its phases at ``R`` after the halving ones
#: (:func:`~roadcollab.privacy.secagg_phased.public_schedule`; docs/security-secagg.md).
BOUNDED_KAPPA2 = 0.25
BOUNDED_FINAL = 2


def ball_radius(C: np.ndarray, n: int, kappa2: float = BOUNDED_KAPPA2) -> float:
    """``R = sqrt(kappa2 (1 - 1/n) sum C)``, the public radius of phases 2 and later.

    Parameters
    ----------
    C : ndarray
        Public expected inversion error ``E|Z_kt - Z_kt^true|^2`` per active bin and track, (m/s)^2.
    n : int
        Vehicles in the session.
    kappa2 : float
        Stated multiple.

    Returns
    -------
    float
        ``R`` in the units of the validated vector.
    """
    return float(np.sqrt(kappa2 * (1.0 - 1.0 / n) * float(np.sum(C))))


def _onto_ball(d: np.ndarray, radius: float) -> tuple[np.ndarray, bool]:
    norm = float(np.sqrt(np.sum(d * d)))
    return (d, False) if norm <= radius else (d * (radius / norm), True)


def centred_clipping(first: Sequence[np.ndarray], raw: Sequence[np.ndarray], radius: float, phases: int, *,
                     adaptive: tuple[int, np.ndarray] | None = None, grow: float = 1.0) -> tuple[np.ndarray, int]:
    """The result of ``phases`` validated sessions over one checked set (module docstring).

    Parameters
    ----------
    first : sequence of (L,) ndarray
        Phase-1 inputs, inside the wide box (and quantised).
    raw : sequence of (L,) ndarray
        What each vehicle wants to send (its own inversion or its lie); phase ``k`` sends
        ``raw_i - m_{k-1}`` scaled onto the ball.
    radius : float
        ``R``.
    phases : int
        Sessions, at least 1.
    adaptive : (int, ndarray), optional
        An attacker's index and direction: it sends ``R_k dir / ||dir||`` in every phase after the first.
    grow : float
        Radius schedule :func:`~roadcollab.privacy.secagg_phased.radius_schedule` (1: ``R`` in every phase).

    Returns
    -------
    m : (L,) ndarray
        The final public result.
    clipped : int
        Inputs scaled onto the ball, over the phases (the attacker's included, except adaptive).
    """
    m = np.mean(first, axis=0)
    clipped = 0
    for radius_k in radius_schedule(radius, phases, grow):
        ds = []
        for i, r in enumerate(raw):
            if adaptive is not None and i == adaptive[0]:
                direction = adaptive[1]
                ds.append(direction * (radius_k / float(np.sqrt(np.sum(direction ** 2)))))
                continue
            d, c = _onto_ball(r - m, radius_k)
            clipped += c
            ds.append(d)
        m = m + np.mean(ds, axis=0)
    return m, clipped


def bounded_inputs(run: Any, msgs: Sequence[Any]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Phase-1 inputs (clipped into the wide box, quantised) and raw vectors of the encodable messages.

    Parameters
    ----------
    run : fusion_poisoning._Run
        With ``box`` set (``(SpectralBox, ValidityEncoding)``).
    msgs : sequence of InversionMessage

    Returns
    -------
    first, raw : lists of (L,) ndarray
        Non-finite inputs cannot be encoded and are in neither list (not counted).
    """
    box, enc = run.validity
    first, raw = [], []
    for m in msgs:
        with np.errstate(over="ignore", invalid="ignore"):
            u = box.to_vector(run.grid.rfft(m.z))
        if not np.all(np.isfinite(u)):
            continue
        first.append(enc.quantize(enc.clip(u)[0]))
        # Beyond the wide box a lie's phase-k deviation is projected anyway; 1e150 keeps the norm finite.
        raw.append(np.clip(u, -1e150, 1e150))
    return first, raw
