"""How a fleet fuses its segments: in the clear (the service sums the inversions it receives) or by
secure aggregation (the service learns only each round's sum).

The policy is the fleet authority's, written by ``roadcollab enroll`` into ``fleet.toml`` (table
``[aggregation]``) and read by the service and by every vehicle: the privacy parameters (``k``, ``t``,
``c``, the clip) are not the service's to choose, and a vehicle refuses a round outside them
(:class:`~roadcollab.privacy.secagg_active.SecAggVehicle` checks the roster against its spec).

In secure mode a vehicle's input to the round of segment ``s`` is its band-limited inversion on the
segment's ``m`` grid points with the coverage beside it, one ``(2m, 2)`` array
(:func:`segment_input`)::

    z[0:m]  = inversion (m), zero where the vehicle did not pass
    z[m:2m] = 1 where it passed, else 0 (both columns)

so the revealed sum gives at once the total and the count of :class:`~roadcollab.network.engine.SegmentSums`
(:func:`sums_from_total`): the fused estimate of a segment is the same average of inversions as in the
clear, to the fixed-point resolution ``2^-frac_bits`` m.

Under ``mode = "validated"`` a segment's sum comes from a phased validated session with three aggregators,
the service and two other operators (two with ``aggregators = 2``; :mod:`~roadcollab.network.prioround`,
:mod:`~roadcollab.network.validated_rounds`):
every input is proven inside the public box ``[-clip_m, clip_m]`` and then, phase after phase, its deviation
from the previous result inside an l2 ball (centred clipping), so no vehicle moves the result by more than
about ``R / (n - 1)`` (``R = deviation_m * sqrt(2 m)``). Clipping deviations would cut a coverage row, so
the input is the inversion alone, ``(m, 2)`` flattened (:func:`validated_input`), from vehicles that covered
every grid point of the segment; the count of every point is the number of inputs accepted
(:func:`sums_from_mean`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .._validation import check_int, check_real
from ..errors import ParameterError
from ..experiments.drives.distance_maps import covered
from ..privacy.secagg_flp import ValidityEncoding
from ..privacy.secagg_messages import SecAggSpec
from ..privacy.secagg_phased import colluder_schedule
from .engine import Contribution
from .plan import RoadPlan
from .prioround import PrioParams

__all__ = ["AggregationPolicy", "segment_input", "sums_from_total", "validated_input", "validated_segments", "validated_params",
           "validated_schedule", "validated_radii", "sums_from_mean", "MODES", "HELPER_IDS"]

MODES = ("clear", "secure", "validated")
#: The helpers' certificate ids, in order (a fleet with two aggregators has the first only).
HELPER_IDS = ("aggregator-b", "aggregator-c")
#: Policy fields read as numbers (the others are integers).
_FLOATS = ("clip_m", "deviation_m", "resolution_m")


@dataclass(frozen=True)
class AggregationPolicy:
    """The fleet's fusion rule.

    Attributes
    ----------
    mode : str
        ``clear`` or ``secure``.
    round_size : int
        ``n``: vehicles invited to one round (the first ``n`` that contributed to the segment and were
        not in a round of it yet); ``min_inputs <= n <= 2 t - c - 1``.
    min_inputs : int
        ``k``: the fewest inputs whose sum may be revealed.
    threshold : int
        ``t``: Shamir threshold (``t <= k``); privacy against the service plus ``c < t`` vehicles.
    max_colluders : int
        ``c``.
    clip_m : float
        Public bound on every elevation sent into a round, m (values beyond it are clipped at the
        source: the fused estimate then differs from the clear one).
    frac_bits : int
        Fixed-point resolution ``2^-frac_bits`` m.
    deviation_m : float
        ``validated``: public bound on the rms deviation of an honest vehicle's inversion from the segment's
        mean, m; the later phases' l2 ball is ``R = deviation_m * sqrt(2 m)``. An honest input farther out is
        scaled onto it (the result then differs from the clear mean).
    phases : int
        ``validated``: ``K`` (0: the public schedule of :func:`validated_radii`, which works off the largest
        phase-1 shift of ``max(1, max_colluders)`` lying vehicles among ``min_inputs``; given, the last
        ``K - 1`` balls of that schedule).
    resolution_m : float
        ``validated``: fixed-point step of the proofs, m.
    aggregators : int
        ``validated``: 3 (the service and two helpers; one aggregator that deviates is caught) or 2 (one
        helper: privacy of the later phases needs both aggregators to follow the protocol). A fleet file
        without the key was enrolled before there was a choice, with 2.
    """

    mode: str = "clear"
    round_size: int = 5
    min_inputs: int = 5
    threshold: int = 5
    max_colluders: int = 0
    clip_m: float = 1.0
    frac_bits: int = 40
    deviation_m: float = 0.01
    phases: int = 0
    resolution_m: float = 2.0 ** -12
    aggregators: int = 3

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ParameterError(f"aggregation mode must be one of {MODES}, got {self.mode!r}")
        spec = self.spec                                    # checks k, t, c, clip, frac_bits
        check_int("round_size", self.round_size, low=spec.min_inputs, high=spec.max_roster)
        check_real("clip_m", self.clip_m, low=0.0, low_open=True, high=1e3)
        check_real("deviation_m", self.deviation_m, low=0.0, low_open=True, high=self.clip_m)
        check_int("phases", self.phases, low=0, high=32)
        check_real("resolution_m", self.resolution_m, low=1e-9, high=self.clip_m / 4)
        check_int("aggregators", self.aggregators, low=2, high=3)
        if self.validated and self.min_inputs <= 2 * self.liars:
            raise ParameterError(f"validated aggregation against {self.liars} lying vehicles (max_colluders, at least 1) "
                                 f"needs min_inputs above {2 * self.liars}, got {self.min_inputs}")

    @property
    def secure(self) -> bool:
        """The service sees no inversion: the sums come from rounds (``secure`` or ``validated``)."""
        return self.mode in ("secure", "validated")

    @property
    def liars(self) -> int:
        """``validated``: lying vehicles the phase schedule is built for, ``max(1, max_colluders)``."""
        return max(1, self.max_colluders)

    @property
    def validated(self) -> bool:
        """Phased validated sessions with two or three aggregators (module docstring)."""
        return self.mode == "validated"

    @property
    def spec(self) -> SecAggSpec:
        """The :class:`~roadcollab.privacy.secagg_messages.SecAggSpec` of every round."""
        return SecAggSpec(min_inputs=self.min_inputs, threshold=self.threshold, clip=self.clip_m,
                          frac_bits=self.frac_bits, max_colluders=self.max_colluders)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict, where: str) -> "AggregationPolicy":
        """The policy from a table read from ``where`` (unknown keys and wrong types refused, naming it).

        Parameters
        ----------
        data : dict
        where : str
        """
        if not isinstance(data, dict):
            raise ParameterError(f"{where}: expected an [aggregation] table")
        extra = sorted(set(data) - set(cls.__dataclass_fields__))
        if extra:
            raise ParameterError(f"{where}: unknown aggregation keys {extra}; expected some of "
                                 f"{sorted(cls.__dataclass_fields__)}")
        kw: dict = {} if "aggregators" in data or data.get("mode") != "validated" else {"aggregators": 2}
        for k, v in data.items():
            if k == "mode":
                kw[k] = v
            elif k in _FLOATS:
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ParameterError(f"{where}: aggregation.{k} must be a number, got {v!r}")
                kw[k] = float(v)
            else:
                if isinstance(v, bool) or not isinstance(v, int):
                    raise ParameterError(f"{where}: aggregation.{k} must be an integer, got {v!r}")
                kw[k] = v
        try:
            return cls(**kw)
        except (ParameterError, ValueError) as err:
            raise ParameterError(f"{where}: aggregation: {err}") from None


def segment_input(plan: RoadPlan, c: Contribution) -> np.ndarray:
    """A vehicle's round input for its contribution ``c`` (module docstring).

    Parameters
    ----------
    plan : RoadPlan
    c : Contribution

    Returns
    -------
    (2 m, 2) ndarray
        ``m = plan.points_per_segment``; inversion in m, then the coverage (0 or 1).
    """
    m = plan.points_per_segment
    a = c.i0 - plan.segment_range(c.segment)[0]
    z = np.zeros((2 * m, 2))
    z[a:a + c.n] = c.inversion
    z[m + a:m + a + c.n] = 1.0
    return z


def sums_from_total(plan: RoadPlan, total: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(total, count)`` of a segment from a round's revealed sum of :func:`segment_input` arrays.

    Parameters
    ----------
    plan : RoadPlan
    total : (2 m, 2) array_like
        The round's sum.

    Returns
    -------
    total : (m, 2) ndarray
        Sum of the inversions, m.
    count : (m,) ndarray of int64
        Inputs covering each point.

    Raises
    ------
    ParameterError
        The coverage rows are not whole numbers equal in both columns (a vehicle sent something other
        than 0 or 1 there).
    """
    m = plan.points_per_segment
    total = np.asarray(total, float)
    if total.shape != (2 * m, 2):
        raise ParameterError(f"round sum: expected shape {(2 * m, 2)}, got {total.shape}")
    cov = total[m:]
    count = np.rint(cov[:, 0])
    if np.max(np.abs(cov - count[:, None]), initial=0.0) > 1e-6 or np.any(count < 0):
        raise ParameterError("round sum: the coverage rows are not whole counts (an input was not 0/1 there)")
    return total[:m].copy(), count.astype(np.int64)


def validated_input(plan: RoadPlan, c: Contribution) -> np.ndarray | None:
    """A vehicle's input to the validated session of ``c.segment``: its inversion there, flattened, or None
    when it did not cover every grid point of the segment (module docstring).

    Parameters
    ----------
    plan : RoadPlan
    c : Contribution

    Returns
    -------
    (2 m,) ndarray or None
        Point by point, both tracks (``inversion.ravel()``), m.
    """
    m = plan.points_per_segment
    if c.n != m or c.i0 != plan.segment_range(c.segment)[0] or not np.all(np.isfinite(c.inversion)):
        return None
    return np.asarray(c.inversion, float).reshape(-1).copy()


def validated_segments(engine) -> list[int]:
    """The segments a vehicle's engine covers at every grid point (its inversion and observer finite):
    those it can give to a validated session.

    Parameters
    ----------
    engine : VehicleEngine

    Returns
    -------
    list of int
    """
    plan, ok = engine.plan, covered(engine.inversion) & covered(engine.single)
    out = []
    for s in engine.segments:
        a, b = plan.segment_range(s)
        if a >= engine.i_first and b - 1 <= engine.i_last and bool(np.all(ok[a - engine.i_first:b - engine.i_first])):
            out.append(s)
    return out


def validated_radii(plan: RoadPlan, policy: AggregationPolicy) -> list[float]:
    """The balls of phases ``2..K`` of the public schedule
    (:func:`~roadcollab.privacy.secagg_phased.colluder_schedule`): built for ``c = max(1, max_colluders)``
    lying vehicles among ``n = min_inputs`` (the fewest a session accepts; fewer honest vehicles pull back
    less), from the liars' largest shift of ``m_1``, ``c 2 clip_m sqrt(2 m) / n``, down to
    ``R = deviation_m sqrt(2 m)``, then 2 phases at ``R``.

    Parameters
    ----------
    plan : RoadPlan
    policy : AggregationPolicy
    """
    L, n, c = 2 * plan.points_per_segment, policy.min_inputs, policy.liars
    R = policy.deviation_m * math.sqrt(L)
    return colluder_schedule(c * 2.0 * policy.clip_m * math.sqrt(L) / n, R, n, c)


def validated_schedule(plan: RoadPlan, policy: AggregationPolicy) -> int:
    """``K`` of the public schedule (:func:`validated_radii`); with fewer phases (``policy.phases``) the liars
    keep part of their phase-1 shift.

    Parameters
    ----------
    plan : RoadPlan
    policy : AggregationPolicy
    """
    return 1 + len(validated_radii(plan, policy))


def validated_params(plan: RoadPlan, policy: AggregationPolicy) -> PrioParams:
    """The public parameters of every validated session of the fleet (module docstring).

    Parameters
    ----------
    plan : RoadPlan
    policy : AggregationPolicy

    Returns
    -------
    PrioParams
        Phase 1's box ``clip_m`` per value; phases ``2..K`` on the balls of :func:`validated_radii` (given
        ``policy.phases``, its last ``K - 1``, or more phases at ``R``).
    """
    L = 2 * plan.points_per_segment
    radii = validated_radii(plan, policy)
    want = policy.phases - 1
    if want == 0:
        radii = []
    elif want > 0:       # the schedule's last K - 1 balls, or it and more at R
        radii = radii[-want:] + [radii[-1]] * max(0, want - len(radii))
    wide = ValidityEncoding(np.full(L, policy.clip_m), policy.resolution_m)
    tight = tuple(ValidityEncoding(np.full(L, r), policy.resolution_m, norm=r) for r in radii)
    return PrioParams(wide, tight, min_inputs=policy.min_inputs, helper_ids=HELPER_IDS[:policy.aggregators - 1])


def sums_from_mean(plan: RoadPlan, mean: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(total, count)`` of a segment from a validated session's result over ``n`` inputs.

    Parameters
    ----------
    plan : RoadPlan
    mean : (2 m,) array_like
        The session's result ``m_K``.
    n : int
        Inputs accepted (each covered every grid point).

    Returns
    -------
    total : (m, 2) ndarray
    count : (m,) ndarray of int64
    """
    m = plan.points_per_segment
    mean = np.asarray(mean, float)
    if mean.shape != (2 * m,) or not np.all(np.isfinite(mean)) or n < 1:
        raise ParameterError(f"validated result: expected {2 * m} finite values over at least one input")
    return mean.reshape(m, 2) * n, np.full(m, int(n), dtype=np.int64)
