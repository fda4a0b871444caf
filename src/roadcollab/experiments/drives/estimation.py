"""Road estimates from recorded drives: the relay of Algorithm 1 down the drives, elevations, anomalies.

The drives are read by :mod:`roadcollab.io.drives`; this module runs the estimators on them exactly
as the in-memory pipeline (:func:`roadcollab.experiments.reproduction.run_estimates`) does.

Processing
----------
* The estimators are designed (Lemma 1) as in the simulations, by
  ``ExperimentConfig(speed=..., sample_rate=..., sensor_noise_std=...).noise_model()``: an ISO 8608
  class C road with the default pothole statistics at the drives' speed and the drive's sensor
  noise. Real roads differ; the design is a prior, not a fit.
* One :class:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator` per drive with
  ``Vehicle(index=j, true_params=p, estimated_params=p)`` (the true parameters of a real car are
  unknown; only the estimated ones are used, ``oracle=False``), observer gamma and band edge from
  the :class:`~roadcollab.experiments.reproduction.ExperimentConfig` defaults (512, 0.5 Hz), on
  ``SegmentGrid(n_samples, sample_rate, band_low_hz=0.5)``.
* Per drive ``k``: ``single`` = the vehicle's own observer ``D_k y_k``; ``collaborative`` =
  Algorithm 1 with the message of drive ``k - 1`` (drive 1: the observer only, so equal to
  ``single``); ``fused`` = the running average of the band-limited inversions ``z`` of drives
  1..k (:meth:`~roadcollab.collaboration.algorithm1.CollaborativeEstimator.fused_message`).
* Every road-velocity output is band-limited by the grid's band weight ``W`` exactly as
  :func:`~roadcollab.experiments.reproduction.run_estimates` does (DC and everything well below 0.5 Hz is
  invisible to accelerometers and is not estimated).
* Elevation: :func:`integrate_elevation` of the band-limited road velocity, mean removed. It is
  defined only up to a slow drift: wavelengths above ``speed / 0.5 Hz`` (30 m at 15 m/s) are not
  observed.
* Anomalies: :func:`roadcollab.detection.detector.detect_anomalies` on every band-limited estimate of every
  drive (:func:`find_anomalies`).

The offline filters act on a finite window: the first and last second or so of every estimate
carry window-edge effects (the simulations record a 15 m lead-in and lead-out for this reason);
log a little more road than the stretch of interest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_int, check_positive, check_signal
from ...collaboration.algorithm1 import CollaborativeEstimator
from ...collaboration.drive_guard import GUARD_ROAD_DEFAULT, drive_fleet_prior, drive_guard
from ...collaboration.relay import Relay
from ...detection.detector import DetectorSpec, detect_anomalies
from ...errors import FileFormatError, ParameterError
from ...estimation.estimator import JDPNoise
from ...estimation.grid import SegmentGrid
from ..config import ExperimentConfig
from ...io.drives import Drive, common_time_grid
from ...models.vehicle import Vehicle

__all__ = ["ESTIMATORS", "DEFAULT_WINDOW", "DEFAULT_MARGIN_PERIODS", "AnomalyRow", "OffsetRow", "DriveEstimates",
           "integrate_elevation", "window_plan", "window_slices", "estimate_drives", "find_anomalies"]

ESTIMATORS = ("single", "collaborative", "fused")
DEFAULT_WINDOW = 2 ** 16          # samples (328 s at 200 Hz): longer records are estimated in windows
DEFAULT_MARGIN_PERIODS = 10.0     # margin = 10 periods of the band edge (20 s at 0.5 Hz) either side


@dataclass(frozen=True)
class AnomalyRow:
    """One detection of ``anomalies.csv`` (the fields are its columns, in order).

    Attributes
    ----------
    estimator : str
        One of :data:`ESTIMATORS`.
    vehicle : int
        1-based drive number.
    position_m : float
        Center, m.
    side, kind : str
        Track (``left``, ``right``, ``both``) and ``pothole`` or ``bump``.
    depth_m : float
        m.
    confidence : float
        The detector's confidence.
    """

    estimator: str
    vehicle: int
    position_m: float
    side: str
    kind: str
    depth_m: float
    confidence: float


@dataclass(frozen=True)
class OffsetRow:
    """One drive of ``offsets.csv`` (the fields are its columns, in order).

    Attributes
    ----------
    drive : int
        1-based drive number.
    csv : str
        The drive's file name.
    start_m_given, offset_m, start_m_used : float
        The start the parameters file gives, the estimated offset and their sum, m.
    correlation_peak : float or str
        Peak of the normalised cross-correlation that set the offset; an empty string for a drive that did
        not pass.
    """

    drive: int
    csv: str
    start_m_given: float
    offset_m: float
    start_m_used: float
    correlation_peak: float | str


def integrate_elevation(w, sample_rate: float) -> np.ndarray:
    """Elevation (m) from road velocity (m/s), mean removed.

    The road velocity is taken as constant over each sample interval (the convention of
    :class:`roadcollab.models.road.TimeRoad` and of the ZOH-exact simulation), so the elevation at the
    *start* of sample ``k`` is ``h[k] = sum_{i<k} w[i] / sample_rate`` exactly (``h[0] = 0``). The
    mean over the window is then removed: the integration constant is unknown, and for a
    band-limited velocity the elevation is defined only up to a slow drift (wavelengths above
    ``speed / band_low_hz`` are not observed).

    Parameters
    ----------
    w : (N, C) array_like
        Road velocity, m/s.
    sample_rate : float
        Hz.

    Returns
    -------
    (N, C) ndarray
        Elevation, m.
    """
    w = check_signal("w", w)
    fs = check_positive("sample_rate", sample_rate)
    h = np.zeros_like(w)
    h[1:] = np.cumsum(w[:-1], axis=0) / fs
    return h - h.mean(axis=0)


@dataclass(frozen=True, eq=False)
class DriveEstimates:
    """Estimates of every drive on the common window.

    Attributes
    ----------
    drives : list of Drive
    sample_rate, speed, start_m : float
        Hz, m/s, m.
    n_samples : int
        Common window length (the shortest drive).
    time : (n,) ndarray
        ``k / sample_rate``, s (time since each drive's first sample).
    positions : (n,) ndarray
        ``start_m + speed * time``, m.
    velocity, elevation : dict
        ``{estimator: (V, n, 2) ndarray}`` for estimator in :data:`ESTIMATORS`: band-limited road
        velocity (m/s) and its elevation (m), columns ``[left, right]``.
    gamma, band_low_hz : float
        Observer parameter and band edge used.
    receiver_guard : str
        The receiver guards' road prior (``"class"``, ``"own"``) or ``"none"`` (``guard=None``, the opt-out).
    n_windows : int
        Overlapping windows the record was estimated in (1: in one piece).
    """

    drives: list
    sample_rate: float
    speed: float
    start_m: float
    n_samples: int
    time: np.ndarray
    positions: np.ndarray
    velocity: dict
    elevation: dict
    gamma: float
    band_low_hz: float
    n_windows: int = 1
    receiver_guard: str = GUARD_ROAD_DEFAULT

    @property
    def truncated(self) -> bool:
        """True if some drive is longer than the common window (it was cut to the shortest)."""
        return any(d.n_samples > self.n_samples for d in self.drives)


def _drive_estimators(drives: list[Drive], grid: SegmentGrid, *, speed: float, sample_rate: float, gamma: float,
                      band_low_hz: float) -> list[CollaborativeEstimator]:
    """One estimator per drive, designed for the drive's sensor noise (one design per distinct noise level).

    Parameters
    ----------
    drives : list of Drive
        In driving order.
    grid : SegmentGrid
        The common window.
    speed, sample_rate : float
        m/s, Hz.
    gamma, band_low_hz : float
        Observer parameter and band edge (Hz).

    Returns
    -------
    list of CollaborativeEstimator
        ``Vehicle(index=j, true_params=p, estimated_params=p)`` for drive ``j`` (0-based).

    Raises
    ------
    FileFormatError
        The design rejects a drive's parameters (a singular or unstable model); the message starts
        with its parameters file and gives the cause.
    """
    noise_models: dict[float, JDPNoise] = {}
    cars = []
    for j, d in enumerate(drives):
        if d.sensor_noise_std not in noise_models:
            try:
                cfg = ExperimentConfig(speed=speed, sample_rate=sample_rate, sensor_noise_std=d.sensor_noise_std,
                                       gamma=gamma, band_low_hz=band_low_hz)
            except ParameterError as err:
                raise ParameterError(f"{d.params_path}: {err}") from None
            noise_models[d.sensor_noise_std] = cfg.noise_model()
        vehicle = Vehicle(index=j, true_params=d.params, estimated_params=d.params)
        try:
            cars.append(CollaborativeEstimator(vehicle, noise_models[d.sensor_noise_std], grid, gamma=gamma))
        except (ValueError, np.linalg.LinAlgError, ArithmeticError) as err:  # e.g. "Singular matrix"
            raise FileFormatError(f"{d.params_path}: no estimator can be designed for this vehicle at "
                                  f"{speed:g} m/s and {sample_rate:g} Hz ({type(err).__name__}: {err}); check the "
                                  "[vehicle] parameters") from None
    return cars


def window_plan(n: int, fs: float, band_low_hz: float, window: int | None, margin_s: float | None
                 ) -> tuple[int, int]:
    """Window length and margin (samples) for a record of ``n`` samples: one window of ``n`` if it fits.

    Parameters
    ----------
    n : int
        Record length, samples.
    fs : float
        Sample rate, Hz.
    band_low_hz : float
        Band edge, Hz (the default margin is ``DEFAULT_MARGIN_PERIODS`` of its period).
    window : int or None
        Longest record in one piece, samples (default :data:`DEFAULT_WINDOW`).
    margin_s : float or None
        Margin, s.

    Returns
    -------
    length, margin : int
        Samples.
    """
    window = DEFAULT_WINDOW if window is None else check_int("window", window, low=64)
    margin_s = DEFAULT_MARGIN_PERIODS / band_low_hz if margin_s is None else check_positive("margin_s", margin_s)
    margin = int(np.ceil(margin_s * fs))
    if n <= window:
        return n, 0
    if window < 4 * margin:
        raise ParameterError(f"window must be at least 4 margins ({4 * margin} samples, margin {margin_s:g} s), "
                             f"got {window}")
    return window, margin


def window_slices(n: int, length: int, margin: int) -> list[tuple[int, int, int, int]]:
    """Overlapping windows of ``length`` samples over ``n`` and the core each one contributes.

    The cores tile ``[0, n)``; every core lies at least ``margin`` samples inside its window except
    at the record's own ends (where the unwindowed estimate has its edge effects too). Every
    window has the same length (the last one is moved back to end at ``n``), so one estimator
    design serves them all.

    Parameters
    ----------
    n, length, margin : int
        Record length, window length (``<= n``) and margin, samples.

    Returns
    -------
    list of (lo, hi, c0, c1)
        Window ``[lo, hi)`` and its core ``[c0, c1)``.
    """
    if length >= n:
        return [(0, n, 0, n)]
    core = length - 2 * margin
    out, c0 = [], 0
    while c0 < n:
        c1 = min(n, c0 + core if c0 else length - margin)
        if n - c1 < margin:        # too little left for a core of its own: end the record here
            c1 = n
        lo = min(max(0, c0 - margin), n - length)
        out.append((lo, lo + length, c0, c1))
        c0 = c1
    return out


def _relay_window(drives: list[Drive], cars: list, grid: SegmentGrid, lo: int, hi: int, *, unguarded: bool) -> dict:
    """Band-limited single, collaborative and fused road velocities (m/s) of samples ``[lo, hi)``, every
    message through the cars' attached guards unless ``unguarded``."""
    n = hi - lo
    ys = [d.accel[lo:hi] for d in drives]
    Ys = [grid.rfft(y) for y in ys]
    try:
        plain = Relay(cars, "none", unguarded=unguarded).run(ys, spectra=Ys)
        fused = Relay(cars, "fused", unguarded=unguarded).run(ys, spectra=Ys)
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as err:  # a degenerate model mid-relay
        raise FileFormatError(f"{', '.join(str(d.params_path) for d in drives)}: the relay failed on these "
                              f"drives' vehicle models ({type(err).__name__}: {err}); check the [vehicle] "
                              "parameters") from None
    return {"single": np.array([grid.band_limited(s.result.W_obs, n) for s in plain]),
            "collaborative": np.array([grid.band_limited(s.result.W_hat, n) for s in plain]),
            "fused": np.array([grid.band_limited(s.estimate_spectrum, n) for s in fused])}


def _attach_guards(drives: list[Drive], cars: list, windows: list, *, road: str, speed: float, sample_rate: float,
                   gamma: float, band_low_hz: float) -> None:
    """Every car's receiver guard from its drive's own priors (:mod:`roadcollab.collaboration.drive_guard`)."""
    for d, car in zip(drives, cars):
        if car.fleet is None:
            car.fleet = drive_fleet_prior(d.params)
        noise = ExperimentConfig(speed=speed, sample_rate=sample_rate, sensor_noise_std=d.sensor_noise_std,
                                 gamma=gamma, band_low_hz=band_low_hz).noise_model()
        spectra = [car.grid.rfft(d.accel[lo:hi]) for lo, hi, _, _ in windows] if road == "own" else ()
        drive_guard(car, noise, d.sensor_noise_std, road=road, spectra=spectra)


def estimate_drives(drives: list[Drive], *, gamma: float | None = None, band_low_hz: float | None = None,
                    window: int | None = None, margin_s: float | None = None,
                    guard: str | None = GUARD_ROAD_DEFAULT) -> DriveEstimates:
    """Run the single-vehicle, collaborative (Algorithm 1) and fused estimators down the drives.

    Relays through the same engine as :func:`roadcollab.experiments.reproduction.run_estimates`
    (:class:`roadcollab.collaboration.relay.Relay`, same estimator design, grid and band limiting), so
    simulated drives give the in-memory estimates.

    Parameters
    ----------
    drives : list of Drive
        In driving order, sharing one time grid (:func:`roadcollab.io.drives.common_time_grid`);
        others go to :func:`roadcollab.experiments.drives.fleet_estimation.estimate_fleet`.
    gamma, band_low_hz : float, optional
        Observer parameter and band edge (Hz). Default: the
        :class:`~roadcollab.experiments.reproduction.ExperimentConfig` defaults (512, 0.5 Hz).
    window : int, optional
        Longest record estimated in one piece, samples (default :data:`DEFAULT_WINDOW`); a longer
        one is estimated in overlapping windows of this length (:func:`window_slices`).
    margin_s : float, optional
        Overlap on either side of a window's core, s (default ``DEFAULT_MARGIN_PERIODS / band_low_hz``).
    guard : {"class", "own"} or None
        Road prior of every vehicle's receiver guard (:func:`_attach_guards`): each received message (the
        relay's exchange and the fused running average) goes through it; None: the paper's Algorithm 1
        unguarded (``roadcollab estimate --unguarded-receive``).

    Returns
    -------
    DriveEstimates
        Every estimator's band-limited road velocity (m/s) and elevation (m), each ``(V, n, 2)``,
        on the common window of ``n`` samples (the shortest drive).

    Raises
    ------
    ParameterError
        Not a non-empty list of drives, drives on different time grids, a sample rate not above twice
        the band edge, or parameters the estimator design rejects.
    """
    if not drives or not all(isinstance(d, Drive) for d in drives):
        raise ParameterError("drives must be a non-empty list of Drive (see load_drives)")
    if not common_time_grid(drives):
        raise ParameterError("drives must share one time grid (constant speed_mps, sample rate and start_m); use "
                             "estimate_fleet for drives at different speeds, rates or starts")
    d0 = drives[0]
    base = ExperimentConfig()
    gamma = base.gamma if gamma is None else gamma
    band_low_hz = base.band_low_hz if band_low_hz is None else band_low_hz
    fs, speed = d0.sample_rate, d0.speed
    if not band_low_hz < fs / 2:
        raise ParameterError(f"{d0.csv_path}: expected a sample rate above {2 * band_low_hz:g} Hz (twice the "
                             f"{band_low_hz:g} Hz band edge), got {fs:.9g} Hz")
    n = min(d.n_samples for d in drives)
    length, margin = window_plan(n, fs, band_low_hz, window, margin_s)
    grid = SegmentGrid(length, fs, band_low_hz=band_low_hz)
    cars = _drive_estimators(drives, grid, speed=speed, sample_rate=fs, gamma=gamma, band_low_hz=band_low_hz)
    velocity = {k: np.zeros((len(drives), n, 2)) for k in ESTIMATORS}
    windows = window_slices(n, length, margin)
    if guard is not None:
        _attach_guards(drives, cars, windows, road=guard, speed=speed, sample_rate=fs, gamma=gamma,
                       band_low_hz=band_low_hz)
    for lo, hi, c0, c1 in windows:
        part = _relay_window(drives, cars, grid, lo, hi, unguarded=guard is None)
        for k in ESTIMATORS:
            velocity[k][:, c0:c1] = part[k][:, c0 - lo:c1 - lo]
    elevation = {k: np.array([integrate_elevation(x, fs) for x in v]) for k, v in velocity.items()}
    t = np.arange(n) / fs
    return DriveEstimates(drives=list(drives), sample_rate=fs, speed=speed, start_m=d0.start_m, n_samples=n, time=t,
                          positions=d0.start_m + speed * t, velocity=velocity, elevation=elevation, gamma=float(gamma),
                          band_low_hz=float(band_low_hz), n_windows=len(windows), receiver_guard=guard or "none")


def find_anomalies(est: DriveEstimates, spec=None) -> list[AnomalyRow]:
    """Anomalies in every band-limited estimate of every drive.

    One call of :func:`roadcollab.detection.detector.detect_anomalies` per (estimator, drive).

    Parameters
    ----------
    est : DriveEstimates
        From :func:`estimate_drives`.
    spec : DetectorSpec, optional
        Detector settings (default ``DetectorSpec()``).

    Returns
    -------
    list of AnomalyRow
        In estimator, then drive, then position order.
    """
    spec = DetectorSpec() if spec is None else spec
    rows = []
    for name in ESTIMATORS:
        for j, w in enumerate(est.velocity[name]):
            for det in detect_anomalies(w, positions=est.positions, speed=est.speed, sample_rate=est.sample_rate,
                                        spec=spec):
                rows.append(AnomalyRow(name, j + 1, float(det.position), det.side, det.kind, float(det.depth),
                                       float(det.confidence)))
    return rows
