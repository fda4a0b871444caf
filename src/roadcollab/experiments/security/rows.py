"""Typed rows of the security study's tables (one frozen type per CSV; the fields are the columns).

``attack.csv`` (:class:`AttackRow`), ``exactness.csv`` (:class:`ExactnessRow`), ``linkability.csv``
(:class:`LinkabilityRow`), ``baselines.csv`` (:class:`BaselineRow`), ``dp_composition.csv``
(:class:`CompositionRow`), the privacy/accuracy frontier (:class:`FrontierPoint`) and ``fig8_10_poles.csv``
(:class:`PoleRow`, from :func:`pole_rows`); ``poisoning.csv`` is
:class:`~roadcollab.experiments.security.fusion_poisoning.PoisoningSummary`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...privacy.attacks import SUCCESS_TOLERANCE

__all__ = ["AttackRow", "ExactnessRow", "LinkabilityRow", "BaselineRow", "CompositionRow", "FrontierPoint",
           "PoleRow", "POLE_KINDS", "pole_rows", "attack_row"]

#: The pole sets of a Figs. 8-10 example, in the order of ``fig8_10_poles.csv``.
POLE_KINDS = ("true", "model_reduction", "pole_intersection", "multiplicity")


@dataclass(frozen=True)
class PoleRow:
    """One pole of a Figs. 8-10 example, a row of ``fig8_10_poles.csv``.

    Attributes
    ----------
    vehicle : int
        1-based vehicle whose message was attacked.
    kind : str
        One of :data:`POLE_KINDS`: the true poles, or the poles an attack recovered.
    real, imag : float
        The pole, rad/s.
    """

    vehicle: int
    kind: str
    real: float
    imag: float


def pole_rows(pole_examples: list[dict]) -> list[PoleRow]:
    """Rows of ``fig8_10_poles.csv``: every pole of every example, kind-major within an example.

    Parameters
    ----------
    pole_examples : list of dict
        The security study's Figs. 8-10 examples: ``vehicle`` and one array of poles (rad/s) per kind of
        :data:`POLE_KINDS`.

    Returns
    -------
    list of PoleRow
    """
    return [PoleRow(ex["vehicle"], kind, float(p.real), float(p.imag))
            for ex in pole_examples for kind in POLE_KINDS for p in np.asarray(ex[kind])]


@dataclass(frozen=True)
class AttackRow:
    """One (mechanism, attack, road, segments) cell of ``attack.csv``.

    Attributes
    ----------
    mechanism : str
    attack : str
    road : str
        The road the attacker is given: ``true``, ``fused`` (the fleet's published map), ``own``
        (its own inversion), or ``-`` (not needed).
    segments : int
        Messages of one vehicle combined per estimate (0 for the prior guess).
    median_rel_pole_error : float
        Median over messages of the median relative pole error (inf: nothing found).
    success_rate : float
        Fraction of messages with every pole within :data:`~roadcollab.privacy.attacks.SUCCESS_TOLERANCE`.
    n_messages : int
        Estimates scored.
    epsilon_total : float
        DP rows: the composed epsilon of ``segments`` messages (PLD accountant); NaN otherwise.
    """

    mechanism: str
    attack: str
    road: str
    segments: int
    median_rel_pole_error: float
    success_rate: float
    n_messages: int
    epsilon_total: float = float("nan")


def attack_row(mechanism: str, attack: str, road: str, segments: int, errors, epsilon_total: float = float("nan")
               ) -> AttackRow:
    """Score relative pole errors into an :class:`AttackRow`.

    Parameters
    ----------
    mechanism, attack, road : str
        The cell (see :class:`AttackRow`).
    segments : int
        Messages per estimate.
    errors : (n, 4) array_like
        Relative error of each target pole per estimate (inf where unmatched).
    epsilon_total : float
        Composed DP epsilon (NaN if not DP).

    Returns
    -------
    AttackRow
    """
    E = np.asarray(errors, dtype=float).reshape(len(errors), -1)
    return AttackRow(mechanism, attack, road, int(segments), float(np.median(np.median(E, axis=1))),
                     float(np.mean(np.all(E < SUCCESS_TOLERANCE, axis=1))), int(E.shape[0]), float(epsilon_total))


@dataclass(frozen=True)
class ExactnessRow:
    """``exactness.csv``: the largest relative change of any estimate against the clear exchange.

    Attributes
    ----------
    mechanism : str
    max_rel_diff : float
    """

    mechanism: str
    max_rel_diff: float


@dataclass(frozen=True)
class LinkabilityRow:
    """``linkability.csv``: how well a feature links one vehicle's messages across segments.

    Attributes
    ----------
    mechanism, feature : str
    auc : float
        P(a same-vehicle pair is closer than a different-vehicle pair); 0.5 = no information.
    top1_accuracy : float
        How often the nearest message from another segment is the same vehicle's.
    chance : float
        Top-1 accuracy by chance.
    """

    mechanism: str
    feature: str
    auc: float
    top1_accuracy: float
    chance: float


@dataclass(frozen=True)
class BaselineRow:
    """``baselines.csv``: accuracy and cost of one mechanism on the same segments.

    Attributes
    ----------
    mechanism : str
    mse_vehicle1, mse_vehicle2, mse_vehicle3 : float
        Road-velocity MSE of vehicles 1..3, (m/s)^2.
    ms_per_message : float
        Sender's compute per message (median), ms.
    bytes_per_message : int
        Bytes a vehicle sends per segment.
    note : str
    """

    mechanism: str
    mse_vehicle1: float
    mse_vehicle2: float
    mse_vehicle3: float
    ms_per_message: float
    bytes_per_message: int
    note: str = ""


@dataclass(frozen=True)
class CompositionRow:
    """``dp_composition.csv``: a per-message DP level composed over a vehicle's segments.

    Attributes
    ----------
    epsilon_per_message, delta : float
    noise_multiplier : float
        ``sigma / sensitivity`` of the per-message Gaussian mechanism.
    segments : int
        Messages composed.
    epsilon_total : float
        At the same ``delta`` (PLD accountant of ``dp-accounting``).
    """

    epsilon_per_message: float
    delta: float
    noise_multiplier: float
    segments: int
    epsilon_total: float


@dataclass(frozen=True)
class FrontierPoint:
    """One mechanism on the privacy/accuracy frontier: its strongest attack and its accuracy.

    Attributes
    ----------
    mechanism, attack, road : str
        The mechanism and its strongest attack (highest success, then lowest error).
    segments : int
    success_rate, median_rel_pole_error : float
        Of that attack.
    mse : float
        Receivers' road-velocity MSE under the mechanism, (m/s)^2 (vehicles 2-3, or the fused estimate).
    """

    mechanism: str
    attack: str
    road: str
    segments: int
    success_rate: float
    median_rel_pole_error: float
    mse: float
