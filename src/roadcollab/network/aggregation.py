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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .._validation import check_int, check_real
from ..errors import ParameterError
from ..privacy.secagg_messages import SecAggSpec
from .engine import Contribution
from .plan import RoadPlan

__all__ = ["AggregationPolicy", "segment_input", "sums_from_total", "MODES"]

MODES = ("clear", "secure")


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
    """

    mode: str = "clear"
    round_size: int = 5
    min_inputs: int = 5
    threshold: int = 5
    max_colluders: int = 0
    clip_m: float = 1.0
    frac_bits: int = 40

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ParameterError(f"aggregation mode must be one of {MODES}, got {self.mode!r}")
        spec = self.spec                                    # checks k, t, c, clip, frac_bits
        check_int("round_size", self.round_size, low=spec.min_inputs, high=spec.max_roster)
        check_real("clip_m", self.clip_m, low=0.0, low_open=True, high=1e3)

    @property
    def secure(self) -> bool:
        return self.mode == "secure"

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
        kw: dict = {}
        for k, v in data.items():
            if k == "mode":
                kw[k] = v
            elif k == "clip_m":
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ParameterError(f"{where}: aggregation.clip_m must be a number, got {v!r}")
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
