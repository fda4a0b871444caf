"""Road estimates from drives at different speeds, rates and starts, on one uniform distance grid.

Approach (kernels in :mod:`roadcollab.experiments.drives.distance_maps`)
------------------------------------------------------------------------
A vehicle's suspension is time-invariant in its own time, not in distance, so **every inversion
runs in the vehicle's own time base**: vehicle ``j`` is designed (Lemma 1) at a constant speed,
its mean speed, on ``SegmentGrid(N_j, rate_j)``; its observer ``D_j y_j``, its offline inversion
``W_reg P_hat_j^-1 y_j`` and (from drive 2 on) Algorithm 1 give road velocities ``w_j(t)``. Each
is integrated to the elevation at the sample instants (exact for the piecewise-constant road
velocity of the ZOH model) and mapped to road distance by a cubic spline through
``(p_j(t_k), h_j(t_k))``; the speed may vary within the drive, since ``p_j(t)`` is the logged or
integrated position. The only speed-dependent piece of the design is the noise model (the road
velocity's intensity scales with speed); it is a prior, evaluated at the drive's mean speed.

On the common grid every estimate is band-limited in **wavenumber** with the band weight from
``n_low = band_low_hz / v_min`` cycles/m, where ``v_min`` is the lowest speed of any drive: below
``band_low_hz`` in time (0.5 Hz) no vehicle's accelerometers see the road, and a slower vehicle
sees shorter wavelengths only (0.5 Hz is 24 m at 12 m/s, 36 m at 18 m/s). The weight is applied to
each drive's covered stretch separately.

* ``single``: the vehicle's own observer; ``inversion``: its own offline inversion.
* ``collaborative``: Algorithm 1 with the previous drive's inversion sent *through distance*: the
  previous elevation is evaluated at this vehicle's positions, differenced in this vehicle's time
  (``w = v(t) h'(p(t))``), band-limited by ``W_reg`` and fed through ``-S_j^-1 T_j``. Where the
  previous drive did not pass, the feed-forward is zero.
* ``fused`` (drive ``k``): the average over drives 1..k of the inversions covering each grid
  point (blank where none does).

Start positions known only to a few metres (GPS): with ``align=True`` each drive's offset is
estimated by cross-correlating its band-limited inversion against the running fused elevation of
the drives before it (within ``+-max_offset``), and the corrections are then shifted to mean zero
(the drives' mean start is kept: an absolute error common to every drive cannot be seen).

Limits: the road is assumed the same for every pass; the window edges of every drive carry
edge effects of the offline filters over roughly ``2 / n_low`` metres; lateral wander between the
tracks is not modelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...collaboration.drive_guard import GUARD_ROAD_DEFAULT
from ...detection.detector import DetectorSpec, detect_anomalies
from ...errors import ParameterError
from ...io.drives import Drive
from ...models.iri import IRISegments, iri_segments
from ...models.vehicle import FleetSpec
from ..config import ExperimentConfig
from .distance_maps import band_limit_stretch, covered, distance_grid, elevation_to_distance, estimate_offset
from .estimation import AnomalyRow, integrate_elevation
from .relay import VehicleRecord, collaborative_velocity, invert_drive, received_spectra, velocity_from_spectra

__all__ = ["FLEET_ESTIMATORS", "FleetEstimates", "VehicleRecord", "invert_drive", "estimate_fleet",
           "find_fleet_anomalies", "fused_iri", "drive_stretches", "covered_runs",
           "collaborative_velocity", "received_spectra", "velocity_from_spectra", "GUARD_ROAD_DEFAULT"]

FLEET_ESTIMATORS = ("single", "inversion", "collaborative", "fused")


@dataclass(frozen=True, eq=False)
class FleetEstimates:
    """Every estimate on one uniform distance grid.

    Attributes
    ----------
    drives : list of Drive
    position : (n,) ndarray
        Uniform distance grid, m.
    spacing : float
        Its step, m.
    elevation : dict
        ``{estimator: (V, n, 2) ndarray}`` for :data:`FLEET_ESTIMATORS`, m, band-limited from
        ``band_low_per_m``; NaN where drive ``j`` (or, for ``fused``, drives 1..j) did not pass.
    offsets : (V,) ndarray
        Corrections added to every drive's positions, m (zeros unless aligned).
    offset_peaks : (V,) ndarray
        Normalised correlation at each estimated offset (NaN for the reference or unaligned).
    band_low_per_m : float
        Wavenumber band edge, cycles/m.
    band_low_hz, gamma : float
        Band edge in time and observer parameter.
    aligned : bool
        True if the offsets were estimated.
    receiver_guard : str
        The receiver guards' road prior (``"class"``, ``"own"``) or ``"none"`` (``guard=None``, the opt-out).
    """

    drives: list
    position: np.ndarray
    spacing: float
    elevation: dict
    offsets: np.ndarray
    offset_peaks: np.ndarray
    band_low_per_m: float
    band_low_hz: float
    gamma: float
    aligned: bool
    receiver_guard: str = GUARD_ROAD_DEFAULT

    @property
    def fused(self) -> np.ndarray:
        """(n, 2) ndarray: the fused elevation of every drive, m (NaN where none passed)."""
        return self.elevation["fused"][-1]

    @property
    def coverage(self) -> np.ndarray:
        """(n,) int ndarray: how many drives passed each grid point."""
        return np.sum([covered(e) for e in self.elevation["inversion"]], axis=0)


def _posterior(rec: VehicleRecord) -> np.ndarray:
    """The record's posterior-fused inversion (set by the relay whenever a fleet posterior is given)."""
    if rec.w_posterior is None:
        raise ParameterError("a drive's record has no posterior inversion although a fleet posterior was given")
    return rec.w_posterior


def _to_grid(drive: Drive, w: np.ndarray, x: np.ndarray, shift: float) -> np.ndarray:
    """Elevation of a road velocity in the drive's time base, on the distance grid ``x`` (NaN outside)."""
    return elevation_to_distance(drive.positions + shift, integrate_elevation(w, drive.sample_rate), x)


def _align(band_inv: list[np.ndarray], dx: float, max_offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (m, mean zero) and correlation peaks of every drive against the running fusion."""
    V = len(band_inv)
    lags, peaks = np.zeros(V), np.full(V, np.nan)
    ref = band_inv[0].copy()
    count = covered(ref).astype(float)
    for j in range(1, V):
        lag, peaks[j] = estimate_offset(ref, band_inv[j], dx, max_offset)
        shift = int(round(lag / dx))
        lags[j] = lag                                     # sub-sample: positions are continuous
        moved = np.roll(band_inv[j], -shift, axis=0)
        if shift > 0:
            moved[-shift:] = np.nan
        elif shift < 0:
            moved[:-shift] = np.nan
        ok = covered(moved)
        total = np.where(count[:, None] > 0, np.nan_to_num(ref) * count[:, None], 0.0)
        total[ok] += moved[ok]
        count += ok
        ref = np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], np.nan)
    corrections = -lags
    return corrections - corrections.mean(), peaks


def _running_mean(stack: list[np.ndarray]) -> np.ndarray:
    """(V, n, C): the average over drives 1..k of the finite values, NaN where none."""
    arr = np.array(stack)
    ok = np.isfinite(arr)
    sums = np.cumsum(np.where(ok, arr, 0.0), axis=0)
    counts = np.cumsum(ok, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def estimate_fleet(drives: list[Drive], *, spacing: float = 0.05, align: bool = False, max_offset: float = 10.0,
                   gamma: float | None = None, band_low_hz: float | None = None, fleet: FleetSpec | None = None,
                   window: int | None = None, margin_s: float | None = None,
                   guard: str | None = GUARD_ROAD_DEFAULT) -> FleetEstimates:
    """Every drive's estimates and the fused elevation on one uniform distance grid (module docstring).

    Parameters
    ----------
    drives : list of Drive
        In driving order; any speeds (constant or logged), sample rates, starts and lengths.
    spacing : float
        Distance grid step, m.
    align : bool
        Estimate and apply each drive's start offset by cross-correlation.
    max_offset : float
        Largest offset searched between two drives, m (twice the GPS error of one).
    gamma, band_low_hz : float, optional
        Observer parameter and band edge in time (Hz); default the ExperimentConfig defaults.
    fleet : FleetSpec, optional
        A known fleet prior: ``fused`` then averages posterior-mean inversions (simulation studies;
        the command line uses the nominal ones).
    window, margin_s : int and float, optional
        Longest record inverted in one piece (samples) and the windows' margin (s), as
        :func:`~roadcollab.experiments.drives.estimation.estimate_drives`.
    guard : {"class", "own"} or None
        Road prior of every drive's receiver guard (:func:`invert_drive`); None: unguarded (the opt-out).

    Returns
    -------
    FleetEstimates

    Raises
    ------
    ParameterError
        No drives, or a vehicle the design rejects.
    """
    if not drives or not all(isinstance(d, Drive) for d in drives):
        raise ParameterError("drives must be a non-empty list of Drive (see load_drives)")
    base = ExperimentConfig()
    gamma = base.gamma if gamma is None else gamma
    band_low_hz = base.band_low_hz if band_low_hz is None else band_low_hz
    recs = [invert_drive(d, gamma=gamma, band_low_hz=band_low_hz, fleet=fleet, index=j, window=window,
                         margin_s=margin_s, guard=guard) for j, d in enumerate(drives)]
    n_low = band_low_hz / min(float(d.speeds().min()) for d in drives)
    pad = max_offset if align else 0.0
    x = distance_grid([d.positions[0] - pad for d in drives], [d.positions[-1] + pad for d in drives], spacing)
    def band(h):
        return band_limit_stretch(h, spacing, n_low)

    inv = [band(_to_grid(d, r.w_inversion, x, 0.0)) for d, r in zip(drives, recs)]
    offsets, peaks = _align(inv, spacing, max_offset) if align and len(drives) > 1 else (np.zeros(len(drives)),
                                                                                        np.full(len(drives), np.nan))
    if align:
        inv = [band(_to_grid(d, r.w_inversion, x, s)) for d, r, s in zip(drives, recs, offsets)]
    single = [band(_to_grid(d, r.w_single, x, s)) for d, r, s in zip(drives, recs, offsets)]
    collab = [single[0]] + [band(_to_grid(d, collaborative_velocity(r, d, x, inv[j - 1], s), x, s))
                            for j, (d, r, s) in enumerate(zip(drives, recs, offsets)) if j > 0]
    fuse_from = inv if fleet is None else [band(_to_grid(d, _posterior(r), x, s))
                                           for d, r, s in zip(drives, recs, offsets)]
    elevation = {"single": np.array(single), "inversion": np.array(inv), "collaborative": np.array(collab),
                 "fused": _running_mean(fuse_from)}
    return FleetEstimates(drives=list(drives), position=x, spacing=float(spacing), elevation=elevation,
                          offsets=offsets, offset_peaks=peaks, band_low_per_m=float(n_low),
                          band_low_hz=float(band_low_hz), gamma=float(gamma), aligned=bool(align),
                          receiver_guard=guard or "none")


def find_fleet_anomalies(est: FleetEstimates, spec: DetectorSpec | None = None) -> list[AnomalyRow]:
    """Anomalies in the fused elevation of every drive, seen by a virtual vehicle on the grid.

    A grid of step ``dx`` is the time grid of a vehicle at the drives' mean speed ``v`` sampled at
    ``v / dx``; its road velocity is ``v`` times the slope of the fused elevation.

    Parameters
    ----------
    est : FleetEstimates
    spec : DetectorSpec, optional
        Detector settings (default ``DetectorSpec()``).

    Returns
    -------
    list of AnomalyRow
        Estimator ``fused``, vehicle = the number of drives.
    """
    spec = DetectorSpec() if spec is None else spec
    v = float(np.mean([d.speed for d in est.drives]))
    rate = v / est.spacing
    V = len(est.drives)
    rows, errors = [], []
    for run in covered_runs(est.fused):       # separate stretches of road: one search each
        x, h = est.position[run], est.fused[run]
        w = np.zeros_like(h)
        w[:-1] = np.diff(h, axis=0) * rate
        try:
            dets = detect_anomalies(w, positions=x, speed=v, sample_rate=rate, spec=spec)
        except ParameterError as err:          # e.g. a stretch shorter than the longest template
            errors.append(err)
            continue
        rows += [AnomalyRow("fused", V, float(det.position), det.side, det.kind, float(det.depth),
                            float(det.confidence)) for det in dets]
    if errors and len(errors) == len(covered_runs(est.fused)):
        raise errors[0]
    return rows


def covered_runs(elevation: np.ndarray) -> list[slice]:
    """The contiguous covered stretches of an elevation on the grid, in road order.

    Parameters
    ----------
    elevation : (n, C) ndarray
        m, NaN where not covered.

    Returns
    -------
    list of slice
        Grid index ranges.
    """
    ok = covered(elevation).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok, [0]])))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def fused_iri(est: FleetEstimates, segment_length: float) -> tuple[IRISegments | None, str | None]:
    """IRI per segment of the fused elevation over the stretches any drive passed, or a note why not.

    Every separate covered stretch (drives that do not overlap) has its own segments from its start.

    Parameters
    ----------
    est : FleetEstimates
    segment_length : float
        m.

    Returns
    -------
    IRISegments or None
        None if every fused stretch is shorter than one segment (or the IRI's initialisation).
    str or None
        The note for the stretches without an IRI (None if every stretch has one).
    """
    parts, notes = [], []
    for run in covered_runs(est.fused):       # separate stretches of road: segments of each
        try:
            parts.append(iri_segments(est.position[run], est.fused[run], segment_length))
        except ParameterError as err:
            notes.append(f"{est.position[run][0]:.1f}-{est.position[run][-1]:.1f} m: {err}")
    if not parts:
        return None, f"IRI was not computed: {'; '.join(notes) or 'no drive covers the grid'}."
    def cat(k: str) -> np.ndarray:
        return np.concatenate([getattr(p, k) for p in parts])
    iri = IRISegments(start=cat("start"), end=cat("end"), left=cat("left"), right=cat("right"), tracks=parts[0].tracks)
    return iri, (f"IRI was not computed on {'; '.join(notes)}." if notes else None)


def drive_stretches(drives: list[Drive], min_overlap: float, offsets=None) -> list[tuple[list[int], float, float]]:
    """Group drives into stretches of road they share: two drives are together if they overlap by at
    least ``min_overlap`` metres (directly or through other drives).

    Parameters
    ----------
    drives : list of Drive
    min_overlap : float
        m (``roadcollab estimate`` uses the IRI segment length).
    offsets : (V,) array_like, optional
        Corrections added to every drive's positions, m (default zeros).

    Returns
    -------
    list of (drives, start_m, end_m)
        1-based drive numbers of each stretch and the stretch it covers, m, in road order.
    """
    shift = np.zeros(len(drives)) if offsets is None else np.asarray(offsets, dtype=float)
    spans = sorted((float(d.positions[0] + s), float(d.positions[-1] + s), j + 1)
                   for j, (d, s) in enumerate(zip(drives, shift)))
    groups: list[list] = []
    for lo, hi, j in spans:
        if groups and min(hi, groups[-1][2]) - lo >= min_overlap:
            groups[-1][0].append(j)
            groups[-1][2] = max(groups[-1][2], hi)
        else:
            groups.append([[j], lo, hi])
    return [(sorted(g), lo, hi) for g, lo, hi in groups]
