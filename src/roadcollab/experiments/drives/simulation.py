"""Simulated drives written as real-looking drive files, for trying ``roadcollab estimate``.

:func:`simulate_drives` returns the drives in memory (:class:`DriveSimulation`); :func:`write_drives`
writes them as drive CSVs with their TOML parameters files (:mod:`roadcollab.io.drives`). The
command is ``roadcollab simulate-drives`` (:mod:`roadcollab.cli.simulate_drives`).

Simulation
----------
* Road: the packaged measured profile (544 m, :func:`roadcollab.io.profiles.measured_road`) or a
  synthetic ISO 8608 class C road of ``length_m`` (:func:`roadcollab.models.road.generate_road`,
  0.1 m grid), both with potholes and bumps drawn from ``RoadSpec()`` (0.02 per metre).
* Fleet: ``sample_fleet(vehicles, FleetSpec())``: every vehicle has *true* parameters (they drive
  the simulation) and *estimated* ones (written to ``[vehicle]``, all a real user would know).
* Each vehicle drives from ``start_m`` (15 m, the window-edge lead-in of the simulations) to 5 m
  before the road's end at its speed (``speeds`` cycled over the vehicles), sampled at
  ``sample_rate``; the ZOH simulation is exact for the elevation taken linear between samples
  (:func:`roadcollab.experiments.drives.mixed_fleet.simulate_drive`). White sensor noise of ``noise_std``.
* ``gravity``: ``+9.80665 m/s^2`` on both channels, as phones and most IMUs log them.

Seeds: ``SeedSequence(seed).spawn(3)`` for the road, the fleet and the sensor noise (one child per
vehicle), so vehicle ``j``'s noise does not depend on how many vehicles follow it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..._validation import check_int, check_nonnegative, check_positive
from ...errors import ParameterError
from ...io.drive_params import STANDARD_GRAVITY, write_drive_params
from ...io.drives import Drive, write_drive_csv
from ...io.profiles import measured_road
from ...models.profile import RoadProfile
from ...models.road import RoadSpec, generate_road, with_anomalies
from ...models.vehicle import FleetSpec, HalfCarParameters, sample_fleet
from .mixed_fleet import simulate_drive

__all__ = ["ROADS", "SimulatedDrive", "DriveSimulation", "simulate_drives", "write_drives"]

ROADS = ("measured", "synthetic")
_START_M = 15.0          # m: lead-in before the first sample (window edges)
_SYNTHETIC_SPACING = 0.1  # m


@dataclass(frozen=True, eq=False)
class SimulatedDrive:
    """One simulated pass, as it will be written.

    Attributes
    ----------
    name : str
        File stem (``d1``, ``d2``, ...).
    drive : Drive
        The accelerations as logged (m/s^2, gravity included if simulated), speed, start and the
        vehicle's *estimated* parameters.
    true_params : HalfCarParameters
        The parameters that drove the simulation (not written to the TOML; recorded in config.json).
    """

    name: str
    drive: Drive
    true_params: HalfCarParameters


@dataclass(frozen=True, eq=False)
class DriveSimulation:
    """Outcome of :func:`simulate_drives`.

    Attributes
    ----------
    drives : tuple of SimulatedDrive
        In driving order.
    road : RoadProfile
        The truth (elevation (n, 2) m on ``road.distance``, anomalies).
    config : dict
        The settings, JSON-ready.
    """

    drives: tuple
    road: RoadProfile
    config: dict


def _road(kind: str, length_m: float | None, rng: np.random.Generator) -> RoadProfile:
    """The packaged measured profile or a synthetic class C road, with anomalies from ``RoadSpec()``."""
    if kind == "measured":
        if length_m is not None:
            raise ParameterError("--length-m applies to --road synthetic only (the measured profile is 544 m)")
        return with_anomalies(measured_road(rng=rng), RoadSpec(), rng=rng)
    length = 600.0 if length_m is None else length_m
    return generate_road(RoadSpec(length=length, spacing=_SYNTHETIC_SPACING), rng=rng)


def simulate_drives(*, vehicles: int = 3, speeds=(15.0,), road: str = "measured", length_m: float | None = None,
                    sample_rate: float = 200.0, noise_std: float = 0.05, gravity: bool = False, seed: int = 0
                    ) -> DriveSimulation:
    """Simulate ``vehicles`` drives over one road (module docstring).

    Parameters
    ----------
    vehicles : int
        Number of drives, 1-50.
    speeds : sequence of float
        Speeds, m/s (0.5-70), cycled over the vehicles.
    road : {"measured", "synthetic"}
    length_m : float, optional
        Length of the synthetic road, m (50 m to 200 km; default 600).
    sample_rate : float
        Hz (20-10000).
    noise_std : float
        Sensor noise, m/s^2 (0-20).
    gravity : bool
        Add +9.80665 m/s^2 to both channels.
    seed : int
        Root seed.

    Returns
    -------
    DriveSimulation

    Raises
    ------
    ParameterError
        A value outside its range, named as the option.
    """
    check_int("vehicles", vehicles, low=1, high=50)
    speeds = tuple(float(check_positive("speeds", s)) for s in speeds)
    if not speeds or not all(0.5 <= s <= 70.0 for s in speeds):
        raise ParameterError(f"--speeds must be speeds in [0.5, 70] m/s, got {speeds}")
    if road not in ROADS:
        raise ParameterError(f"--road must be one of {', '.join(ROADS)}, got {road!r}")
    if length_m is not None and not 50.0 <= float(length_m) <= 200_000.0:
        raise ParameterError(f"--length-m must lie in [50, 200000] m, got {length_m:g}")
    if not 20.0 <= float(sample_rate) <= 10_000.0:
        raise ParameterError(f"--sample-rate must lie in [20, 10000] Hz, got {sample_rate:g}")
    if not 0.0 <= check_nonnegative("noise_std", noise_std) <= 20.0:
        raise ParameterError(f"--noise must lie in [0, 20] m/s^2, got {noise_std:g}")
    road_ss, fleet_ss, noise_ss = np.random.SeedSequence(seed).spawn(3)
    profile = _road(road, length_m, np.random.default_rng(road_ss))
    fleet = sample_fleet(vehicles, FleetSpec(), rng=np.random.default_rng(fleet_ss))
    out: list[SimulatedDrive] = []
    for j, (veh, ss) in enumerate(zip(fleet, noise_ss.spawn(vehicles))):
        d = simulate_drive(profile, veh, speeds[j % len(speeds)], start=_START_M, sample_rate=float(sample_rate),
                           noise_std=float(noise_std), rng=np.random.default_rng(ss))
        name = f"d{j + 1}"
        accel = d.accel + STANDARD_GRAVITY if gravity else d.accel
        d = Drive(csv_path=Path(f"{name}.csv"), params_path=Path(f"{name}.toml"), time=d.time, accel=accel,
                  sample_rate=d.sample_rate, speed=d.speed, start_m=d.start_m, sensor_noise_std=d.sensor_noise_std,
                  params=d.params, positions=d.positions)
        out.append(SimulatedDrive(name=name, drive=d, true_params=veh.true_params))
    config = {"vehicles": vehicles, "speeds_mps": list(speeds), "road": road, "road_source": profile.source,
              "road_length_m": float(profile.distance[-1]), "length_m": length_m, "sample_rate_hz": float(sample_rate),
              "noise_std_mps2": float(noise_std), "gravity": bool(gravity), "start_m": _START_M,
              "anomalies": [{"position_m": a.position, "length_m": a.length, "depth_m": a.depth, "kind": a.kind,
                             "side": a.side} for a in profile.anomalies],
              "true_vehicles": [s.true_params.as_dict() for s in out]}
    return DriveSimulation(drives=tuple(out), road=profile, config=config)


def write_drives(sim: DriveSimulation, folder) -> list[Path]:
    """Write every simulated drive as ``<name>.csv`` and ``<name>.toml`` into ``folder``.

    Parameters
    ----------
    sim : DriveSimulation
    folder : str or Path
        An existing folder (files of the same names are overwritten).

    Returns
    -------
    list of Path
        The CSVs, in driving order.
    """
    folder = Path(folder)
    paths = []
    for s in sim.drives:
        d = s.drive
        paths.append(write_drive_csv(folder / f"{s.name}.csv", d.time, d.accel))
        write_drive_params(folder / f"{s.name}.toml", speed=d.speed, params=d.params,
                           sensor_noise_std=d.sensor_noise_std, start_m=d.start_m)
    return paths
