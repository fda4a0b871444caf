"""``roadcollab bench``: per-segment cost of one vehicle, and its scaling with segment length; with
``--scale``, fleet-scale runs on a local Dask cluster (throughput, memory per worker, linearity)."""

from __future__ import annotations

import argparse
import json

from ._arguments import WORKERS, add_check, count, help_range, ranged, ranged_list
from ._common import MAX_VEHICLES, MIN_SCORED_M, add_kernels_option, command_parser, plural, print_table, progress

__all__ = ["NAME", "add_parser", "run"]

NAME = "bench"
_QUICK_SIZES = (1000, 2000, 4000, 8000, 16000)
_SIZES = (1000, 2000, 4000, 8000, 16000, 32000, 64000)
_REPEATS = count("number of repeats", 1, 10_000)
_SCALE = ranged_list("number of segments", 1, 100_000, integer=True, most=20)
_VEHICLES = count("fleet size", 1, MAX_VEHICLES)
#: Scored metres per segment: at least what a simulated run scores; 10 km is 1.3e5 samples at 15 m/s.
_SEGMENT_LENGTH = ranged("segment length", MIN_SCORED_M, 10_000, "m")
_CHECK_SEGMENTS = count("number of segments", 0, 1000)


def _check(args: argparse.Namespace) -> str | None:
    """--check-segments compares the first segments of the smallest --scale run: it cannot exceed it."""
    if args.scale is not None and args.check_segments > min(args.scale):
        return (f"argument --check-segments: expected at most the smallest --scale run ({min(args.scale)}), "
                f"got {args.check_segments}")
    return None


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``bench`` subcommand and its options.

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
        subparsers, NAME, summary="per-segment cost of one vehicle, and its scaling with segment length",
        does="Times one vehicle's work per road segment for every privacy mechanism (single-threaded) and how the "
             "cost grows with the segment length.",
        writes="nothing: tables (or one JSON line with --json) on stdout.",
        example="roadcollab bench --quick --json")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--repeats", type=_REPEATS, default=30,
                   help=f"timed segments per point (default 30; {help_range(_REPEATS)})")
    p.add_argument("--quick", action="store_true", help="only up to 16k samples")
    add_kernels_option(p)   # the paper mechanism is also timed on both paths, alternating
    g = p.add_argument_group("fleet scale (a local Dask cluster)")
    g.add_argument("--scale", type=_SCALE, default=None, metavar="SEGMENTS",
                   help="instead of the per-segment benchmark: drive this many road segments (comma-separated "
                        "for several runs, e.g. 100,300,1000) with a fleet on a local Dask cluster and report "
                        "vehicle-segments per second, peak memory per worker and a linear fit of the cost (each "
                        f"{help_range(_SCALE)}, at most 20 runs)")
    g.add_argument("--vehicles", type=_VEHICLES, default=20,
                   help=f"fleet size for --scale (default 20; {help_range(_VEHICLES)})")
    g.add_argument("--workers", type=WORKERS, default=2,
                   help=f"Dask worker processes for --scale (default 2; {help_range(WORKERS)})")
    g.add_argument("--segment-length", type=_SEGMENT_LENGTH, default=300.0,
                   help="scored metres per segment for --scale (default 300: 4000 samples at 15 m/s; "
                        f"{help_range(_SEGMENT_LENGTH)})")
    g.add_argument("--check-segments", type=_CHECK_SEGMENTS, default=4,
                   help="segments also run serially and compared bit for bit with the cluster (default 4; "
                        f"{help_range(_CHECK_SEGMENTS)}, at most the smallest --scale run)")
    add_check(p, _check)
    return p


def _run_scale(args: argparse.Namespace) -> int:
    """``--scale``: the fleet-scale runs, printed as a table or one JSON line."""
    from ..experiments.bench.scale import run_scale

    total = sum(args.scale)
    bar, advance = progress(total, f"{plural(args.vehicles, 'vehicle')} x {plural(total, 'segment')}")
    base = {"done": 0}

    def step(label: str, done: int, n: int) -> None:
        advance(base["done"] + done)
        if done == n:
            base["done"] += n

    with bar:
        res = run_scale(list(args.scale), n_vehicles=args.vehicles, workers=args.workers,
                        segment_length=args.segment_length, check_segments=args.check_segments,
                        progress=step)
    if args.json:
        print(json.dumps(res.to_dict()))
        return 0
    print_table(f"fleet scale: {plural(args.vehicles, 'vehicle')}, {res.samples_per_segment} samples per segment, "
                f"{plural(args.workers, 'Dask worker')}, mechanism {res.mechanism}",
                ("segments", "wall s", "vehicle-segments / s", "s / segment", "peak MB / worker"),
                [(str(p.segments), f"{p.wall_s:.1f}", f"{p.vehicle_segments_per_s:.1f}", f"{p.s_per_segment:.3f}",
                  f"{p.peak_rss_mb_per_worker:.0f}") for p in res.points])
    print(f"linear fit: wall = {res.fixed_s:.2f} s + {res.per_segment_s:.4f} s x segments (worst residual "
          f"{100 * res.max_fit_residual:.1f} %); cluster start {res.cluster_start_s:.1f} s, warm-up "
          f"{res.warmup_s:.1f} s; first "
          f"{plural(res.serial_check_segments, 'segment')} identical to serial: {res.identical_to_serial}")
    return 0


def _load(load: dict) -> str:
    """The load averages before and after a benchmark, for its table's title."""
    start, end = load["start"], load["end"]
    if start is None or end is None:
        return "load average not available"
    return f"load {start[0]:.2f} -> {end[0]:.2f} (1 min), {start[1]:.2f} -> {end[1]:.2f} (5 min)"


def run(args: argparse.Namespace, command_line: str) -> int:
    """Time the pipeline and print the record (one JSON line with ``--json``, else tables).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        Unused (the benchmark writes no files).

    Returns
    -------
    int
        Exit status 0.
    """
    from ..experiments.bench.study import run_bench

    if args.scale is not None:
        return _run_scale(args)
    rec = run_bench(sizes=_QUICK_SIZES if args.quick else _SIZES, repeats=args.repeats, kernels=args.kernels)
    if args.json:
        print(json.dumps(rec))
        return 0
    f = rec["floor"]
    print_table(f"ms per vehicle-segment ({rec['samples_per_segment']} samples, 1 thread, "
                f"{plural(rec['repeats'], 'repeat')}; floor {f['floor_ms']:.3f} ms; {_load(rec['load_average'])})",
                ("mechanism", "min ms", "median ms", "receive (median)", "send (median)", "x floor (min)",
                 "x floor (median)"),
                [(m, f"{v['ms_min']:.2f}", f"{v['ms_median']:.2f}", f"{v['ms_receive_median']:.2f}",
                  f"{v['ms_send_median']:.2f}", f"{v['floor_multiple_min']:.1f}",
                  f"{v['floor_multiple_median']:.1f}") for m, v in rec["by_mechanism"].items()])
    nv, sp = rec["naive_paper"], rec["speedup_paper_vs_naive"]
    print(f"naive paper chain: min {nv['ms_min']:.2f} ms, median {nv['ms_median']:.2f} ms; on the same segments "
          f"the library took {nv['library_ms_min']:.2f} / {nv['library_ms_median']:.2f} ms: {sp['min']:.1f}x (min), "
          f"{sp['median']:.1f}x (median), {sp['per_segment_median']:.1f}x (median per segment) faster")
    print("exactness: " + ", ".join(f"{k} {v:.1e}" for k, v in rec["exactness"].items())
          + f"; privacy vs clear over every benchmark segment {rec['max_rel_privacy_vs_clear']:.1e}")
    kp = rec["kernel_paths"]
    print(f"kernels: {rec['kernels']}; paper on both paths, alternating: " + ", ".join(
        f"{k} {kp[k]['ms_min']:.2f} / {kp[k]['ms_median']:.2f} ms (min / median)" for k in ("compiled", "reference")
        if k in kp) + (f"; reference / compiled {kp['speedup_median']:.2f}x (median)" if "speedup_median" in kp else ""))
    print_table("scaling (cost per N log N relative to N = 4000)", ("N", "paper ms", "rel", "hardened ms", "rel"),
                [(str(s_["n_samples"]), f"{s_['ms_paper']:.2f}", f"{s_['paper_per_nlogn_rel']:.2f}",
                  f"{s_['ms_hardened']:.2f}", f"{s_['hardened_per_nlogn_rel']:.2f}") for s_ in rec["scaling"]])
    print(f"setup per vehicle: {rec['ms_per_vehicle_setup']:.1f} ms; seed {rec['seed']}, "
          f"roadcollab {rec['roadcollab_version']}")
    return 0
