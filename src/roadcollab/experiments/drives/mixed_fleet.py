"""Simulated fleets at mixed speeds over the packaged measured profile, scored on distance.

:func:`mixed_fleet_check` is the reproducible check of issue 10: drives at 12, 15, 18 and 13-17 m/s
(the last varying within the drive) over the measured profile, estimated by
:func:`~roadcollab.experiments.drives.fleet_estimation.estimate_fleet`, scored as the normalised MSE of
the elevation in the 0.5-15 m wavelength band against the truth. ``tools/mixed_fleet_check.py``
prints it.

Scoring: the truth (the profile, linear between its points, as the vehicles saw it) passes the same
wavenumber weight as the estimates (from ``band_low_per_m``), then truth and estimate alike pass the
scoring band (Butterworth-shaped edges at 1/15 and 2 cycles/m). NMSE = mean square error / mean square
truth over the stretch every drive covered, minus ``margin`` metres at either end (window edges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...io.drives import Drive
from ...io.profiles import measured_road
from ...models.profile import RoadProfile
from ...models.simulation import add_sensor_noise, discretize_plant, simulate_response
from ...models.vehicle import FleetSpec, Vehicle, sample_fleet
from .distance_maps import band_limit_stretch
from .fleet_estimation import FLEET_ESTIMATORS, FleetEstimates, estimate_fleet

__all__ = ["MIXED_SPEEDS", "SCORE_WAVELENGTHS", "MixedFleetRow", "MixedFleetResult", "simulate_drive", "score_fleet",
           "mixed_fleet_check"]

MIXED_SPEEDS = (12.0, 15.0, 18.0, (13.0, 17.0))
SCORE_WAVELENGTHS = (0.5, 15.0)   # m
_SPEED_PERIOD = 20.0              # s: period of the sinusoidal speed of a varying drive


def _speed_at(speed, t: np.ndarray) -> np.ndarray:
    """Speed (m/s) at times ``t``: constant, or ``(low, high)`` swept sinusoidally."""
    if isinstance(speed, tuple):
        lo, hi = speed
        return 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.sin(2 * np.pi * t / _SPEED_PERIOD)
    return np.full(t.shape, float(speed))


def simulate_drive(road: RoadProfile, vehicle: Vehicle, speed, *, start: float, end_margin: float = 5.0,
                   sample_rate: float = 200.0, noise_std: float = 0.05, given_start: float | None = None,
                   rng=None) -> Drive:
    """One vehicle's pass over ``road`` from ``start`` to near its end, as a :class:`Drive`.

    The elevation is sampled at the positions ``p(t_k)`` and taken as linear between samples, so the
    road velocity is piecewise constant and the ZOH simulation is exact, at any speed profile.

    Parameters
    ----------
    road : RoadProfile
    vehicle : Vehicle
        True parameters drive the simulation; the Drive carries the estimated ones.
    speed : float or (float, float)
        Constant speed, or ``(low, high)``: a sinusoidal sweep (period 20 s), m/s.
    start : float
        True road position of the first sample, m.
    end_margin : float
        The drive stops this far before the profile's end, m.
    sample_rate, noise_std : float
        Hz and m/s^2.
    given_start : float, optional
        The start recorded in the Drive (e.g. with a GPS error); default ``start``.
    rng : numpy.random.Generator | int | None
        Sensor noise.

    Returns
    -------
    Drive
        ``speed_source`` is ``"parameters"`` for a constant speed, ``"speed_mps column"`` otherwise.
    """
    rng = np.random.default_rng(rng)
    end = float(road.distance[-1]) - end_margin
    vmin = min(speed) if isinstance(speed, tuple) else float(speed)
    n = int(math.ceil((end - start) / vmin * sample_rate)) + 2
    t = np.arange(n) / sample_rate
    v = _speed_at(speed, t)
    p = start + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]) / sample_rate
    n = int(np.searchsorted(p, end))
    p, t, v = p[:n], t[:n], v[:n]
    h = np.column_stack([np.interp(p, road.distance, road.elevation[:, c]) for c in range(2)])
    w = np.diff(h, axis=0) * sample_rate
    y = add_sensor_noise(simulate_response(discretize_plant(vehicle.true_model, 1 / sample_rate), w), noise_std,
                         rng=rng)
    shift = (start if given_start is None else given_start) - start
    name = Path(f"simulated-{vehicle.index + 1}.csv")
    return Drive(csv_path=name, params_path=name.with_suffix(".toml"), time=t[:-1], accel=y,
                 sample_rate=sample_rate, speed=float(np.mean(v[:-1])), start_m=start + shift,
                 sensor_noise_std=noise_std, params=vehicle.estimated_params, positions=p[:-1] + shift,
                 speed_source="speed_mps column" if isinstance(speed, tuple) else "parameters")


def score_fleet(est: FleetEstimates, road: RoadProfile, *, margin: float = 40.0, shift: float = 0.0) -> dict:
    """NMSE of every estimator and drive in the 0.5-15 m band (module docstring).

    Parameters
    ----------
    est : FleetEstimates
    road : RoadProfile
        The truth.
    margin : float
        Metres dropped at either end of the stretch every drive covered.
    shift : float
        The truth is compared at ``position - shift`` (a start error common to every drive, m).

    Returns
    -------
    dict
        ``{estimator: (V,) ndarray}`` of NMSE.
    """
    x, dx = est.position, est.spacing
    truth = np.column_stack([np.interp(x - shift, road.distance, road.elevation[:, c]) for c in range(2)])
    truth = band_limit_stretch(truth, dx, est.band_low_per_m)
    lo, hi = 1.0 / SCORE_WAVELENGTHS[1], 1.0 / SCORE_WAVELENGTHS[0]
    def score_band(h):
        return band_limit_stretch(np.nan_to_num(h), dx, lo, hi)

    all_ = est.coverage == len(est.drives)
    idx = np.flatnonzero(all_)
    keep = np.zeros(x.shape, bool)
    m = int(round(margin / dx))
    keep[idx[0] + m:idx[-1] - m] = True
    tb = score_band(truth)[keep]
    power = float(np.mean(tb ** 2))
    return {name: np.array([float(np.mean((score_band(e)[keep] - tb) ** 2)) / power for e in est.elevation[name]])
            for name in FLEET_ESTIMATORS}


@dataclass(frozen=True)
class MixedFleetRow:
    """One drive of the mixed-fleet table (the fields are its columns, in order).

    Attributes
    ----------
    drive : int
        1-based drive number.
    speed : str
        The drive's speed, m/s: ``"15"`` for a constant one, ``"13-17"`` for one swept within the drive.
    single : float
        NMSE of the drive's single-vehicle estimate in the 0.5-15 m band (dimensionless).
    inversion : float
        NMSE of the drive's own offline inversion.
    collaborative : float
        NMSE of the drive's collaborative estimate.
    fused : float
        NMSE of the fused elevation of drives 1..``drive``.
    """

    drive: int
    speed: str
    single: float
    inversion: float
    collaborative: float
    fused: float


@dataclass(frozen=True)
class MixedFleetResult:
    """Outcome of :func:`mixed_fleet_check`.

    Attributes
    ----------
    speeds : tuple
        Per drive: a speed or ``(low, high)``, m/s.
    nmse : dict
        ``{estimator: (V,) ndarray}`` (``fused`` entry ``j``: drives 1..j+1).
    fused_posterior : float or None
        NMSE of the fused posterior-mean inversions with the known fleet prior (None if not run).
    offset_errors : (V,) ndarray or None
        Estimated minus true start corrections after removing their common mean, m (None unless aligned).
    """

    speeds: tuple
    nmse: dict
    fused_posterior: float | None
    offset_errors: np.ndarray | None

    @property
    def fused(self) -> float:
        """NMSE of the fused elevation of every drive."""
        return float(self.nmse["fused"][-1])

    @property
    def single_mean(self) -> float:
        """Mean NMSE of the single vehicles' own offline inversions (the strongest single-vehicle estimate)."""
        return float(np.mean(self.nmse["inversion"]))

    def to_rows(self) -> list[MixedFleetRow]:
        """One row per drive: ``drive, speed, single, inversion, collaborative, fused`` (NMSE).

        Returns
        -------
        list of MixedFleetRow
            ``(V,)`` rows, in drive order.
        """
        return [MixedFleetRow(j + 1, "-".join(f"{v:g}" for v in s) if isinstance(s, tuple) else f"{s:g}",
                              **{name: float(self.nmse[name][j]) for name in FLEET_ESTIMATORS})
                for j, s in enumerate(self.speeds)]


def mixed_fleet_check(speeds=MIXED_SPEEDS, *, seed: int = 0, start_errors=None, align: bool = False,
                      posterior: bool = False, margin: float = 40.0) -> MixedFleetResult:
    """Simulate drives at ``speeds`` over the packaged profile, estimate on distance and score.

    Parameters
    ----------
    speeds : sequence
        Per drive a constant speed or ``(low, high)`` (swept within the drive), m/s.
    seed : int
        Seeds the road's second track, the fleet (``sample_fleet`` with ``FleetSpec()``) and the
        sensor noise (0.05 m/s^2), as independent ``SeedSequence`` children.
    start_errors : sequence of float, optional
        GPS errors added to the recorded starts, m (default none); true starts are 0, 2, 4, ... m.
    align : bool
        Estimate the start offsets by cross-correlation.
    posterior : bool
        Also fuse posterior-mean inversions with the known fleet prior.
    margin : float
        Metres dropped at either end of the scored stretch.

    Returns
    -------
    MixedFleetResult
    """
    speeds = tuple(tuple(s) if isinstance(s, (tuple, list)) else float(s) for s in speeds)
    road_ss, fleet_ss, noise_ss = np.random.SeedSequence(seed).spawn(3)
    road = measured_road(rng=np.random.default_rng(road_ss))
    fleet = sample_fleet(len(speeds), FleetSpec(), rng=np.random.default_rng(fleet_ss))
    errors = np.zeros(len(speeds)) if start_errors is None else np.asarray(start_errors, dtype=float)
    starts = 2.0 * np.arange(len(speeds)) + 8.0
    noise = [np.random.default_rng(s) for s in noise_ss.spawn(len(speeds))]
    drives = [simulate_drive(road, veh, s, start=float(st), given_start=float(st + e), rng=r)
              for veh, s, st, e, r in zip(fleet, speeds, starts, errors, noise)]
    est = estimate_fleet(drives, align=align)
    common = float(np.mean(errors)) if align else 0.0      # what no alignment can see
    nmse = score_fleet(est, road, margin=margin, shift=common)
    post = None
    if posterior:
        post = float(score_fleet(estimate_fleet(drives, align=align, fleet=FleetSpec()), road,
                                 margin=margin, shift=common)["fused"][-1])
    off = None
    if align:
        want = -errors - np.mean(-errors)
        off = est.offsets - want
    return MixedFleetResult(speeds=speeds, nmse=nmse, fused_posterior=post, offset_errors=off)
