"""``roadcollab simulate-drives --out DIR``: simulated drives as real-looking drive files.

The simulation is :func:`roadcollab.experiments.drive_simulation.simulate_drives` (returns the drives)
and the files are written by :func:`~roadcollab.experiments.drive_simulation.write_drives`; this
module parses the options and stages the folder (``d1.csv``, ``d1.toml``, ..., ``config.json``,
``road.csv`` with the true elevation and ``README.md`` with the command to estimate the road).
"""

from __future__ import annotations

import argparse

from ..errors import ParameterError
from ._common import command_parser, nonneg_int, positive_int

__all__ = ["NAME", "add_parser", "simulate_command", "run"]

NAME = "simulate-drives"


def _speeds(text: str) -> tuple[float, ...]:
    """argparse type: comma-separated speeds in m/s."""
    try:
        values = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated speeds in m/s (e.g. 12,15,18), got {text!r}"
                                         ) from None
    if not all(0.5 <= v <= 70.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected speeds in [0.5, 70] m/s, got {text!r}")
    return values


def _nonneg_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not 0.0 <= v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return v


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
        As :func:`roadcollab.experiments.drive_simulation.simulate_drives` (m/s, m, Hz, m/s^2).

    Returns
    -------
    dict
        ``out_dir``, ``drives`` (CSV names), ``n_samples`` (per drive), ``road_length_m``, ``speeds_mps``.
    """
    from ..experiments.drive_simulation import simulate_drives, write_drives
    from ..reporting.drive_tables import write_array_csv
    from ..reporting.records import staged_output, write_config

    sim = simulate_drives(vehicles=vehicles, speeds=speeds, road=road, length_m=length_m, sample_rate=sample_rate,
                          noise_std=noise_std, gravity=gravity, seed=seed)
    with staged_output(out_dir) as out:
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
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--vehicles", type=positive_int, default=3, metavar="N", help="number of drives, 1-50 (default 3)")
    p.add_argument("--speeds", type=_speeds, default=(15.0,), metavar="V,V,...",
                   help="speeds in m/s cycled over the vehicles (default 15: one time grid; different speeds give "
                        "drives on the distance grid)")
    p.add_argument("--road", choices=("measured", "synthetic"), default="measured",
                   help="the packaged measured profile (544 m) or a synthetic class C road (default measured)")
    p.add_argument("--length-m", type=float, default=None, metavar="L",
                   help="length of the synthetic road, m, 50-200000 (default 600; implies --road synthetic)")
    p.add_argument("--sample-rate", type=float, default=200.0, metavar="HZ", help="Hz, 20-10000 (default 200)")
    p.add_argument("--noise", type=_nonneg_float, default=0.05, metavar="STD",
                   help="accelerometer noise, m/s^2 per sample, 0-20 (default 0.05)")
    p.add_argument("--gravity", action="store_true", help="log the accelerations with gravity (+9.80665 m/s^2)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="root seed (default 0)")
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
