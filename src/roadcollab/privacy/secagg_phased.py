"""Bounded influence by phased, centred clipping: several validated sessions over one checked set (issue 20, Sec. 2).

One validated session (:mod:`.secagg_validity`) bounds an input by a box that must contain the road, so
one vehicle moves the average by a road-sized ``2 B / n``. Here the same vehicles run ``K`` validated
sessions on one measurement (segment, epoch):

1. phase 1: ``u_i`` in the wide box (``wide``); the result ``m_1 = mean u_i`` goes to the session's vehicles;
2. phase ``k = 2..K``: vehicle ``i`` sends ``d_i = u_i - m_{k-1}``, scaled down onto the public l2 ball of
   ``tight`` (:attr:`~.secagg_flp.ValidityEncoding.norm`, proven in the FLP) if longer, and
   ``m_k = m_{k-1} + mean d_i`` (centred clipping, Karimireddy, He and Jaggi, ICML 2021).

The result is ``m_K``: ``mean u`` when no honest input is clipped; one vehicle moves it by about
``R / (n - 1)`` whatever it sends (its phase-1 offset ``2 B / n`` is removed by the later phases).

Rules (docs/security-secagg.md, "Phased sessions"):

- **Equal sets.** Phase ``k`` is combined only if its accepted set equals phase 1's: a sum over another
  set, with the public ``m_{k-1}``, would give a single input away (``sum_S d_i - sum_S' d_i``). A
  vehicle records phase 1's accepted set in its ledger (``record_view``) and sends nothing for a phase
  announced over another set; the aggregators abort the session, naming the vehicles whose phase-``k``
  input was refused or missing, and nothing after phase 1 is revealed (there is no result).
- **One session per measurement.** The ledger records the measurement once, before phase 1; a second
  phased (or plain) session on it gets nothing.
- What is revealed beyond ``mean u``: the intermediate ``m_k`` and the final result are functions of the
  clipped deviations. With no honest input clipped they are all ``mean u`` up to quantisation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_int
from ..errors import ParameterError
from .secagg_flp import ValidityEncoding
from . import secagg_replicated, secagg_replicated_run
from .secagg_messages import AggregationRefused
from .secagg_validity import ValidatedAggregate, run_validated_aggregation, submit

__all__ = ["PhasedResult", "check_encodings", "phase_session", "public_schedule", "radius_schedule", "colluder_schedule",
           "run_phased_session"]

#: ``tamper(phase, vehicle, submission) -> submission``: a malicious vehicle's change to what it sends
#: (a :class:`~.secagg_replicated.Upload` with three aggregators).
Tamper = Callable[[int, int, Any], Any]


@dataclass(frozen=True)
class PhasedResult:
    """The outcome of a phased session.

    Attributes
    ----------
    result : (L,) ndarray or None
        ``m_K`` (None: refused by the ledgers, fewer than ``min_inputs`` in phase 1, or aborted).
    accepted : tuple of int
        Phase 1's accepted set (every later phase's, unless aborted).
    refused : dict
        Vehicle id to the reason (the first phase that refused it).
    phases : int
        Phases completed.
    clipped : int
        Honest deviations scaled onto the ball, over the phases.
    """

    result: np.ndarray | None
    accepted: tuple[int, ...]
    refused: dict[int, str]
    phases: int
    clipped: int


def phase_session(session: bytes, phase: int) -> bytes:
    """The session bytes of phase ``phase`` of ``session`` (each phase is its own validated session).

    Parameters
    ----------
    session : bytes
        ``session_id(segment, epoch)``.
    phase : int
        1-based.
    """
    return bytes(session) + b"/phase" + int(phase).to_bytes(2, "little")


def radius_schedule(radius: float, phases: int, grow: float = 1.0) -> list[float]:
    """The balls of phases ``2..K``: ``R_k = R max(1, grow / 2^(k-2))`` (wider first, then ``R``).

    Parameters
    ----------
    radius : float
        ``R``, the last phases' ball.
    phases : int
        ``K``.
    grow : float
        ``>= 1``; 1 gives ``R`` in every phase.

    Returns
    -------
    list of float
        ``K - 1`` radii.
    """
    return [radius * max(1.0, grow / 2.0 ** j) for j in range(check_int("phases", phases, low=1) - 1)]


def public_schedule(offset: float, radius: float, final: int = 2) -> tuple[int, float]:
    """``(K, grow)`` that work off the largest phase-1 offset: ``grow = 2^ceil(log2(offset / R))``, halved per
    phase down to ``R``, then ``final`` phases at ``R``.

    Parameters
    ----------
    offset : float
        The largest shift of ``m_1`` one vehicle can cause, public: ``2 ||B||_2 / n`` for the wide box ``B``.
    radius : float
        ``R``.
    final : int
        Phases at ``R`` (at least 1).

    Returns
    -------
    phases : int
    grow : float
    """
    steps = max(0, math.ceil(math.log2(max(1.0, offset / radius))))
    return 1 + steps + check_int("final", final, low=1), float(2 ** steps)


def colluder_schedule(offset: float, radius: float, n: int, c: int = 1, final: int = 2) -> list[float]:
    """The balls of phases ``2..K`` that work off the shift ``c`` lying vehicles among ``n`` give ``m_1``.

    The worst case, with the honest inputs close together: a distance ``s`` of ``m_{k-1}`` from the honest mean,
    a ball of radius ``r = s`` (no honest deviation clipped) and the liars' whole balls pointing away give
    ``s_k = c (s + r) / n = (2 c / n) s``. So ``r_k = s_{k-1}`` from ``s_1 = offset`` until ``s <= R``, then
    ``final`` phases at ``R``, where ``s`` settles near ``c R / (n - c)``. For ``c = 1``, ``n = 4`` the radii
    halve, as in :func:`public_schedule`.

    Parameters
    ----------
    offset : float
        The largest shift of ``m_1`` the liars can cause, public: ``c 2 ||B||_2 / n``.
    radius : float
        ``R``.
    n : int
        The fewest inputs a session accepts (``k``): fewer honest vehicles pull back less.
    c : int
        Lying vehicles the schedule is built for; ``n > 2 c``.
    final : int
        Phases at ``R``.

    Returns
    -------
    list of float
        ``K - 1`` radii.
    """
    n, c = check_int("n", n, low=1), check_int("c", c, low=1)
    if n <= 2 * c:
        raise ParameterError(f"a schedule against {c} lying vehicles needs more than {2 * c} inputs, got {n}")
    s, q = float(offset), 2.0 * c / n
    out: list[float] = []
    while s > radius and len(out) < 64:
        out.append(s)
        s *= q
    return out + [float(radius)] * check_int("final", final, low=1)


def check_encodings(wide: ValidityEncoding, tight: ValidityEncoding | Sequence[ValidityEncoding],
                    phases: int) -> list[ValidityEncoding]:
    """The encodings of phases ``2..K``: ``tight`` repeated or one per phase, each with a norm bound and ``wide``'s length.

    Parameters
    ----------
    wide : ValidityEncoding
    tight : ValidityEncoding or sequence of them
    phases : int
        ``K``.

    Raises
    ------
    ParameterError
        Another count, an encoding without ``norm``, or another length.
    """
    phases = check_int("phases", phases, low=1)
    encs = [tight] * (phases - 1) if isinstance(tight, ValidityEncoding) else list(tight)
    if len(encs) != phases - 1:
        raise ParameterError(f"tight: one encoding per phase after the first ({phases - 1}), got {len(encs)}")
    for e in encs:
        if not e.norm:
            raise ParameterError("tight: the later phases need encodings with a norm bound (ValidityEncoding(norm=R))")
        if wide.length != e.length:
            raise ParameterError(f"wide and tight must have the same length, got {wide.length} and {e.length}")
    return encs


@dataclass(frozen=True)
class _Aggregators:
    """How a phase is validated: two aggregators with a shared key (:mod:`.secagg_validity`) or three with
    replicated shares and coin-tossed query randomness (:mod:`.secagg_replicated`)."""

    count: int
    verify_key: bytes
    gen: np.random.Generator

    def submit(self, enc: ValidityEncoding, u: np.ndarray, session: bytes, vehicle: int, identity: Any) -> Any:
        if self.count == 3:
            return secagg_replicated.submit(enc, u, session, vehicle, self.gen, aggregators=3, identity=identity)
        return submit(enc, u, session, vehicle, self.gen, identity=identity)

    def aggregate(self, fleet: Any, enc: ValidityEncoding, subs: dict[int, Any], session: bytes) -> ValidatedAggregate:
        if not subs:
            return ValidatedAggregate(None, (), {})
        certs = {i: fleet.vehicles[i].identity.certificate for i in subs}
        if self.count == 3:
            return secagg_replicated_run.run_replicated_aggregation(
                enc, subs, session, aggregators=3, min_inputs=fleet.spec.min_inputs, trust=fleet.trust,
                certificates=certs, rng=self.gen)
        return run_validated_aggregation(enc, subs, session, verify_key=self.verify_key,
                                         min_inputs=fleet.spec.min_inputs, trust=fleet.trust, certificates=certs)


def _later_phase(fleet: Any, us: dict[int, np.ndarray], m: np.ndarray, k: int, session: bytes,
                 announced: tuple[int, ...], tight: ValidityEncoding, aggs: _Aggregators,
                 tamper: Tamper | None) -> tuple[ValidatedAggregate, dict[int, str], int]:
    """Phase ``k``: every vehicle of ``announced`` checks the set against its ledger and sends its clipped ``d``."""
    subs, refused, clipped = {}, {}, 0
    for i in announced:
        if i not in us:
            refused[i] = f"vehicle {i} sends nothing in phase {k}: it had no input in phase 1"
            continue
        try:
            fleet.vehicles[i].ledger.record_view(session, announced)
        except AggregationRefused as e:
            refused[i] = f"vehicle {i} sends nothing in phase {k}: {e}"
            continue
        d, c = tight.onto_ball(us[i] - m)
        clipped += c
        sub = aggs.submit(tight, np.clip(d, -tight.bounds, tight.bounds), phase_session(session, k), i,
                          fleet.vehicles[i].identity)
        subs[i] = sub if tamper is None else tamper(k, i, sub)
    out = aggs.aggregate(fleet, tight, subs, phase_session(session, k))
    return out, {**refused, **out.refused}, clipped


def run_phased_session(fleet: Any, inputs: dict[int, ArrayLike], session: bytes, wide: ValidityEncoding,
                       tight: ValidityEncoding | Sequence[ValidityEncoding], *, phases: int, verify_key: bytes, rng: Any = None,
                       tamper: Tamper | None = None,
                       announce: Callable[[int, tuple[int, ...]], tuple[int, ...]] | None = None,
                       aggregators: int = 2) -> PhasedResult:
    """A phased session among the certified vehicles of ``fleet`` (module docstring), both aggregators in-process.

    Parameters
    ----------
    fleet : SecAggFleet
        Certified vehicles with their ledgers; ``fleet.spec.min_inputs`` is ``k``.
    inputs : dict
        Vehicle id to its input (``L`` values).
    session : bytes
        ``session_id(segment, epoch)``.
    wide : ValidityEncoding
        Phase 1's box.
    tight : ValidityEncoding or sequence of them
        The later phases' (with ``norm``), one for all or one per phase (:func:`radius_schedule`).
    phases : int
        ``K >= 1``.
    verify_key : bytes
        The aggregators' shared key.
    rng : int or numpy.random.Generator, optional
    tamper : callable, optional
        ``tamper(phase, vehicle, submission) -> submission``.
    announce : callable, optional
        ``announce(phase, accepted) -> set``: what a deviating aggregator announces for phase ``k > 1``.
    aggregators : int
        2: the two aggregators of :mod:`.secagg_validity` (``verify_key`` shared); 3: three aggregators with
        replicated shares (:mod:`.secagg_replicated`, coin-tossed query randomness; ``verify_key`` unused),
        which keeps privacy and soundness when one of them deviates. The result is the same.

    Returns
    -------
    PhasedResult
    """
    encs = check_encodings(wide, tight, phases)
    if aggregators not in (2, 3):
        raise ParameterError(f"aggregators must be 2 or 3, got {aggregators!r}")
    gen = np.random.default_rng(rng)
    aggs = _Aggregators(aggregators, verify_key, gen)
    subs: dict[int, Any] = {}
    refused: dict[int, str] = {}
    us = {}
    for i, z in sorted(inputs.items()):
        try:
            fleet.vehicles[i].ledger.record_contribution(session, sorted(inputs))
        except AggregationRefused as e:
            refused[i] = f"vehicle {i} sends nothing: {e}"
            continue
        us[i], _ = wide.clip(np.asarray(z, float).ravel())
        sub = aggs.submit(wide, us[i], phase_session(session, 1), i, fleet.vehicles[i].identity)
        subs[i] = sub if tamper is None else tamper(1, i, sub)
    first = aggs.aggregate(fleet, wide, subs, phase_session(session, 1))
    refused.update(first.refused)
    if first.average is None:
        return PhasedResult(None, first.accepted, refused, 0, 0)
    accepted, m, clipped = first.accepted, first.average, 0
    for i in accepted:          # the checked set, kept by every vehicle of it for the later phases
        fleet.vehicles[i].ledger.record_view(session, accepted)
    for k, enc in enumerate(encs, start=2):
        announced = tuple(accepted) if announce is None else tuple(announce(k, accepted))
        out, why, c = _later_phase(fleet, us, m, k, session, announced, enc, aggs, tamper)
        clipped += c
        if out.average is None or out.accepted != accepted:
            missing = {i: why.get(i, f"vehicle {i}: no input in phase {k}") for i in accepted if i not in out.accepted}
            return PhasedResult(None, accepted, {**refused, **why, **missing}, k - 1, clipped)
        m = m + out.average
    return PhasedResult(m, accepted, refused, len(encs) + 1, clipped)
