"""``roadcollab iri``: International Roughness Index per road segment of a measured profile."""

from __future__ import annotations

import argparse
import time

from ._common import add_out_option, input_paths, positive_float

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
    p = subparsers.add_parser(
        NAME, help="International Roughness Index (Golden Car, ASTM E1926) per road segment of a profile",
        description="Run the IRI's Golden Car quarter-car at 80 km/h over a measured profile (250 mm moving "
                    "average, exact state transition) and write iri.csv (start_m, end_m, iri_left_m_per_km, "
                    "iri_right_m_per_km, iri_m_per_km), iri.png, report.md and config.json. "
                    "Example: roadcollab iri --segment-length 100 --out out/iri")
    p.add_argument("--road-profile", metavar="FILE", default=None,
                   help="profile file, rows 'distance_m elevation_m' (one track); default: the packaged one")
    p.add_argument("--segment-length", type=positive_float, default=100.0,
                   help="segment length, m (default 100); segments start at the profile's first distance")
    add_out_option(p)
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
    profile = load_profile(path)
    t0 = time.perf_counter()
    result = iri_segments(profile.distance, profile.elevation, args.segment_length, car=GOLDEN_CAR)
    elapsed = time.perf_counter() - t0
    source = profile.source if args.road_profile not in (None, "packaged") else "packaged data/profile_1.txt"
    with staged_output(args.out, NAME, input_paths(args)) as out:
        write_iri(result, out, command=command_line, source=source, car=GOLDEN_CAR, elapsed=elapsed)
    mean = result.mean
    print(f"IRI over {len(mean)} segments of {args.segment_length:g} m: mean {mean.mean():.3f} m/km "
          f"(min {mean.min():.3f}, max {mean.max():.3f}); wrote {args.out}/iri.csv and report.md")
    return 0
