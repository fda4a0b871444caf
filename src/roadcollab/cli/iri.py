"""``roadcollab iri``: International Roughness Index per road segment of a measured profile."""

from __future__ import annotations

import argparse
import time

from ..errors import ParameterError
from ._arguments import add_check, help_range
from ._common import (input_paths, SEGMENT_LENGTH, add_limit_options, add_out_option, check_file_options, check_segment_length,
                      command_parser, file_limits, plural)

__all__ = ["NAME", "add_parser", "run"]

NAME = "iri"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``iri`` subcommand and its options.

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
        subparsers, NAME,
        summary="International Roughness Index (Golden Car, ASTM E1926) per road segment of a profile",
        does="Runs the IRI's Golden Car quarter-car at 80 km/h over a measured profile (250 mm moving average, exact "
             "state transition), per track: a profile file holds one track ('distance_m elevation_m') or two "
             "('distance_m left_m right_m'), whitespace or comma separated, with an optional header line.",
        writes="into --out: iri.csv (start_m, end_m, iri_left_m_per_km, iri_right_m_per_km, iri_m_per_km; one "
               "track: left and right are that track), iri.png, report.md, config.json.",
        example="roadcollab iri --road-profile profile.txt --segment-length 100 --out out/iri")
    p.add_argument("--road-profile", metavar="FILE", default=None,
                   help="profile file, rows 'distance_m elevation_m' (one track) or 'distance_m left_m right_m' "
                        "(two tracks); default: the packaged one")
    p.add_argument("--segment-length", type=SEGMENT_LENGTH, default=100.0, metavar="M",
                   help=f"segment length, m (default 100; {help_range(SEGMENT_LENGTH)}, and at least 10 profile "
                        "spacings); segments start at the profile's first distance")
    add_limit_options(p, "the --road-profile file")
    add_out_option(p)
    add_check(p, lambda args: check_file_options("--road-profile", [args.road_profile], "profile file",
                                                 keep=("packaged",)))
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Compute the IRI per segment of ``args.road_profile`` and write the outputs to ``args.out``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        The command line, recorded in ``config.json`` and ``report.md``.

    Returns
    -------
    int
        Exit status 0.

    Raises
    ------
    ParameterError
        Unreadable or bad profile file, or a profile shorter than one segment.
    """
    from ..io.profiles import load_profile, packaged_profile_path
    from ..models.iri import GOLDEN_CAR, iri_segments
    from ..reporting.iri_report import write_iri
    from ..reporting.output_folder import staged_output

    path = packaged_profile_path() if args.road_profile in (None, "packaged") else args.road_profile
    profile = load_profile(path, limits=file_limits(args))
    problem = check_segment_length(args.segment_length, profile.spacing,
                                   f"the profile's spacing of {profile.spacing:g} m")
    if problem:
        raise ParameterError(problem.removeprefix("argument "))
    t0 = time.perf_counter()
    result = iri_segments(profile.distance, profile.elevation, args.segment_length, car=GOLDEN_CAR)
    elapsed = time.perf_counter() - t0
    source = profile.source if args.road_profile not in (None, "packaged") else "packaged data/profile_1.txt"
    with staged_output(args.out, NAME, input_paths(args)) as out:
        write_iri(result, out, command=command_line, source=source, car=GOLDEN_CAR, elapsed=elapsed)
    mean = result.mean
    print(f"IRI over {plural(len(mean), 'segment')} of {args.segment_length:g} m: mean {mean.mean():.3f} m/km "
          f"(min {mean.min():.3f}, max {mean.max():.3f}); wrote {args.out}/iri.csv and report.md")
    return 0
