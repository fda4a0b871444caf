"""``roadcollab export --store FILE --out DIR``: the files ``estimate`` writes, from the service's store."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._arguments import help_range
from ._common import SEGMENT_LENGTH, command_parser, input_paths, out_path

__all__ = ["NAME", "add_parser", "run"]

NAME = "export"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``export`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="write a service store's results as 'estimate' writes them",
        does="Reads the service's store (also while 'serve' runs) and writes the fused estimate, every "
             "vehicle's estimates, the IRI per segment and the anomalies of the fused elevation.",
        writes="into --out (replaced as a whole at the end): final_estimate.csv, road_estimates.csv, iri.csv, "
               "anomalies.csv, config.json, report.md; with --fleet of a fleet on a road also segments.geojson, "
               "anomalies.geojson and roads.gpkg (the geometry serve --roads writes).",
        example="roadcollab export --store road.sqlite --out results/road")
    p.add_argument("--store", required=True, metavar="FILE", help="the service's SQLite file or PostgreSQL URL")
    p.add_argument("--out", type=out_path, required=True, metavar="DIR",
                   help="output folder: absent, empty or a previous export result")
    p.add_argument("--segment-length", type=SEGMENT_LENGTH, default=100.0, metavar="M",
                   help=f"IRI segment length of the fused elevation (default 100; {help_range(SEGMENT_LENGTH)})")
    p.add_argument("--fleet", metavar="DIR", default=None,
                   help="the fleet folder of a fleet enrolled on a road (enroll --network FILE --road-id ID): also "
                        "write its segments and anomalies with their geometry as GeoJSON and a GeoPackage")
    return p


def _fleet_road(args, plan):
    """The fleet's road of ``--fleet`` (None without it), checked against the store's plan."""
    if args.fleet is None:
        return None
    from ..errors import ParameterError
    from ..network.fleetdir import load_plan
    from ..network.fleetlanes import load_road

    if load_plan(args.fleet) != plan:
        raise ParameterError(f"--fleet {args.fleet}: not the fleet of --store {args.store} (another plan)")
    road = load_road(args.fleet, plan)
    if road is None:
        raise ParameterError(f"--fleet {args.fleet}: fleet {plan.fleet_id!r} is not enrolled on a road (enroll "
                             "--network FILE --road-id ID); its results have no geometry")
    return road


def run(args: argparse.Namespace, command_line: str) -> int:
    """Export the store.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0.
    """

    from ..errors import ParameterError
    from ..network.results import results_from_store
    from ..network.pgstore import is_url, open_service_store
    from ..reporting.network_report import write_network_results
    from ..reporting.records import staged_output

    if not is_url(args.store) and not Path(args.store).is_file():
        raise ParameterError(f"--store {args.store}: not found (expected the file 'roadcollab serve' writes)")
    store = open_service_store(args.store)
    try:
        road = _fleet_road(args, store.plan)
        r = results_from_store(store)
        with staged_output(args.out, NAME, input_paths(args)) as out:
            summary = write_network_results(r, out, command=command_line, segment_length=args.segment_length,
                                            plan=store.plan.to_dict())
            if road is not None:
                from ..network.roadfiles import write_road_files

                geo = write_road_files(store, road, out, segment_length=args.segment_length, source=command_line)
    finally:
        store.close()
    for note in summary["notes"]:
        print(f"note: {note}")
    if road is not None:
        where = "every road" if road.road_id == "*" else f"road {road.road_id!r}"
        print(f"{where}: {geo['n_segments']} segments and {geo['n_anomalies']} anomalies with their "
              f"geometry in {', '.join(geo['files'])}")
    print(f"exported {summary['n_vehicles']} vehicles over {summary['length_m']:.1f} m; wrote {args.out}/report.md")
    return 0
