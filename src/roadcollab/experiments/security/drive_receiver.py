"""The receiver rows through the recorded-drive path (issue 20, section 4): what ``roadcollab estimate``
and the networked ``vehicle`` run (:class:`~roadcollab.network.engine.VehicleEngine`).

Simulated drives (:func:`~roadcollab.experiments.drives.simulation.simulate_drives`, the packaged measured
road with anomalies, default fleet) stand for recorded ones: the estimators see the drive files' content
only (estimated parameters, speed, noise), and the guard its priors from them
(:mod:`roadcollab.collaboration.drive_guard`). The truth (the simulated road) only scores.

The receiver is drive 2 (0-based 1); its message is drive 1's band-limited inversion on distance. The
attacker is given more than a sender has: it writes the received spectrum ``z`` in the receiver's own
windows directly (:func:`~roadcollab.experiments.drives.fleet_estimation.received_spectra` is linear and
invertible in band, so any such ``z`` is some elevation on distance), knowing the receiver's guard
(bands, ``v_b``, threshold) and the honest ``z``:

====================== ==============================================================================
``honest``             drive 1's inversion as sent
``scale_1e6``          ``z x 1e6``
``coherent_up``        ``z`` plus ``a_b z`` per guard band to expected statistic ``0.8 x threshold``
                       (:func:`~roadcollab.experiments.receiver_attacks.coherent_dz`)
``coherent_down``      the same with ``- a_b z``
``fake_pothole_09``    a 5 cm, 0.5 m pothole (left track, full depth in the receiver's estimate:
                       ``(I - D P_hat)^-1 W p``) at the middle of the drive, scaled per band to expected
                       statistic ``0.9 x threshold`` (at most full depth), added to ``z``
``fake_pothole_full``  the same pothole at full depth in every band (whatever the statistic)
====================== ==============================================================================

                       Scores: MSE of the receiver's collaborative elevation against the band-limited truth on its distance grid
                       (interior, ``edge_m`` from either end), over its observer-only (``single``) MSE; fake anomalies are
                       detections in the receiver's collaborative road velocity that match neither a true anomaly nor a detection
                       with the honest message (:func:`~roadcollab.detection.scoring.new_false_detections`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from ...collaboration.drive_guard import drive_fleet_prior, drive_guard
from ...detection.detector import detect_anomalies
from ...detection.scoring import new_false_detections
from ...lti.batch2x2 import inv2x2, matmul, matvec
from ..config import ExperimentConfig
from ..drives.distance_maps import band_limit_stretch, elevation_to_distance
from ...collaboration.guard import ReceiverGuard
from ...collaboration.relay import Relay
from ...estimation.grid import SegmentGrid
from ..drives.estimation import _attach_guards, _drive_estimators, integrate_elevation
from .poisoning import _add_to_z
from ..drives.simulation import simulate_drives
from ..drives.fleet_estimation import invert_drive, received_spectra, velocity_from_spectra
from .receiver_attacks import coherent_dz

__all__ = ["DRIVE_ATTACKS", "DriveReceiverRow", "drive_receiver_rows", "honest_refusals", "time_grid_rows"]

DRIVE_ATTACKS = ("honest", "scale_1e6", "coherent_up", "coherent_down", "fake_pothole_09", "fake_pothole_full")


@dataclass(frozen=True)
class DriveReceiverRow:
    """One construction against drive 2 of one simulated fleet.

    Attributes
    ----------
    attack : str
        One of :data:`DRIVE_ATTACKS`.
    seed : int
        Simulation seed.
    guard : str
        The receiver's guard road prior (``"class"``, ``"own"``) or ``"none"`` (unguarded).
    ratio : float
        Collaborative MSE over observer-only MSE (inf if not finite).
    fakes : int
        New false detections.
    refused_bands : int
        Bands refused over every window (whole-message refusals count every band).
    bands : int
        Bands judged over every window.
    """

    attack: str
    seed: int
    guard: str
    ratio: float
    fakes: int
    refused_bands: int
    bands: int


class _Vehicle:
    """One drive as :class:`~roadcollab.network.engine.VehicleEngine` holds it (the same calls, without
    its segments): its record, its grid and its band-limited observer and inversion on distance."""

    def __init__(self, drive, index: int, guard: str | None, spacing: float, band_low_per_m: float) -> None:
        cfg = ExperimentConfig()
        self.drive, self.spacing, self.band_low_per_m = drive, spacing, band_low_per_m
        self.rec = invert_drive(drive, gamma=cfg.gamma, band_low_hz=cfg.band_low_hz, index=index, guard=guard)
        i0 = int(np.ceil(drive.positions[0] / spacing - 1e-9))
        i1 = int(np.floor(drive.positions[-1] / spacing + 1e-9))
        self.x = np.arange(i0, i1 + 1) * spacing
        self.single = self.band(self.to_grid(self.rec.w_single))
        self.inversion = self.band(self.to_grid(self.rec.w_inversion))

    def to_grid(self, w: np.ndarray) -> np.ndarray:
        d = self.drive
        return elevation_to_distance(d.positions, integrate_elevation(w, d.sample_rate), self.x)

    def band(self, h: np.ndarray) -> np.ndarray:
        return band_limit_stretch(h, self.spacing, self.band_low_per_m)


def _engines(seed: int, vehicles: int, guard: str | None, road: str, spacing: float = 0.05):
    sim = simulate_drives(vehicles=vehicles, road=road, seed=seed)
    drives = [s.drive for s in sim.drives]
    n_low = ExperimentConfig().band_low_hz / min(float(d.speeds().min()) for d in drives)
    return sim, [_Vehicle(d, j, guard, spacing, n_low) for j, d in enumerate(drives)]


def _pothole_z(eng, lo: int, hi: int, x0: float) -> np.ndarray:
    """``(I - D P_hat)^-1 W p`` on the active bins of window ``[lo, hi)``: a 5 cm pothole at ``x0`` m."""
    car, d = eng.rec.car, eng.drive
    g = car.grid
    x = d.positions[lo:hi]
    h = np.where(np.abs(x - x0) <= 0.25, -0.05, 0.0)
    k = max(1, int(round(0.25 / (d.speed / d.sample_rate))))
    h = np.convolve(h, np.ones(k) / k, mode="same")
    p = np.zeros((hi - lo, 2))
    p[:, 0] = np.gradient(h, 1.0 / d.sample_rate)
    act = g.active
    M = np.eye(2) - matmul(car.D_f[act], car.P_f[act])
    return matvec(inv2x2(M), g.reg_weight[act][:, None] * g.rfft(p)[act])


def _attacked(eng, spectra: list, attack: str) -> list:
    guard = eng.rec.guard
    g = eng.rec.car.grid
    act = g.active
    thr = 10.0 if guard is None else guard.threshold
    probe = guard
    if probe is None:                                # unguarded: the same construction with the default guard's statistics
        cfg = ExperimentConfig(speed=eng.drive.speed, sample_rate=eng.drive.sample_rate)
        probe = drive_guard(_with_prior(eng.rec.car, eng.drive), cfg.noise_model(), eng.drive.sensor_noise_std)
        eng.rec.car.guard = None
    x0 = 0.5 * (eng.drive.positions[0] + eng.drive.positions[-1])
    out = []
    for (lo, hi, _, _), Z in zip(eng.rec.windows, spectra):
        z = Z[act]
        if attack == "honest":
            dz = np.zeros_like(z)
        elif attack == "scale_1e6":
            dz = (1e6 - 1.0) * z
        elif attack in ("coherent_up", "coherent_down"):
            dz = (1.0 if attack == "coherent_up" else -1.0) * g.rfft(coherent_dz(probe, z, 0.8 * thr))[act]
        else:
            inside = eng.drive.positions[lo] <= x0 <= eng.drive.positions[hi - 1]
            shape = _pothole_z(eng, lo, hi, x0)
            if not inside:
                dz = np.zeros_like(z)
            elif attack == "fake_pothole_full":
                dz = shape
            else:
                dz = g.rfft(coherent_dz(probe, shape, 0.9 * thr, cap=1.0))[act]
        A = Z.copy()
        A[act] = z + dz
        out.append(A)
    return out


def _with_prior(car, drive):
    """The receiver's estimator with the drive prior set (the unguarded rows probe the default guard)."""
    if car.fleet is None:
        car.fleet = drive_fleet_prior(drive.params)
    return car


def drive_receiver_rows(seeds=(0, 1, 2), *, vehicles: int = 3, guard: str | None = "class", road: str = "measured",
                        attacks=DRIVE_ATTACKS, edge_m: float = 20.0) -> list[DriveReceiverRow]:
    """Measure :data:`DRIVE_ATTACKS` against drive 2 through the recorded-drive path (module docstring).

    Parameters
    ----------
    seeds : iterable of int
        Simulation seeds (one fleet and road draw each).
    vehicles : int
        Drives simulated (at least 2).
    guard : {"class", "own"} or None
        The receiver's guard road prior; None: unguarded (the opt-out).
    road : {"measured", "synthetic"}
        :func:`~roadcollab.experiments.drives.simulation.simulate_drives`' road.
    attacks : iterable of str
        Subset of :data:`DRIVE_ATTACKS`.
    edge_m : float
        Metres left out of the score at either end of the receiver's drive.

    Returns
    -------
    list of DriveReceiverRow
    """
    rows = []
    for seed in seeds:
        sim, engs = _engines(seed, vehicles, guard, road)
        prev, eng = engs[0], engs[1]
        d = eng.drive
        truth = _truth(sim.road, eng)
        inner = (eng.x >= eng.x[0] + edge_m) & (eng.x <= eng.x[-1] - edge_m)

        obs = _mse(eng.single, truth, inner)
        honest = received_spectra(eng.rec, d, prev.x, prev.inversion, 0.0)
        dets_h = None
        for attack in ("honest",) + tuple(a for a in attacks if a != "honest"):
            reports: list = []
            with np.errstate(all="ignore"):
                vel = velocity_from_spectra(eng.rec, d, _attacked(eng, honest, attack), reports=reports)
                elev = eng.band(eng.to_grid(vel))
            dets = detect_anomalies(np.nan_to_num(vel), positions=d.positions, speed=d.speed,
                                    sample_rate=d.sample_rate) if np.isfinite(vel).all() else []
            if attack == "honest":
                dets_h = dets
            fakes = new_false_detections(dets, dets_h, sim.road.anomalies) if np.isfinite(vel).all() else -1
            n_bands = len(eng.rec.guard.bands) * len(reports) if eng.rec.guard is not None else 0
            refused = sum(len(r.refused_bands) for r in reports)
            if attack in attacks:
                rows.append(DriveReceiverRow(attack, int(seed), guard or "none", _mse(elev, truth, inner) / obs, int(fakes),
                                             int(refused), int(n_bands)))
    return rows


def _mse(h: np.ndarray, truth: np.ndarray, inner: np.ndarray) -> float:
    """Mean squared error on the scored grid points, m^2 (inf if not finite)."""
    e = h[inner] - truth[inner]
    return float(np.mean(e ** 2)) if np.isfinite(e).all() else float("inf")


def _truth(road, eng) -> np.ndarray:
    """The true elevation on the receiver's grid, band-limited as its estimates are, m."""
    h = np.stack([np.interp(eng.x, road.distance, road.elevation[:, c]) for c in range(2)], axis=1)
    return band_limit_stretch(h, eng.spacing, eng.band_low_per_m)


def honest_refusals(seeds=(0, 1, 2), *, vehicles: int = 10, guard: str = "class", road: str = "measured"
                    ) -> tuple[int, int, int, int]:
    """Honest refusals of every receiver (drives 2..V) through the recorded-drive path.

    Parameters
    ----------
    seeds : iterable of int
        Simulation seeds.
    vehicles : int
        Drives per fleet.
    guard : {"class", "own"}
        The guards' road prior.
    road : {"measured", "synthetic"}

    Returns
    -------
    refused_bands, bands, refused_messages, messages : int
        Over every receiver and window.
    """
    rb = nb = rm = nm = 0
    for seed in seeds:
        _, engs = _engines(seed, vehicles, guard, road)
        for prev, eng in zip(engs[:-1], engs[1:]):
            reports: list = []
            velocity_from_spectra(eng.rec, eng.drive, received_spectra(eng.rec, eng.drive, prev.x, prev.inversion,
                                                                         0.0), reports=reports)
            rb += sum(len(r.refused_bands) for r in reports)
            nb += len(eng.rec.guard.bands) * len(reports)
            rm += sum(r.whole_message_refused for r in reports)
            nm += len(reports)
    return rb, nb, rm, nm


def time_grid_rows(seeds=(0, 1, 2), *, vehicles: int = 3, guard: str | None = "class", road: str = "measured",
                   attacks=DRIVE_ATTACKS, edge_s: float = 2.0) -> list[DriveReceiverRow]:
    """:data:`DRIVE_ATTACKS` against drive 2 on the time-grid path (drives sharing one time grid:
    :func:`~roadcollab.experiments.drives.estimation.estimate_drives`, what ``roadcollab estimate`` runs on
    them), the lie added to the ``z`` of drive 1's exchange message (its ``e``).

    Parameters
    ----------
    seeds, vehicles, guard, road, attacks
        As :func:`drive_receiver_rows`.
    edge_s : float
        Seconds left out of the score at either end.

    Returns
    -------
    list of DriveReceiverRow
        Scored on band-limited road velocity (m/s) against the truth sampled at the drive's positions.
    """
    rows = []
    for seed in seeds:
        sim = simulate_drives(vehicles=vehicles, road=road, seed=seed)
        drives = [s.drive for s in sim.drives]
        d = drives[1]
        cfg = ExperimentConfig()
        grid = SegmentGrid(d.n_samples, d.sample_rate, band_low_hz=cfg.band_low_hz)
        cars = _drive_estimators(drives[:2], grid, speed=d.speed, sample_rate=d.sample_rate, gamma=cfg.gamma,
                                 band_low_hz=cfg.band_low_hz)
        windows = [(0, d.n_samples, 0, d.n_samples)]
        _attach_guards(drives[:2], cars, windows, road=guard or "class", speed=d.speed, sample_rate=d.sample_rate,
                       gamma=cfg.gamma, band_low_hz=cfg.band_low_hz)
        probe = cast(ReceiverGuard, cars[1].guard)      # attached by _attach_guards
        if guard is None:
            cars[1].guard = None
        Ys = [grid.rfft(x.accel) for x in drives[:2]]
        honest = Relay([cars[0]], "none", unguarded=True).step(0, drives[0].accel, Y=Ys[0]).message
        h = np.stack([np.interp(d.positions, sim.road.distance, sim.road.elevation[:, c]) for c in range(2)], axis=1)
        w = np.zeros_like(h)
        w[:-1] = np.diff(h, axis=0) * d.sample_rate
        truth = grid.band_limited(grid.rfft(w), d.n_samples)
        k = int(edge_s * d.sample_rate)
        inner = np.zeros(d.n_samples, bool)
        inner[k:d.n_samples - k] = True
        act = grid.active
        z = cars[0].invert(Ys[0])[act]
        obs = _mse(grid.band_limited(cars[1].estimate(None, Y=Ys[1]).W_obs, d.n_samples), truth, inner)
        x0 = 0.5 * (d.positions[0] + d.positions[-1])
        dets_h = None
        for attack in ("honest",) + tuple(a for a in attacks if a != "honest"):
            if attack == "honest":
                dz = np.zeros((grid.nfft, 2))
            elif attack == "scale_1e6":
                Z = np.zeros((grid.n_bins, 2), complex)
                Z[act] = (1e6 - 1.0) * z
                dz = grid.irfft(Z)
            elif attack in ("coherent_up", "coherent_down"):
                dz = (1.0 if attack == "coherent_up" else -1.0) * coherent_dz(probe, z, 0.8 * probe.threshold)
            else:
                shape = _pothole_z(_Car(cars[1], d), 0, d.n_samples, x0)
                if attack == "fake_pothole_full":
                    Z = np.zeros((grid.n_bins, 2), complex)
                    Z[act] = shape
                    dz = grid.irfft(Z)
                else:
                    dz = coherent_dz(probe, shape, 0.9 * probe.threshold, cap=1.0)
            msg = _add_to_z(honest, dz, cars[0])
            step = Relay(cars[1:], "none", unguarded=guard is None).step(0, d.accel, msg, Y=Ys[1])
            with np.errstate(all="ignore"):
                vel = grid.band_limited(step.result.W_hat, d.n_samples)
            ok = bool(np.isfinite(vel).all())
            dets = detect_anomalies(vel, positions=d.positions, speed=d.speed, sample_rate=d.sample_rate) if ok else []
            if attack == "honest":
                dets_h = dets
            rep = step.guard
            nb = 0 if rep is None else len(probe.bands)
            if attack in attacks:
                rows.append(DriveReceiverRow(attack, int(seed), guard or "none", _mse(vel, truth, inner) / obs,
                                             new_false_detections(dets, dets_h, sim.road.anomalies) if ok else -1,
                                             0 if rep is None else len(rep.refused_bands), nb))
    return rows


class _Car:
    """What :func:`_pothole_z` reads of a vehicle (``rec.car``, ``drive``) for an estimator and its drive."""

    def __init__(self, car, drive) -> None:
        self.rec = type("rec", (), {"car": car})()
        self.drive = drive
