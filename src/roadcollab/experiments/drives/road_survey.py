"""Drives with GPS on a road network: per road and direction, the fused profile, IRI per segment and anomalies.

Pipeline
--------
1. Every drive is map-matched and placed on the roads it travels
   (:func:`roadcollab.geo.matching.road_passes`): per road, the whole record with positions in the
   lane coordinate ``u`` (the road measure, or ``length - measure`` against the road's direction).
2. Per road and direction (a lane: the two directions of a road are different wheel tracks), the
   passes go through :func:`~roadcollab.experiments.drives.fleet_estimation.estimate_fleet` with the
   cross-correlation alignment (``max_offset`` 5 m: the GPS offsets are good to about 0.2 m, the
   alignment catches what the matching left).
3. Each pass's aligned inversion is kept only on the road (``u_range``) and at least ``edge_m``
   from its record's ends (the inversion's window-edge effects reach about ``2 / n_low``, 48 m at
   12 m/s; the ends of a pass that continues onto another road are not record ends). With
   ``calibrate``, every vehicle's IRI gain (its estimated parameters scale its inversion over the IRI
   band) is fitted from the segments it shares with other vehicles, over all lanes at once
   (:mod:`~roadcollab.experiments.drives.gain_calibration`; drives of one ``vehicle_id`` share one
   gain), and each pass's inversion is divided by its vehicle's gain. The fused profile is their
   average where any covers.
4. Segments (:func:`roadcollab.geo.segments.segment_bounds`, fixed in the road's measure) fully
   covered by the fused profile get the IRI: the mean of the two wheel tracks' IRIs (the mean
   roughness index, MRI, which agencies report as "IRI"), m/km and in/mi; a 95 % bootstrap interval
   over the drives (``bootstrap`` resamples of the passes with replacement, re-fused; none below
   :data:`MIN_BOOTSTRAP_VEHICLES` vehicles). It is the drive-to-drive spread only: the estimate's
   bias (sensor noise adds roughness, +3 to +8 % on the simulated city) is not in it. The number
   of vehicles is the number of passes covering at least half of the segment.
5. Anomalies are found in the fused profile (:func:`~roadcollab.experiments.drives.fleet_estimation.find_fleet_anomalies`);
   their votes are the passes whose own inversion shows an anomaly of the same kind within
   ``vote_tolerance``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..._validation import check_int, check_real
from ...errors import ParameterError
from ...geo.matching import RoadPass, lonlat_at, road_passes
from ...geo.network import RoadNetwork
from ...geo.segments import IN_PER_MI_PER_M_PER_KM, segment_bounds, segment_lonlat
from ...models.iri import iri
from ...store import RoadStore
from .fleet_estimation import estimate_fleet, find_fleet_anomalies
from .gain_calibration import calibrate_gains

__all__ = ["MIN_BOOTSTRAP_VEHICLES", "SegmentEstimate", "AnomalyEstimate", "PassRow", "RoadSurvey", "survey_drives",
           "lane_survey", "store_survey", "vehicle_of"]

MIN_BOOTSTRAP_VEHICLES = 3   # two drives resample into three distinct sets: no interval worth the name


@dataclass(frozen=True, eq=False)
class SegmentEstimate:
    """One segment of one lane.

    Attributes
    ----------
    road_id : str
    direction : int
        +1 along the road's measure, -1 against it.
    from_m, to_m : float
        Road measure of the segment, m (``from_m < to_m`` whatever the direction).
    iri_m_per_km, iri_low, iri_high : float
        IRI (mean of the two tracks) and its 95 % bootstrap interval, m/km (NaN bounds with fewer than
        :data:`MIN_BOOTSTRAP_VEHICLES` vehicles).
    n_vehicles : int
    spacing : float
        Profile grid step, m.
    profile : (n, 2) ndarray
        Fused elevation (left, right), m, in the direction of travel.
    lonlat : (K, 2) ndarray
        Segment geometry, WGS 84 ``[lon, lat]`` along the road's measure.
    """

    road_id: str
    direction: int
    from_m: float
    to_m: float
    iri_m_per_km: float
    iri_low: float
    iri_high: float
    n_vehicles: int
    spacing: float
    profile: np.ndarray
    lonlat: np.ndarray

    @property
    def iri_in_per_mi(self) -> float:
        """IRI in inches per mile (1 m/km = 63.36 in/mi)."""
        return self.iri_m_per_km * IN_PER_MI_PER_M_PER_KM


@dataclass(frozen=True)
class AnomalyEstimate:
    """One anomaly found on a lane.

    Attributes
    ----------
    road_id : str
    direction : int
    measure_m : float
        Road measure of its centre, m.
    lon, lat : float
        WGS 84 degrees.
    kind, side : str
    depth_m : float
    votes : int
        Passes that saw it on their own.
    """

    road_id: str
    direction: int
    measure_m: float
    lon: float
    lat: float
    kind: str
    side: str
    depth_m: float
    votes: int


@dataclass(frozen=True)
class PassRow:
    """One pass of a drive along one road, a row of ``passes.csv`` (the fields are its columns, in order).

    Attributes
    ----------
    drive : str
        The drive's CSV file as given.
    road_id : str
        The road it was placed on.
    direction : int
        ``+1`` along the road's measure, ``-1`` against it.
    n_fixes : int
        GPS fixes of the pass.
    offset_std_m : float
        Standard error of the pass's along-road offset, m.
    u_from_m, u_to_m : float
        The stretch of the drive's own distance that lies on this road, m.
    """

    drive: str
    road_id: str
    direction: int
    n_fixes: int
    offset_std_m: float
    u_from_m: float
    u_to_m: float


@dataclass(frozen=True, eq=False)
class RoadSurvey:
    """Everything the drives said about the network.

    Attributes
    ----------
    segments : list of SegmentEstimate
    anomalies : list of AnomalyEstimate
    passes : list of PassRow
        One per drive and road it was placed on.
    band_low_per_m : dict
        ``{(road_id, direction): n_low}``, cycles/m: the wavenumber band the estimate sees.
    gains : list of VehicleGain
        Every vehicle's IRI gain, by ``vehicle_id`` (empty when not calibrated).
    """

    segments: list
    anomalies: list
    passes: list
    band_low_per_m: dict
    gains: list = dataclasses.field(default_factory=list)


def _kept(est, passes: list[RoadPass], length: float, edge_m: float) -> np.ndarray:
    """(V, n, 2): each pass's aligned inversion on its road and away from its record's ends (NaN elsewhere)."""
    x = est.position
    out = np.array(est.elevation["inversion"], copy=True)
    for j, (p, off) in enumerate(zip(passes, est.offsets)):
        u = p.drive.positions + off
        lo = max(p.u_range[0] + off, u[0] + edge_m, 0.0)
        hi = min(p.u_range[1] + off, u[-1] - edge_m, length)
        out[j, (x < lo) | (x > hi)] = np.nan
    return out


def _fuse(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(stack[..., 0])
    count = ok.sum(axis=0)
    with np.errstate(invalid="ignore"):
        fused = np.where(count[:, None] > 0, np.nansum(stack, axis=0) / np.maximum(count, 1)[:, None], np.nan)
    return fused, count


def _segment_iri(h: np.ndarray, spacing: float) -> float:
    return float(0.5 * (iri(h[:, 0], spacing) + iri(h[:, 1], spacing)))


def _bootstrap(stack: np.ndarray, sel: np.ndarray, spacing: float, n: int, rng: np.random.Generator
               ) -> tuple[float, float]:
    V = stack.shape[0]
    if V < MIN_BOOTSTRAP_VEHICLES or n == 0:
        return float("nan"), float("nan")
    vals = []
    for _ in range(n):
        fused, count = _fuse(stack[rng.integers(0, V, V)][:, sel])
        if np.all(count > 0):
            vals.append(_segment_iri(fused, spacing))
    if len(vals) < 10:
        return float("nan"), float("nan")
    return float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))


def _detections(est, kept: np.ndarray) -> list[list]:
    """Each pass's own detections (its kept inversion seen by the same virtual vehicle as the fused one)."""
    out: list[list] = []
    for j in range(kept.shape[0]):
        if np.count_nonzero(np.isfinite(kept[j, :, 0])) < 64:
            out.append([])
            continue
        out.append(find_fleet_anomalies(dataclasses.replace(est, elevation={**est.elevation,
                                                                            "fused": kept[j:j + 1]})))
    return out


def _votes(per_pass: list[list], det, tolerance: float) -> int:
    return sum(any(r.kind == det.kind and abs(r.position_m - det.position_m) <= tolerance for r in dets)
               for dets in per_pass)


def _windows(x: np.ndarray, dx: float, length: float, s: int, segment_length: float):
    """``(from_m, to_m, sel)`` of every segment of a lane whose grid points reach both of its ends."""
    for a, b in segment_bounds(length, segment_length):
        ua, ub = (a, b) if s > 0 else (length - b, length - a)
        sel = (x >= ua) & (x <= ub)
        if np.count_nonzero(sel) >= 2 and x[sel][0] - ua <= dx and ub - x[sel][-1] <= dx:
            yield a, b, sel


def _lane_stack(passes: list[RoadPass], network: RoadNetwork, edge_m: float, spacing: float):
    """The lane's fleet estimate and its passes' kept inversions (:func:`_kept`)."""
    length = network.roads[passes[0].road_id].length
    est = estimate_fleet([p.drive for p in passes], spacing=spacing, align=len(passes) > 1, max_offset=5.0)
    return est, _kept(est, passes, length, edge_m)


def _pass_iris(passes: list[RoadPass], network: RoadNetwork, est, kept: np.ndarray, segment_length: float):
    """``(vehicle, (road_id, direction, from_m), iri)`` of every pass over every segment it covers completely."""
    rid, s = passes[0].road_id, passes[0].direction
    out = []
    for a, _b, sel in _windows(est.position, est.spacing, network.roads[rid].length, s, segment_length):
        for p, h in zip(passes, kept):
            if np.all(np.isfinite(h[sel, 0])):
                out.append((vehicle_of(p.drive), (rid, s, float(a)), _segment_iri(h[sel], est.spacing)))
    return out


def _lane_results(passes: list[RoadPass], network: RoadNetwork, est, kept: np.ndarray, *, segment_length: float,
                  bootstrap: int, vote_tolerance: float, rng: np.random.Generator) -> tuple[list, list]:
    """Segments and anomalies of a lane from its passes' kept inversions."""
    rid, s = passes[0].road_id, passes[0].direction
    length = network.roads[rid].length
    fused, count = _fuse(kept)
    dx = est.spacing
    segments = []
    for a, b, sel in _windows(est.position, dx, length, s, segment_length):
        if not np.all(count[sel] > 0):
            continue
        lo, hi = _bootstrap(kept, sel, dx, bootstrap, rng)
        behind = int(np.sum(np.mean(np.isfinite(kept[:, sel, 0]), axis=1) >= 0.5))
        segments.append(SegmentEstimate(rid, s, a, b, _segment_iri(fused[sel], dx), lo, hi, behind,
                                        dx, fused[sel].copy(), segment_lonlat(network, rid, a, b)))
    anomalies = []
    if np.count_nonzero(count) >= 64:
        fest = dataclasses.replace(est, elevation={**est.elevation, "fused": fused[None]})
        per_pass = _detections(est, kept)
        for det in find_fleet_anomalies(fest):
            m = det.position_m if s > 0 else length - det.position_m
            lon, lat = lonlat_at(network, rid, m)
            anomalies.append(AnomalyEstimate(rid, s, float(m), float(lon[0]), float(lat[0]), det.kind, det.side,
                                             det.depth_m, _votes(per_pass, det, vote_tolerance)))
    return segments, anomalies


def vehicle_of(drive) -> str:
    """The vehicle that recorded ``drive``: its ``vehicle_id``, or its CSV's path when it names none.

    Parameters
    ----------
    drive : Drive

    Returns
    -------
    str
    """
    return drive.vehicle_id if drive.vehicle_id is not None else str(drive.csv_path)


def lane_survey(passes: list[RoadPass], network: RoadNetwork, *, segment_length: float = 100.0,
                edge_m: float = 30.0, bootstrap: int = 100, vote_tolerance: float = 2.0, spacing: float = 0.05,
                rng=None) -> tuple[list, list, float]:
    """Segments and anomalies of one lane (one road, one direction) from its passes, uncalibrated.

    Parameters
    ----------
    passes : list of RoadPass
        Same road and direction.
    network : RoadNetwork
    segment_length, edge_m, vote_tolerance, spacing : float
        m.
    bootstrap : int
        Resamples for the IRI interval (0: none).
    rng : numpy.random.Generator | int | None
        The bootstrap's resampling.

    Returns
    -------
    segments : list of SegmentEstimate
    anomalies : list of AnomalyEstimate
    band_low_per_m : float
    """
    est, kept = _lane_stack(passes, network, edge_m, spacing)
    seg, anom = _lane_results(passes, network, est, kept, segment_length=segment_length, bootstrap=bootstrap,
                              vote_tolerance=vote_tolerance, rng=np.random.default_rng(rng))
    return seg, anom, est.band_low_per_m


def survey_drives(drives, network: RoadNetwork, *, segment_length: float = 100.0, sigma_z: float = 5.0,
                  edge_m: float = 30.0, bootstrap: int = 100, calibrate: bool = False, reference=(),
                  rng=None) -> RoadSurvey:
    """Match every drive to the network, calibrate every vehicle's gain and survey every lane (module docstring).

    Parameters
    ----------
    drives : list of Drive
        With GPS fixes.
    network : RoadNetwork
    segment_length : float
        m (default 100).
    sigma_z : float
        GPS error standard deviation assumed by the matcher, m.
    edge_m : float
        Dropped at each record end, m.
    bootstrap : int
        IRI interval resamples.
    calibrate : bool
        Divide every pass's inversion by its vehicle's IRI gain before fusing
        (:func:`~roadcollab.experiments.drives.gain_calibration.calibrate_gains`); False: fuse as inverted.
    reference : iterable of str
        Vehicles whose gain is 1 (calibrated on a reference section): their components' anchors.
    rng : numpy.random.Generator | int | None

    Returns
    -------
    RoadSurvey

    Raises
    ------
    ParameterError
        No drive could be placed on any road, or a reference vehicle recorded none of the drives.
    """
    check_real("segment_length", segment_length, low=1.0, high=10_000.0)
    check_int("bootstrap", bootstrap, low=0, high=10_000)
    rng = np.random.default_rng(rng)
    reference = tuple(reference)
    if reference and not calibrate:
        raise ParameterError("--reference-vehicle needs --calibrate (it anchors the calibrated gains)")
    unknown = sorted(set(reference) - {vehicle_of(d) for d in drives})
    if unknown:
        raise ParameterError(f"--reference-vehicle {unknown[0]!r}: no drive's parameters file has that vehicle_id")
    lanes: dict = {}
    rows: list[PassRow] = []
    for d in drives:
        for p in road_passes(d, network, sigma_z=sigma_z):
            lanes.setdefault((p.road_id, p.direction), []).append(p)
            rows.append(PassRow(str(d.csv_path), p.road_id, p.direction, p.n_fixes, p.offset_std,
                                p.u_range[0], p.u_range[1]))
    if not lanes:
        raise ParameterError("no drive could be placed on any road of the network (every fix farther than 50 m "
                             "from every road, or passes shorter than 50 m)")
    stacks = {key: _lane_stack(passes, network, edge_m, 0.05) for key, passes in lanes.items()}
    gains: dict = {}
    if calibrate:
        gains = calibrate_gains([o for key, (est, kept) in stacks.items()
                                 for o in _pass_iris(lanes[key], network, est, kept, segment_length)],
                                reference=reference)
    segments, anomalies, bands = [], [], {}
    for key, passes in lanes.items():
        est, kept = stacks[key]
        if gains:
            kept = kept / np.array([gains[vehicle_of(p.drive)].gain for p in passes])[:, None, None]
        seg, anom = _lane_results(passes, network, est, kept, segment_length=segment_length, bootstrap=bootstrap,
                                  vote_tolerance=2.0, rng=rng)
        segments += seg
        anomalies += anom
        bands[key] = est.band_low_per_m
    return RoadSurvey(segments=segments, anomalies=anomalies, passes=rows, band_low_per_m=bands,
                      gains=sorted(gains.values(), key=lambda g: g.vehicle_id))


def store_survey(store: RoadStore, survey: RoadSurvey, *, source: str = "", at: str | None = None) -> tuple[int, int]:
    """Add a survey's segments and anomalies to the store (history kept, anomalies merged by position).

    Parameters
    ----------
    store : RoadStore
    survey : RoadSurvey
    source : str
        Recorded with every row (e.g. the command line).
    at : str, optional
        ISO 8601 time of the update; default now.

    Returns
    -------
    (int, int)
        Segments and anomaly detections written.
    """
    for s in survey.segments:
        store.record_segment(s.road_id, s.direction, s.from_m, s.to_m, s.lonlat, s.iri_m_per_km, iri_low=s.iri_low,
                             iri_high=s.iri_high, n_vehicles=s.n_vehicles, profile=s.profile,
                             profile_spacing_m=s.spacing, source=source, at=at)
    for a in survey.anomalies:
        store.record_anomaly(a.road_id, a.direction, a.measure_m, a.lon, a.lat, a.kind, a.side, a.depth_m,
                             max(a.votes, 1), source=source, at=at)
    return len(survey.segments), len(survey.anomalies)
