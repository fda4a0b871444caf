"""The per-segment engine: what one vehicle computes for each segment of road it passed.

The same steps as :func:`roadcollab.experiments.drives.fleet_estimation.estimate_fleet`, cut by segment so that
they can travel as messages (module docstring there for the method):

1. the vehicle designs its estimator (Lemma 1) at its mean speed and inverts its record in its own time
   (``single`` = observer ``D_j y_j``, ``inversion`` = ``W_reg P_hat_j^-1 y_j``);
2. it maps both to the fleet's distance grid and band-limits them in wavenumber over its covered stretch;
3. for each segment it passed it takes the message waiting there (the previous vehicle's band-limited
   inversion on that segment), and runs Algorithm 1 (eq. 12) over its drive with that elevation sent
   through distance (``collaborative``);
4. it emits, per segment, its :class:`Contribution`: the three estimates on the segment's grid points.
   The inversion is at once the message for the next vehicle and its term of the fused estimate
   (the running average of the inversions, :class:`SegmentSums`).

Everything here is deterministic in the drive and the plan: the transports only move the results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..experiments.drives.distance_maps import band_limit_stretch, covered, elevation_to_distance
from ..experiments.drives.estimation import integrate_elevation
from ..experiments.drives.fleet_estimation import GUARD_ROAD_DEFAULT, collaborative_velocity, invert_drive
from ..io.drives import Drive
from .plan import RoadPlan

__all__ = ["ESTIMATES", "Contribution", "SegmentSums", "VehicleEngine"]

#: The three per-vehicle estimates a contribution carries, in wire order.
ESTIMATES = ("single", "inversion", "collaborative")


@dataclass(frozen=True, eq=False)
class Contribution:
    """One vehicle's estimates on one segment.

    Attributes
    ----------
    segment : int
        Segment index (:class:`~roadcollab.network.plan.RoadPlan`).
    i0 : int
        Grid index of the first value (``i0 * spacing`` m).
    single, inversion, collaborative : (n, 2) ndarray
        Band-limited elevations, m, columns ``[left, right]``, all finite.
    """

    segment: int
    i0: int
    single: np.ndarray
    inversion: np.ndarray
    collaborative: np.ndarray

    @property
    def n(self) -> int:
        """Number of grid points."""
        return int(self.inversion.shape[0])


@dataclass(frozen=True, eq=False)
class SegmentSums:
    """The fused estimate of one segment as running sums (``fused = total / count`` where ``count > 0``).

    Attributes
    ----------
    segment : int
    total : (m, 2) ndarray
        Sum of the inversions on every grid point of the segment, m.
    count : (m,) ndarray
        How many inversions cover each grid point.
    """

    segment: int
    total: np.ndarray
    count: np.ndarray

    @classmethod
    def empty(cls, plan: RoadPlan, segment: int) -> "SegmentSums":
        m = plan.points_per_segment
        return cls(segment, np.zeros((m, 2)), np.zeros(m, dtype=np.int64))

    def add(self, plan: RoadPlan, c: Contribution) -> "SegmentSums":
        """The sums with one more inversion (a new object).

        Parameters
        ----------
        plan : RoadPlan
            The fleet's plan.
        c : Contribution
            On this segment.
        """
        a = c.i0 - plan.segment_range(self.segment)[0]
        total, count = self.total.copy(), self.count.copy()
        total[a:a + c.n] += c.inversion
        count[a:a + c.n] += 1
        return SegmentSums(self.segment, total, count)

    @property
    def fused(self) -> np.ndarray:
        """(m, 2) fused elevation, m; NaN where no vehicle passed."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count[:, None] > 0, self.total / np.maximum(self.count, 1)[:, None], np.nan)


class VehicleEngine:
    """One vehicle's side of the engine: its drive inverted once, then one :class:`Contribution` per segment.

    Parameters
    ----------
    drive : Drive
        The vehicle's recorded drive.
    plan : RoadPlan
        The fleet's grid, segments and design.
    index : int
        0-based vehicle number (only names the design's Vehicle).
    guard : {"class", "own"} or None
        Road prior of the receiver guard every waiting elevation goes through
        (:func:`~roadcollab.experiments.drives.fleet_estimation.invert_drive`); None: unguarded, the named opt-out
        (``roadcollab vehicle --unguarded-receive``).

    Raises
    ------
    ParameterError
        The design rejects the drive (a drive over fewer than 16 grid points has no segments: its
        band-limited estimates are blank, as in estimate_fleet).
    """

    def __init__(self, drive: Drive, plan: RoadPlan, *, index: int = 0, guard: str | None = GUARD_ROAD_DEFAULT
                 ) -> None:
        if not isinstance(drive, Drive):
            raise ParameterError(f"drive must be a Drive, got {type(drive).__name__}")
        self.drive, self.plan, self.guard = drive, plan, guard
        self.rec = invert_drive(drive, gamma=plan.gamma, band_low_hz=plan.band_low_hz, index=index, guard=guard)
        dx = plan.spacing
        # The indices distance_grid gives for this drive alone: the grid is multiples of dx, so a
        # drive's points are the same whichever other drives share the grid.
        self.i_first = int(np.ceil(drive.positions[0] / dx - 1e-9))
        self.i_last = int(np.floor(drive.positions[-1] / dx + 1e-9))
        if self.i_last < self.i_first:                   # shorter than one grid step: no segment
            self.i_last = self.i_first
        self.x = plan.positions(self.i_first, self.i_last + 1)
        self.single = self._band(self._to_grid(self.rec.w_single))
        self.inversion = self._band(self._to_grid(self.rec.w_inversion))

    def _to_grid(self, w: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        d = self.drive
        return elevation_to_distance(d.positions, integrate_elevation(w, d.sample_rate), self.x if x is None else x)

    def _band(self, h: np.ndarray) -> np.ndarray:
        return band_limit_stretch(h, self.plan.spacing, self.plan.band_low_per_m)

    @property
    def segments(self) -> list[int]:
        """Segments this vehicle covers (a finite inversion on at least one of their grid points)."""
        ok = np.flatnonzero(covered(self.inversion))
        if ok.size == 0:
            return []
        return self.plan.segments_of(self.i_first + int(ok[0]), self.i_first + int(ok[-1]))

    def collaborative(self, waiting: dict) -> np.ndarray:
        """Algorithm 1 over the drive with the waiting elevations sent through distance.

        Parameters
        ----------
        waiting : dict
            ``{segment: Contribution}`` of the previous vehicle on this vehicle's segments (any subset).

        Returns
        -------
        (n, 2) ndarray
            Band-limited elevation on this vehicle's grid, m; equal to ``single`` when nothing waits
            (the first vehicle, as in estimate_fleet).
        """
        if not waiting:
            return self.single
        segs = self.segments
        lo, hi = self.plan.segment_range(segs[0])[0], self.plan.segment_range(segs[-1])[1]
        xw = self.plan.positions(lo, hi)
        previous = np.full((hi - lo, 2), np.nan)
        for c in waiting.values():
            a, b = max(c.i0, lo), min(c.i0 + c.n, hi)
            if b > a:
                previous[a - lo:b - lo] = c.inversion[a - c.i0:b - c.i0]
        # The same windowed Algorithm 1 as estimate_fleet: one function, so the two cannot drift apart.
        return self._band(self._to_grid(collaborative_velocity(self.rec, self.drive, xw, previous, 0.0)))

    def contributions(self, waiting: dict | None = None) -> list[Contribution]:
        """One :class:`Contribution` per covered segment, with Algorithm 1 on ``waiting``.

        Parameters
        ----------
        waiting : dict, optional
            ``{segment: Contribution}`` waiting on this vehicle's segments.

        Returns
        -------
        list of Contribution
            In segment order; only the finite grid points of each.
        """
        collab = self.collaborative(waiting or {})
        ok = covered(self.inversion) & covered(self.single) & covered(collab)
        out = []
        for s in self.segments:
            a, b = self.plan.segment_range(s)
            a, b = max(a, self.i_first) - self.i_first, min(b, self.i_last + 1) - self.i_first
            idx = np.flatnonzero(ok[a:b])
            if idx.size == 0:
                continue
            sl = slice(a + idx[0], a + idx[-1] + 1)      # the covered stretch is contiguous
            out.append(Contribution(s, self.i_first + sl.start, self.single[sl].copy(), self.inversion[sl].copy(),
                                    collab[sl].copy()))
        return out
