"""``roadcollab status --store FILE``: vehicles seen, segments done, messages refused and why."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import command_parser

__all__ = ["NAME", "add_parser", "run"]

NAME = "status"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``status`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(subparsers, NAME, summary="what a service store holds: vehicles, segments, refusals",
                       does="Reads the service's store (also while 'serve' runs) and prints its counts.",
                       writes="nothing.", example="roadcollab status --store road.sqlite")
    p.add_argument("--store", required=True, metavar="FILE", help="the service's SQLite file or PostgreSQL URL")
    p.add_argument("--roads", metavar="URL", default=None,
                   help="also summarise this road-condition store ('serve --roads', 'roadcollab map')")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Print the store's status.

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
    from ..network.pgstore import is_url, open_service_store

    if not is_url(args.store) and not Path(args.store).is_file():
        raise ParameterError(f"--store {args.store}: not found (expected the file 'roadcollab serve' writes)")
    store = open_service_store(args.store)
    st = store.status()
    store.close()
    print(f"fleet {store.plan.fleet_id!r}: {st['vehicles']} vehicles seen, {st['segments']} segments with a fused "
          f"estimate, {st['contributions']} contributions applied, {st['duplicates']} copies applied once")
    if st["rounds"]:
        r = st["rounds"]
        print(f"  aggregation rounds (secure or validated sessions): {r.get('finished', 0)} finished, {r.get('open', 0)} open, "
              f"{r.get('aborted', 0)} aborted")
    for reason, k in sorted(st["refused"].items(), key=lambda kv: -kv[1]):
        print(f"  refused {k}: {reason}")
    if args.roads is not None:
        from ..store import RoadStore

        path = RoadStore.path_of(args.roads)
        if path is not None and not path.is_file():
            raise ParameterError(f"--roads {args.roads}: not found (expected a road store 'serve --roads' writes)")
        with RoadStore.open(args.roads) as roads:
            segs, anoms = roads.segments(), roads.anomalies()
        if segs:
            iri = [s.iri_m_per_km for s in segs]
            print(f"road store {args.roads}: {len(segs)} segments on {len({s.road_id for s in segs})} road(s), "
                  f"IRI {min(iri):.2f}-{max(iri):.2f} m/km, {sum(s.n_updates for s in segs)} estimates in the "
                  f"history, last update {max(s.last_update for s in segs)}; {len(anoms)} anomalies")
        else:
            print(f"road store {args.roads}: no segment yet; {len(anoms)} anomalies")
    return 0
