"""One recorded drive's side of Algorithm 1 on distance: its inversion in its own time, and what it
receives (the previous drive's elevation sent through distance) applied through its receiver guard.

Split from :mod:`roadcollab.experiments.drives.fleet_estimation` (module docstring there for the method), which
re-exports every name; the networked engine (:class:`roadcollab.network.engine.VehicleEngine`) and
``estimate_fleet`` share these functions, so the two cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ...collaboration.algorithm1 import CollaborativeEstimator
from ...collaboration.drive_guard import GUARD_ROAD_DEFAULT, drive_fleet_prior, drive_guard
from ...collaboration.guard import ReceiverGuard
from ...errors import FileFormatError, ParameterError
from ...estimation.grid import SegmentGrid
from ...io.drives import Drive
from ...models.vehicle import FleetSpec, Vehicle
from ..config import ExperimentConfig
from .distance_maps import elevation_at
from .estimation import window_plan, window_slices

__all__ = ["VehicleRecord", "invert_drive", "received_spectra", "velocity_from_spectra", "collaborative_velocity"]


@dataclass(frozen=True, eq=False)
class VehicleRecord:
    """One drive's estimator and its estimates in its own time base.

    Attributes
    ----------
    car : CollaborativeEstimator
        Designed at the drive's mean speed on ``SegmentGrid(L, rate)``, ``L`` the window length
        (``N`` for a record of at most one window).
    windows : list of (lo, hi, c0, c1)
        The windows and cores of :func:`~roadcollab.experiments.drives.estimation.window_slices`.
    w_single, w_inversion : (N, 2) ndarray
        Observer and offline-inversion road velocities, m/s.
    w_posterior : (N, 2) ndarray or None
        Posterior-mean inversion (only with a fleet prior), m/s.
    guard : ReceiverGuard or None
        The receiver guard every received elevation goes through (:func:`invert_drive`); None: the
        named opt-out ``guard=None`` (the paper's Algorithm 1).
    """

    car: CollaborativeEstimator
    windows: list
    w_single: np.ndarray
    w_inversion: np.ndarray
    w_posterior: np.ndarray | None
    guard: ReceiverGuard | None = None


def invert_drive(drive: Drive, *, gamma: float, band_low_hz: float, fleet: FleetSpec | None = None,
                 index: int = 0, window: int | None = None, margin_s: float | None = None,
                 guard: str | None = GUARD_ROAD_DEFAULT) -> VehicleRecord:
    """Design vehicle ``index``'s estimator for one drive and invert its record in its own time.

    The receiver guard (issue 20, section 4) is built from the drive's own priors
    (:mod:`roadcollab.collaboration.drive_guard`): its parameter estimate with the stated accuracy
    (or ``fleet`` when known) and the road prior ``guard``.

    Parameters
    ----------
    drive : Drive
    gamma, band_low_hz : float
        Observer parameter and band edge (Hz).
    fleet : FleetSpec, optional
        A fleet prior; if given, the posterior-mean inversion is also computed.
    index : int
        0-based vehicle number.
    window, margin_s : int and float, optional
        Longest record inverted in one piece (samples) and the windows' margin (s), as
        :func:`~roadcollab.experiments.drives.estimation.estimate_drives`.
    guard : {"class", "own"} or None
        Road prior of the receiver guard (:func:`~roadcollab.collaboration.drive_guard.drive_guard`): the
        design's ISO class (default) or the own inversions; None: no guard (the named opt-out,
        ``roadcollab estimate --unguarded-receive``).

    Returns
    -------
    VehicleRecord

    Raises
    ------
    FileFormatError
        The design rejects the vehicle's parameters (message starts with the parameters file).
    """
    n, fs = drive.n_samples, drive.sample_rate
    length, margin = window_plan(n, fs, band_low_hz, window, margin_s)
    grid = SegmentGrid(length, fs, band_low_hz=band_low_hz)
    try:
        cfg = ExperimentConfig(speed=drive.speed, sample_rate=fs, sensor_noise_std=drive.sensor_noise_std,
                               gamma=gamma, band_low_hz=band_low_hz)
        vehicle = Vehicle(index=index, true_params=drive.params, estimated_params=drive.params)
        noise = cfg.noise_model()
        prior = fleet if fleet is not None or guard is None else drive_fleet_prior(drive.params)
        car = CollaborativeEstimator(vehicle, noise, grid, gamma=gamma, fleet=prior)
    except ParameterError as err:
        raise ParameterError(f"{drive.params_path}: {err}") from None
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as err:  # e.g. "Singular matrix"
        raise FileFormatError(f"{drive.params_path}: no estimator can be designed for this vehicle at "
                              f"{drive.speed:g} m/s and {fs:g} Hz ({type(err).__name__}: {err}); check the "
                              "[vehicle] parameters") from None
    single, inversion = np.zeros((n, 2)), np.zeros((n, 2))
    post = np.zeros((n, 2)) if fleet is not None else None
    windows = window_slices(n, length, margin)
    spectra = []
    # Every road velocity passes W_reg (DC regularisation, corner band_low_hz / 2) in its own window
    # before the windows are joined: what is below it (a window's own drift) is not observed and
    # must not leak across window joints. The band limit on distance (from band_low_hz at the
    # slowest speed) comes after; W W_reg is within 0.5 % of W in band.
    reg = grid.reg_weight[:, None]
    for lo, hi, c0, c1 in windows:
        Y = grid.rfft(drive.accel[lo:hi])
        spectra.append(Y)
        core = slice(c0 - lo, c1 - lo)
        single[c0:c1] = grid.irfft(reg * car.estimate(None, Y=Y).W_obs, length)[core]
        inversion[c0:c1] = grid.irfft(reg * car.invert(Y), length)[core]
        if post is not None:
            post[c0:c1] = grid.irfft(reg * car.invert(Y, posterior=True), length)[core]
    receiver = None if guard is None else drive_guard(car, noise, drive.sensor_noise_std, road=guard,
                                                      spectra=spectra)
    return VehicleRecord(car=car, windows=windows, w_single=single, w_inversion=inversion, w_posterior=post,
                         guard=receiver)


def received_spectra(rec: VehicleRecord, drive: Drive, x: np.ndarray, previous: np.ndarray, shift: float
                     ) -> list[np.ndarray]:
    """The previous drive's elevation sent through distance into this vehicle's windows: ``z`` per window.

    Parameters
    ----------
    rec : VehicleRecord
        This vehicle's estimator and windows.
    drive : Drive
        This vehicle's drive.
    x : (m,) ndarray
        Distance grid of ``previous``, m.
    previous : (m, 2) ndarray
        The previous vehicle's band-limited elevation on ``x``, m (NaN where it did not pass).
    shift : float
        Start offset applied to this drive's positions, m.

    Returns
    -------
    list of (K, 2) complex ndarray
        ``W_reg`` times the spectrum of ``w = v(t) h'(p(t))`` per window of ``rec.windows``, m/s.
    """
    grid = rec.car.grid
    h = elevation_at(x, previous, drive.positions + shift)
    w = np.zeros_like(h)
    w[:-1] = np.diff(h, axis=0) * drive.sample_rate       # w[k] = (h[k + 1] - h[k]) rate, this vehicle's time
    return [grid.reg_weight[:, None] * grid.rfft(w[lo:hi]) for lo, hi, _, _ in rec.windows]


def velocity_from_spectra(rec: VehicleRecord, drive: Drive, spectra: Sequence[np.ndarray], *,
                          reports: list | None = None) -> np.ndarray:
    """Algorithm 1 per window with the received ``z`` (:func:`received_spectra`), through ``rec.guard``.

    Parameters
    ----------
    rec : VehicleRecord
        This vehicle's estimator, windows and guard (None: ``w^f = -S^-1 T z`` as it is).
    drive : Drive
        This vehicle's drive.
    spectra : sequence of (K, 2) complex ndarray
        One received spectrum per window.
    reports : list, optional
        Appended with the guard's :class:`~roadcollab.collaboration.guard.GuardReport` per window.

    Returns
    -------
    (N, 2) ndarray
        Road velocity in this vehicle's time base, m/s.
    """
    grid = rec.car.grid
    act = grid.active
    out = np.zeros((drive.n_samples, 2))
    for (lo, hi, c0, c1), Z in zip(rec.windows, spectra):
        Y = grid.rfft(drive.accel[lo:hi])
        if rec.guard is None:
            Wf = rec.car.wf_from_z(Z)
        else:
            Wf, report = rec.guard.feedforward_z(Z[act], Y)
            if reports is not None:
                reports.append(report)
        W_hat = rec.car.estimate(None, Y=Y, Wf=Wf).W_hat
        out[c0:c1] = grid.irfft(grid.reg_weight[:, None] * W_hat, hi - lo)[c0 - lo:c1 - lo]   # as invert_drive
    return out


def collaborative_velocity(rec: VehicleRecord, drive: Drive, x: np.ndarray, previous: np.ndarray, shift: float
                           ) -> np.ndarray:
    """Algorithm 1's road velocity with the previous drive's elevation sent through distance.

    The one implementation :func:`estimate_fleet` and the networked engine
    (:class:`roadcollab.network.engine.VehicleEngine`) share, window by window as :func:`invert_drive`:
    :func:`received_spectra`, then :func:`velocity_from_spectra` (through the receiver guard unless the
    record was built with ``guard=None``).

    Parameters
    ----------
    rec : VehicleRecord
        This vehicle's estimator and windows.
    drive : Drive
        This vehicle's drive.
    x : (m,) ndarray
        Distance grid of ``previous``, m.
    previous : (m, 2) ndarray
        The previous vehicle's band-limited elevation on ``x``, m (NaN where it did not pass).
    shift : float
        Start offset applied to this drive's positions, m.

    Returns
    -------
    (N, 2) ndarray
        Road velocity in this vehicle's time base, m/s.
    """
    return velocity_from_spectra(rec, drive, received_spectra(rec, drive, x, previous, shift))
