"""``roadcollab simulate-drives --out DIR``: simulated drives as real-looking drive files.

The simulation is :func:`roadcollab.experiments.drives.simulation.simulate_drives` (returns the drives)
and the files are written by :func:`~roadcollab.experiments.drives.simulation.write_drives`; this
module parses the options and stages the folder (``d1.csv``, ``d1.toml``, ..., ``config.json``,
``road.csv`` with the true elevation and ``README.md`` with the command to estimate the road).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ParameterError
from ._arguments import SEED, count, help_range, ranged, ranged_list
from ._common import command_parser, out_path

_VEHICLES = count("number of drives", 1, 50)
_SPEEDS = ranged_list("speed", 0.5, 70, "m/s")
_LENGTH = ranged("road length", 50, 200_000, "m")
_RATE = ranged("sample rate", 20, 10_000, "Hz")
_NOISE = ranged("noise standard deviation", 0, 20, "m/s^2")

__all__ = ["NAME", "add_parser", "simulate_command", "simulate_gps_command", "run"]

NAME = "simulate-drives"


def simulate_command(out_dir, *, command: str, vehicles: int = 3, speeds=(15.0,), road: str = "measured",
                     length_m: float | None = None, sample_rate: float = 200.0, noise_std: float = 0.05,
                     gravity: bool = False, seed: int = 0) -> dict:
    """Everything ``roadcollab simulate-drives`` does: simulate, then write the folder at once.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (staged: written as a whole at the end).
    command : str
        The command line, recorded in ``config.json``.
    vehicles, speeds, road, length_m, sample_rate, noise_std, gravity, seed
        As :func:`roadcollab.experiments.drives.simulation.simulate_drives` (m/s, m, Hz, m/s^2).

    Returns
    -------
    dict
        ``out_dir``, ``drives`` (CSV names), ``n_samples`` (per drive), ``road_length_m``, ``speeds_mps``.
    """
    from ..experiments.drives.simulation import simulate_drives, write_drives
    from ..reporting.drive_tables import write_array_csv
    from ..reporting.records import staged_output, write_config

    sim = simulate_drives(vehicles=vehicles, speeds=speeds, road=road, length_m=length_m, sample_rate=sample_rate,
                          noise_std=noise_std, gravity=gravity, seed=seed)
    with staged_output(out_dir, NAME) as out:
        paths = write_drives(sim, out)
        write_array_csv(out / "road.csv", ["distance_m", "elevation_left_m", "elevation_right_m"],
                        [sim.road.distance, sim.road.elevation[:, 0], sim.road.elevation[:, 1]])
        write_config(out / "config.json", command=command, seed=seed, config=sim.config)
        drives = " ".join(f"--drive {out_dir}/{p.name}" for p in paths)
        (out / "README.md").write_text(
            f"# Simulated drives\n\nMade by `{command}` (settings and the true vehicles in `config.json`, the true "
            "road in `road.csv`: distance_m, elevation_left_m, elevation_right_m).\n\n"
            f"Estimate the road from them:\n\n    roadcollab estimate {drives} --out {out_dir}-road\n")
    return {"out_dir": str(out_dir), "drives": [p.name for p in paths],
            "n_samples": [s.drive.n_samples for s in sim.drives], "road_length_m": sim.config["road_length_m"],
            "speeds_mps": [s.drive.speed for s in sim.drives]}


def simulate_gps_command(out_dir, *, command: str, network_path=None, vehicles: int = 3, speeds=None,
                         seed: int = 0, shared_vehicles: bool = False) -> dict:
    """``simulate-drives --gps [--network FILE]``: GPS drives on a road network (:mod:`roadcollab.experiments.drives.city`).

    Parameters
    ----------
    out_dir : str or Path
        Output folder (staged).
    command : str
        The command line, recorded in ``config.json``.
    network_path : str or Path, optional
        A road network GeoJSON whose every road is driven; default the built-in city.
    vehicles : int
        Drives per road of ``network_path``.
    speeds : sequence of float, optional
        m/s, cycled (``network_path`` only; the city has its own mix).
    seed : int
        Root seed.
    shared_vehicles : bool
        The built-in city with vehicles that make several trips, named by ``vehicle_id`` (for ``map --calibrate``).

    Returns
    -------
    dict
        ``out_dir``, ``drives`` (CSV names), ``network``.
    """
    from ..experiments.drives.city import write_city
    from ..geo.network import read_network
    from ..reporting.records import staged_output, write_config

    network = None if network_path is None else read_network(network_path)
    with staged_output(out_dir, NAME) as out:
        files = write_city(out, seed=seed, network=network, speeds=speeds, vehicles=vehicles,
                           shared_vehicles=shared_vehicles)
        write_config(out / "config.json", command=command, seed=seed,
                     config={"network": None if network_path is None else str(network_path), "vehicles": vehicles,
                             "shared_vehicles": shared_vehicles,
                             "speeds_mps": None if speeds is None else list(speeds)})
        drives = " ".join(f"--drive {out_dir}/{p.name}" for p in files["drives"])
        (out / "README.md").write_text(
            f"# Simulated GPS drives\n\nMade by `{command}` (true potholes in `truth.json`).\n\nMap them:\n\n"
            f"    roadcollab map {drives} --network {out_dir}/network.geojson --store {out_dir}-roads.sqlite "
            f"--out {out_dir}-map{' --calibrate' if shared_vehicles else ''}\n")
    return {"out_dir": str(out_dir), "drives": [p.name for p in files["drives"]],
            "network": str(Path(out_dir) / "network.geojson")}


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``simulate-drives`` subcommand and its options.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.
    """
    p = command_parser(
        subparsers, NAME, summary="simulated drives as drive files, to try 'estimate' on",
        does="Simulates vehicles (true and estimated half-car parameters drawn from the fleet prior) driving one "
             "road, the packaged measured profile (544 m) or a synthetic ISO 8608 class C road, both with potholes "
             "and bumps, and writes each drive as a real-looking drive CSV with its TOML parameters file (the "
             "vehicle's estimated parameters only) so that 'roadcollab estimate' runs on them.",
        writes="into --out (written as a whole at the end): d1.csv, d1.toml, d2.csv, ..., road.csv (the true "
               "elevation), config.json (seed, settings, true vehicles), README.md (the estimate command).",
        example="roadcollab simulate-drives --out drives --vehicles 3 --speeds 12,15,18 --seed 1")
    p.add_argument("--out", type=out_path, required=True, metavar="DIR",
                   help="output folder: absent, empty or a previous simulate-drives result")
    p.add_argument("--vehicles", type=_VEHICLES, default=3, metavar="N",
                   help=f"number of drives (default 3; {help_range(_VEHICLES)})")
    p.add_argument("--speeds", type=_SPEEDS, default=(15.0,), metavar="V,V,...",
                   help=f"speeds cycled over the vehicles (default 15: one time grid; different speeds give drives on "
                        f"the distance grid; each {help_range(_SPEEDS)})")
    p.add_argument("--road", choices=("measured", "synthetic"), default="measured",
                   help="the packaged measured profile (544 m) or a synthetic class C road (default measured)")
    p.add_argument("--length-m", type=_LENGTH, default=None, metavar="L",
                   help=f"length of the synthetic road (default 600; implies --road synthetic; {help_range(_LENGTH)})")
    p.add_argument("--sample-rate", type=_RATE, default=200.0, metavar="HZ",
                   help=f"sample rate (default 200; {help_range(_RATE)})")
    p.add_argument("--noise", type=_NOISE, default=0.05, metavar="STD",
                   help=f"accelerometer noise per sample (default 0.05; {help_range(_NOISE)})")
    p.add_argument("--gravity", action="store_true", help="log the accelerations with gravity (+9.80665 m/s^2)")
    p.add_argument("--seed", type=SEED, default=0, help=f"root seed (default 0; {help_range(SEED)})")
    p.add_argument("--gps", action="store_true",
                   help="GPS drives on a road network instead (lat_deg,lon_deg at 5 Hz with 3 m errors, 100 Hz "
                        "accelerometers): the built-in city (a junction and a road 10 m from another) or --network; "
                        "writes network.geojson, drive<j>.csv/.toml, truth.json")
    p.add_argument("--network", metavar="FILE", default=None,
                   help="with --gps: a road network GeoJSON (LineStrings with road_id); every road is driven forward "
                        "by --vehicles vehicles at --speeds")
    p.add_argument("--shared-vehicles", action="store_true",
                   help="with --gps, the built-in city: 8 vehicles make the 12 drives (each parameters file names its "
                        "vehicle_id), so that map --calibrate can fit every vehicle's IRI gain")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Simulate and write the drives, then print the command that estimates the road from them.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        The command line, recorded in ``config.json``.

    Returns
    -------
    int
        Exit status 0.
    """
    if args.network is not None and not args.gps:
        raise ParameterError("--network applies to --gps only")
    if args.shared_vehicles and (not args.gps or args.network is not None):
        raise ParameterError("--shared-vehicles applies to --gps on the built-in city only (without --network)")
    if args.gps:
        given = "--speeds" in command_line.split() or any(a.startswith("--speeds=") for a in command_line.split())
        summary = simulate_gps_command(args.out, command=command_line, network_path=args.network,
                                       vehicles=args.vehicles, speeds=args.speeds if given else None, seed=args.seed,
                                       shared_vehicles=args.shared_vehicles)
        print(f"wrote {len(summary['drives'])} GPS drives and {summary['network']}; map them: roadcollab map "
              + " ".join(f"--drive {args.out}/{d}" for d in summary["drives"])
              + f" --network {summary['network']} --store {args.out}-roads.sqlite --out {args.out}-map"
              + (" --calibrate" if args.shared_vehicles else ""))
        return 0
    road = "synthetic" if args.length_m is not None else args.road
    if args.length_m is not None and args.road == "measured" and "--road" in command_line.split():
        raise ParameterError("--length-m applies to --road synthetic only (the measured profile is 544 m)")
    summary = simulate_command(args.out, command=command_line, vehicles=args.vehicles, speeds=args.speeds, road=road,
                               length_m=args.length_m, sample_rate=args.sample_rate, noise_std=args.noise,
                               gravity=args.gravity, seed=args.seed)
    n = len(summary["drives"])
    print(f"wrote {n} drive{'s' if n != 1 else ''} ({', '.join(summary['drives'])}; "
          f"{sum(summary['n_samples'])} samples) over {summary['road_length_m']:.1f} m of road to {args.out}")
    print("estimate the road: roadcollab estimate " + " ".join(f"--drive {args.out}/{d}" for d in summary["drives"])
          + f" --out {args.out}-road")
    return 0
