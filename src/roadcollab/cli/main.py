"""Command-line interface ``roadcollab``.

Subcommands: ``reproduce`` (Figs. 4-7), ``sweep`` (where Algorithm 1 beats a single vehicle),
``attack`` (security study), ``anomalies``, ``calibrate-anomalies``, ``estimate`` (recorded drives),
``bench``, ``message example``. Long work shows a progress bar.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from ..errors import ParameterError

__all__ = ["main", "build_parser"]


def _int_at_least(low: int, what: str):
    """argparse type: an integer >= ``low`` with a clear message otherwise."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {text!r}") from err
        if v < low:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {v}")
        return v
    return parse


_positive_int = _int_at_least(1, "positive")
_nonneg_int = _int_at_least(0, "non-negative")


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from err
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return v


def _add_dask_options(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=_positive_int, default=None,
                   help="run on a local Dask cluster with N worker processes (results are identical)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786")


def _add_road_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--road-profile", metavar="FILE", default=None,
                   help="measured profile (rows 'distance_m elevation_m'); 'packaged' for the shipped one")
    p.add_argument("--speed", type=_positive_float, default=15.0, help="vehicle speed, m/s (default 15)")


def build_parser() -> argparse.ArgumentParser:
    """The ``argparse`` parser of the ``roadcollab`` command.

    Subcommands ``reproduce``, ``sweep``, ``attack``, ``anomalies``, ``calibrate-anomalies``, ``bench``,
    ``estimate`` and ``message example``; the parsed subcommand is ``args.command``.

    Returns
    -------
    argparse.ArgumentParser
    """
    parser = argparse.ArgumentParser(prog="roadcollab", description=__doc__.splitlines()[0])
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"roadcollab {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("reproduce", help="Monte Carlo reproduction of the paper's Figs. 4-7")
    p.add_argument("--runs", type=_positive_int, default=100, help="Monte Carlo runs (default 100)")
    p.add_argument("--vehicles", type=_positive_int, default=10, help="fleet size (default 10)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="root seed (default 0)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--noise", type=float, default=None, help="accelerometer noise std, m/s^2 (default 0.05)")
    p.add_argument("--uncertainty", type=float, default=None,
                   help="relative parameter uncertainty of each vehicle's model (default 0.10)")
    p.add_argument("--iso-class", default=None, help="ISO 8608 roughness class of the synthetic road (default C)")
    p.add_argument("--gamma", type=_positive_float, default=None,
                   help="observer parameter gamma of eq. 4 (default 512, the strongest single-vehicle observer)")
    p.add_argument("--oracle", action="store_true", help="use the true plants in T_j (analysis only)")
    p.add_argument("--redraw-fleet", action="store_true",
                   help="draw a new fleet for every run (statistics over fleets)")
    p.add_argument("--measured-runs", type=_nonneg_int, default=20,
                   help="also run this many runs on the shipped measured profile for the report (default 20; 0: skip; "
                        "ignored with --road-profile)")
    _add_road_options(p)
    _add_dask_options(p)

    p = sub.add_parser("attack", help="security study: attacks, linkability, exactness, baselines")
    p.add_argument("--runs", type=_positive_int, default=20, help="segments (default 20, at least 2)")
    p.add_argument("--vehicles", type=_positive_int, default=10, help="fleet size (default 10, at least 3)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="root seed (default 0)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--paillier-bits", type=_positive_int, default=2048, help="Paillier key size (default 2048)")
    _add_dask_options(p)

    p = sub.add_parser("anomalies", help="road anomaly detection study (F1, position error, sweeps)")
    p.add_argument("--runs", type=_positive_int, default=20, help="roads (default 20)")
    p.add_argument("--vehicles", type=_positive_int, default=10, help="fleet size (default 10, at least 2)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="root seed (default 0)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--noise", type=float, default=None, help="accelerometer noise std, m/s^2 (default 0.05)")
    p.add_argument("--iso-class", default=None, help="ISO 8608 roughness class (default C)")
    p.add_argument("--no-sweeps", action="store_true", help="skip the depth and noise sweeps")
    _add_road_options(p)
    _add_dask_options(p)

    p = sub.add_parser("calibrate-anomalies",
                       help="grid search of the anomaly detector's threshold and depth floor on training seeds")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--seeds", nargs="+", default=["1000-1004"],
                   help="training root seeds, integers or ranges a-b (default 1000-1004; evaluation seed 0 refused)")
    p.add_argument("--runs-per-seed", type=_positive_int, default=8, help="roads per seed (default 8)")
    p.add_argument("--vehicles", type=_positive_int, default=10, help="fleet size (default 10, at least 2)")
    p.add_argument("--snr-thresholds", type=_positive_float, nargs="+", default=None,
                   help="snr_threshold grid (default 3.5 4 4.25 4.5 5 5.5)")
    p.add_argument("--min-depths-mm", type=_positive_float, nargs="+", default=None,
                   help="min_depth grid, mm (default 5 7.5 10 12.5 15)")
    _add_dask_options(p)

    p = sub.add_parser("sweep", help="where Algorithm 1 beats a single vehicle: gamma x noise x uncertainty grid")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--runs", type=_positive_int, default=8,
                   help="Monte Carlo runs per grid point, each with a new fleet and road (default 8)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="root seed (default 0)")
    p.add_argument("--vehicles", type=_positive_int, default=10, help="fleet size (default 10, at least 2)")
    p.add_argument("--gammas", default=None, metavar="LIST",
                   help="observer parameters gamma, comma-separated (default 1,8,32,128,512)")
    p.add_argument("--noise", default=None, metavar="LIST",
                   help="accelerometer noise stds, m/s^2, comma-separated (default 0.05,0.2)")
    p.add_argument("--uncertainty", default=None, metavar="LIST",
                   help="relative parameter uncertainties, comma-separated (default 0.05,0.15)")
    _add_dask_options(p)

    p = sub.add_parser("bench", help="per-segment cost of one vehicle, and its scaling with segment length")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--repeats", type=_positive_int, default=30, help="timed segments per point (default 30)")
    p.add_argument("--quick", action="store_true", help="only up to 16k samples")

    p = sub.add_parser("estimate", help="estimate the road from recorded drives (CSV + parameters)")
    from ..io.drives import add_estimate_arguments

    add_estimate_arguments(p)

    p = sub.add_parser("message", help="message utilities")
    msub = p.add_subparsers(dest="message_command", required=True)
    q = msub.add_parser("example", help="write a valid example message")
    q.add_argument("--out", type=Path, required=True, help="output file")
    q.add_argument("--mechanism", choices=["none", "paper", "hardened", "fused"], default="paper")
    q.add_argument("--seed", type=_nonneg_int, default=0)
    return parser


def _progress(total: int, description: str):
    """A rich progress bar (on stderr) and a callback that advances it."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(stderr=True), transient=False)
    task = prog.add_task(description, total=total)
    return prog, (lambda done: prog.update(task, completed=done))


def _config_from_args(args):
    import dataclasses

    from ..experiments.reproduction import ExperimentConfig
    from ..models.vehicle import FleetSpec

    kw = dict(n_runs=args.runs, n_vehicles=args.vehicles, speed=args.speed, oracle=args.oracle,
              road_profile=args.road_profile, redraw_fleet=getattr(args, "redraw_fleet", False))
    if args.noise is not None:
        kw["sensor_noise_std"] = args.noise
    if args.iso_class is not None:
        kw["iso_class"] = args.iso_class
    if getattr(args, "gamma", None) is not None:
        kw["gamma"] = args.gamma
    if args.uncertainty is not None:
        kw["fleet"] = dataclasses.replace(FleetSpec(), estimate_uncertainty=args.uncertainty)
    if args.road_profile is not None and args.road_profile != "packaged" and not Path(args.road_profile).is_file():
        raise ParameterError(f"--road-profile must be an existing file, got {args.road_profile!r}")
    if args.road_profile is not None:
        # A measured profile covers a fixed stretch: score as much of it as fits.
        from ..models.road import measured_road

        length = measured_road(None if args.road_profile == "packaged" else args.road_profile, rng=0).length
        kw["segment_length"] = min(300.0, length - 2 * 15.0 - 1.0)
    return ExperimentConfig(**kw)


def _cmd_reproduce(args, argv) -> int:
    from rich.console import Console
    from rich.table import Table

    from ..experiments.reproduction import run_reproduction
    from ..reporting.reproduction_report import write_reproduction

    cfg = _config_from_args(args)
    prog, cb = _progress(cfg.n_runs, "reproduce")
    t0 = time.perf_counter()
    with prog:
        result = run_reproduction(cfg, args.seed, progress=cb, workers=args.workers, scheduler=args.scheduler)
    elapsed = time.perf_counter() - t0
    measured = None
    if args.road_profile is None and args.measured_runs > 0:
        import argparse as _ap

        margs = _ap.Namespace(**{**vars(args), "road_profile": "packaged", "runs": args.measured_runs})
        mcfg = _config_from_args(margs)
        prog, cb = _progress(mcfg.n_runs, "measured profile")
        t1 = time.perf_counter()
        with prog:
            mres = run_reproduction(mcfg, args.seed, progress=cb, workers=args.workers, scheduler=args.scheduler)
        measured = (mres, time.perf_counter() - t1)
    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    summary = write_reproduction(result, args.out, command=command, elapsed=elapsed, measured=measured)
    table = Table(title=f"MSE per vehicle ((m/s)^2), {cfg.n_runs} runs, {elapsed:.1f} s")
    from ..reporting.reproduction_report import HEADLINE_COLUMNS

    for _, header in HEADLINE_COLUMNS:
        table.add_column(header, justify="right")
    for r in result.table():
        table.add_row(str(r["vehicle"]), *(f"{r[k]:.3g}" for k, _ in HEADLINE_COLUMNS[1:]))
    console = Console()
    console.print(table)
    console.print(f"vehicle 1 online / Algorithm 1 (vehicles 2..{cfg.n_vehicles}): "
                  f"{summary['vehicle1_observer_over_algorithm1']:.2f}x; fused / centralized at vehicle "
                  f"{cfg.n_vehicles}: {summary['fused_over_centralized_last']:.2f}x; wrote {args.out}/report.md")
    return 0


def _cmd_attack(args, argv) -> int:
    from rich.console import Console
    from rich.table import Table

    from ..experiments.reproduction import ExperimentConfig
    from ..reporting.attack_report import write_attack
    from ..experiments.security_study import AttackStudyConfig, run_attack_study

    cfg = AttackStudyConfig(experiment=ExperimentConfig(n_vehicles=args.vehicles, n_runs=1), n_runs=args.runs,
                            paillier_bits=args.paillier_bits)
    prog, cb = _progress(cfg.n_runs, "attack")
    t0 = time.perf_counter()
    with prog:
        result = run_attack_study(cfg, args.seed, progress=cb, workers=args.workers, scheduler=args.scheduler)
    elapsed = time.perf_counter() - t0
    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    write_attack(result, args.out, command=command, elapsed=elapsed)
    table = Table(title=f"Attacks on S_j's poles, {cfg.n_runs} segments, {elapsed:.1f} s")
    for col in ("mechanism", "attack", "median rel. pole error", "success rate"):
        table.add_column(col, justify="right")
    for r in result.attack_rows:
        table.add_row(r["mechanism"], r["attack"], f"{r['median_rel_pole_error']:.3g}", f"{r['success_rate']:.2f}")
    Console().print(table)
    print(f"wrote {args.out}/report.md")
    return 0


def _cmd_anomalies(args, argv) -> int:
    import argparse as _ap

    from ..experiments.anomaly_study import AnomalyStudyConfig, run_anomaly_study
    from ..reporting.anomaly_report import write_anomalies

    ns = _ap.Namespace(runs=1, vehicles=args.vehicles, speed=args.speed, oracle=False, road_profile=args.road_profile,
                       noise=args.noise, iso_class=args.iso_class, uncertainty=None)
    exp = _config_from_args(ns)
    kw = {"depths": (), "noise_levels": ()} if args.no_sweeps else {}
    cfg = AnomalyStudyConfig(experiment=exp, n_runs=args.runs, **kw)
    prog, cb = _progress(cfg.n_runs, "anomalies")
    t0 = time.perf_counter()
    with prog:
        result = run_anomaly_study(cfg, args.seed, progress=cb, workers=args.workers, scheduler=args.scheduler)
    elapsed = time.perf_counter() - t0
    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    write_anomalies(result, args.out, command=command, elapsed=elapsed)
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"Anomaly detection, {cfg.n_runs} runs, {elapsed:.1f} s")
    for c in ("estimator", "precision", "recall", "F1", "median position error (m)"):
        t.add_column(c, justify="right")
    for r in result.detection_rows:
        t.add_row(r["estimator"], f"{r['precision']:.3f}", f"{r['recall']:.3f}", f"{r['f1']:.3f}",
                  f"{r['median_position_error_m']:.3f}")
    Console().print(t)
    print(f"wrote {args.out}/report.md")
    return 0


def _cmd_calibrate_anomalies(args, argv) -> int:
    from ..experiments.anomaly_calibration import (AnomalyCalibrationConfig, calibrate_anomalies, parse_seeds,
                                      write_calibration)
    from ..experiments.reproduction import ExperimentConfig

    kw = {}
    if args.snr_thresholds is not None:
        kw["snr_thresholds"] = tuple(args.snr_thresholds)
    if args.min_depths_mm is not None:
        kw["min_depths"] = tuple(d / 1000.0 for d in args.min_depths_mm)
    cfg = AnomalyCalibrationConfig(seeds=parse_seeds(args.seeds), runs_per_seed=args.runs_per_seed,
                                   experiment=ExperimentConfig(n_vehicles=args.vehicles, n_runs=1), **kw)
    n = len(cfg.seeds) * cfg.runs_per_seed
    prog, cb = _progress(n, "calibrate-anomalies")
    with prog:
        result = calibrate_anomalies(cfg, progress=cb, workers=args.workers, scheduler=args.scheduler)
    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    write_calibration(result, args.out, command=command)
    best = result.best
    print(f"best point: snr_threshold {best.snr_threshold:g}, min_depth {1000 * best.min_depth:g} mm, objective "
          f"{best.objective:.4f} ({n} runs, {result.elapsed_s:.1f} s); wrote {args.out}/report.md")
    return 0


def _cmd_sweep(args, argv) -> int:
    from rich.console import Console
    from rich.table import Table

    from ..experiments.sweep import SweepConfig, run_sweep
    from ..reporting.sweep_report import write_sweep

    def floats(option: str, text: str) -> tuple[float, ...]:
        try:
            return tuple(float(x) for x in text.split(","))
        except ValueError as err:
            raise ParameterError(f"{option} must be comma-separated numbers such as 1,8,32, got {text!r}") from err

    kw = {key: floats(option, text) for key, option, text in (
        ("gammas", "--gammas", args.gammas), ("sensor_noise_stds", "--noise", args.noise),
        ("parameter_uncertainties", "--uncertainty", args.uncertainty)) if text is not None}
    cfg = SweepConfig(n_vehicles=args.vehicles, n_runs=args.runs, **kw)
    prog, cb = _progress(len(cfg.points()) * cfg.n_runs, "sweep")
    t0 = time.perf_counter()
    with prog:
        result = run_sweep(cfg, args.seed, progress=cb, workers=args.workers, scheduler=args.scheduler)
    elapsed = time.perf_counter() - t0
    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    findings = write_sweep(result, args.out, command=command, elapsed=elapsed)
    table = Table(title=f"Vehicle 1's observer vs Algorithm 1, {cfg.n_runs} runs per point, {elapsed:.1f} s")
    for col in ("noise (m/s^2)", "uncertainty", f"smallest gamma within {findings[0].threshold:g}x",
                f"Alg. 1 / observer at gamma {findings[0].largest_gamma:g}", "Alg. 1 wins at gamma"):
        table.add_column(col, justify="right")
    for f in findings:
        table.add_row(f"{f.sensor_noise_std:g}", f"{f.parameter_uncertainty:g}",
                      "none" if f.smallest_gamma_within is None else f"{f.smallest_gamma_within:g}",
                      f"{f.algorithm1_over_observer_at_largest:.3g}",
                      ", ".join(f"{g:g}" for g in f.gammas_algorithm1_wins) or "none")
    Console().print(table)
    print(f"wrote {args.out}/report.md")
    return 0


def _cmd_bench(args) -> int:
    import json

    from ..experiments.bench import run_bench

    sizes = (1000, 2000, 4000, 8000, 16000) if args.quick else (1000, 2000, 4000, 8000, 16000, 32000, 64000)
    rec = run_bench(sizes=sizes, repeats=args.repeats)
    if args.json:
        print(json.dumps(rec))
        return 0
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"ms per vehicle-segment ({rec['samples_per_segment']} samples, 1 thread)")
    for c in ("mechanism", "ms / vehicle-segment"):
        t.add_column(c, justify="right")
    for m, v in rec["ms_per_vehicle_segment_by_mechanism"].items():
        t.add_row(m, f"{v:.2f}")
    Console().print(t)
    t = Table(title="scaling (cost per N log N relative to N = 4000)")
    for c in ("N", "paper ms", "rel", "hardened ms", "rel"):
        t.add_column(c, justify="right")
    for s_ in rec["scaling"]:
        t.add_row(str(s_["n_samples"]), f"{s_['ms_paper']:.2f}", f"{s_['paper_per_nlogn_rel']:.2f}",
                  f"{s_['ms_hardened']:.2f}", f"{s_['hardened_per_nlogn_rel']:.2f}")
    Console().print(t)
    print(f"setup per vehicle: {rec['ms_per_vehicle_setup']:.1f} ms")
    return 0


def _cmd_estimate(args, argv) -> int:
    from ..io.drives import estimate_command

    command = "roadcollab " + " ".join(shlex.quote(a) for a in argv)
    summary = estimate_command(args.drive, args.out, command=command)
    for note in summary.get("notes", []):
        print(f"note: {note}")
    print(f"estimated {summary['n_drives']} drives over {summary['length_m']:.1f} m; wrote {args.out}/report.md")
    return 0


def _cmd_message(args) -> int:
    from ..wire.protocol import write_example

    n = write_example(args.out, mechanism=args.mechanism, seed=args.seed)
    print(f"wrote {n} bytes to {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``roadcollab`` command: parse ``argv`` and run the subcommand.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 on success, 2 if the command rejects its input (a ``ValueError`` such as
        ``ParameterError``; the message is printed to stderr, without a traceback).

    Raises
    ------
    SystemExit
        From argparse, for ``--help``, ``--version`` and invalid arguments.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "reproduce":
            return _cmd_reproduce(args, argv)
        if args.command == "attack":
            return _cmd_attack(args, argv)
        if args.command == "anomalies":
            return _cmd_anomalies(args, argv)
        if args.command == "calibrate-anomalies":
            return _cmd_calibrate_anomalies(args, argv)
        if args.command == "sweep":
            return _cmd_sweep(args, argv)
        if args.command == "estimate":
            return _cmd_estimate(args, argv)
        if args.command == "bench":
            return _cmd_bench(args)
        if args.command == "message":
            return _cmd_message(args)
    except ValueError as err:  # ParameterError / MessageError: a clear message, no traceback
        print(f"roadcollab {args.command}: error: {err}", file=sys.stderr)
        return 2
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
