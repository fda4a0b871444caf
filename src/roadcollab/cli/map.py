"""``roadcollab map --drive FILE [--drive FILE] [--network FILE] --store FILE --out DIR``: roads on a map.

A command of its own rather than options of ``estimate``: its inputs (GPS drives, a road network,
a store that persists between runs) and its outputs (GIS files, a web map) are about roads and
places, while ``estimate`` writes one stretch on a distance axis; and the store it updates is the
one ``serve`` and ``export`` will share.

Reads the drives (with ``lat_deg, lon_deg`` columns, :mod:`roadcollab.io.gps`), matches them to
the network (:mod:`roadcollab.geo.matching`; without ``--network`` each drive's own GPS track is
its road), surveys every lane (:mod:`roadcollab.experiments.drives.road_survey`), adds the result to the
store (:mod:`roadcollab.store`), and writes the store's whole content as files. The store is
updated before the files are written: if writing them fails, ``--out`` is left as it was and the
store keeps the new estimates (a second run rewrites the files from it).
"""

from __future__ import annotations

import argparse
import time

from ._arguments import SEED, count, help_range, ranged
from ._common import SEGMENT_LENGTH, add_limit_options, command_parser, file_limits, out_path

_GPS_SIGMA = ranged("GPS error", 0.1, 100, "m")
_BOOTSTRAP = count("number of resamples", 0, 10_000)

__all__ = ["NAME", "map_command", "add_parser", "run"]

NAME = "map"


def _vehicle_id(text: str) -> str:
    """argparse type: a ``vehicle_id`` as the parameters files write it."""
    from ..io.drive_params import VEHICLE_ID

    if not VEHICLE_ID.fullmatch(text):
        raise argparse.ArgumentTypeError(f"expected a vehicle_id of 1-64 letters, digits, '.', '_' or '-', got "
                                         f"{text[:70]!r}")
    return text


def _own_tracks(drives):
    """Each drive's GPS track as a road named after its file (no --network)."""
    from ..errors import FileFormatError
    from ..geo.network import network_from_lonlat, track_road

    roads = {}
    for d in drives:
        if d.gps is None:
            raise FileFormatError(f"{d.csv_path}: expected lat_deg, lon_deg columns (without --network a drive's "
                                  "GPS track is its road)")
        roads[d.csv_path.stem] = track_road(d.csv_path.stem, d.gps.lon, d.gps.lat)
    return network_from_lonlat(roads)


def _write_outputs(out, store, *, tiles: str | None) -> dict:
    """Every file of the store's content into ``out``."""
    from ..geo import export
    from ..geo.webmap import write_map

    segs, anoms = store.segments(), store.anomalies()
    seg_fc, an_fc = export.segments_geojson(segs), export.anomalies_geojson(anoms)
    export.write_geojson(out / "segments.geojson", seg_fc)
    export.write_geojson(out / "anomalies.geojson", an_fc)
    notes = []
    if segs:
        export.write_geopackage(out / "roads.gpkg", segs, anoms)
    else:
        notes.append("no segment is fully covered by the drives yet: roads.gpkg was not written")
    export.write_segment_csv(out / "segments.csv", segs)
    (out / "profiles").mkdir()
    for s in segs:
        export.write_opencrg(out / "profiles" / f"{s.road_id}_{'fwd' if s.direction > 0 else 'bwd'}_"
                                                f"{s.from_m:06.0f}.crg", s)
    write_map(out / "map.html", seg_fc, an_fc, tiles=tiles)
    return {"n_segments": len(segs), "n_anomalies": len(anoms), "notes": notes}


def map_command(drive_paths: list[str], out_dir, *, store_url, command: str, network_path=None,
                segment_length: float = 100.0, gps_sigma: float = 5.0, bootstrap: int = 100, seed: int = 0,
                tiles: str | None = None, limits=None, calibrate: bool = False, reference=()) -> dict:
    """Everything ``roadcollab map`` does (module docstring).

    Parameters
    ----------
    drive_paths : list of str
        Drive CSVs with GPS columns (parameters files beside them).
    out_dir : str or Path
        Output folder (replaced as a whole at the end).
    store_url : str or Path
        The road store (SQLite file; created if missing, updated otherwise).
    command : str
        The command line, recorded in ``config.json`` and the store.
    network_path : str or Path, optional
        Road network GeoJSON; None: each drive's track is its road.
    segment_length : float
        m.
    gps_sigma : float
        GPS error standard deviation assumed by the matcher, m.
    bootstrap : int
        Resamples for the IRI interval.
    seed : int
        Seeds the bootstrap.
    tiles : str, optional
        Online tile URL template for the web map (default none: offline).
    limits : FileLimits, optional
        Largest drive CSV and most rows.
    calibrate : bool
        Fit every vehicle's IRI gain from the segments it shares and divide its inversions by it before
        fusing (:mod:`roadcollab.experiments.drives.gain_calibration`); writes ``calibration.csv``.
    reference : sequence of str
        Vehicles (``vehicle_id``) whose gain is 1: the anchors of their components.

    Returns
    -------
    dict
        Summary (counts, files; ``"passes"``: the PassRow of every pass).
    """
    from ..experiments.drives.gain_calibration import VehicleGain
    from ..experiments.drives.road_survey import PassRow, store_survey, survey_drives
    from ..geo.network import read_network
    from ..io.drives import load_drives
    from ..reporting.records import staged_output, write_config, write_rows
    from ..store import RoadStore

    t0 = time.perf_counter()
    if RoadStore.path_of(store_url) is None:      # a server it cannot reach is refused before any work
        RoadStore.open(store_url).close()
    inputs = [*drive_paths, network_path, RoadStore.path_of(store_url)]
    with staged_output(out_dir, NAME, inputs) as out:
        network = read_network(network_path) if network_path is not None else None
        drives = load_drives(drive_paths, limits=limits)
        network = network if network is not None else _own_tracks(drives)
        survey = survey_drives(drives, network, segment_length=segment_length, sigma_z=gps_sigma,
                               bootstrap=bootstrap, calibrate=calibrate, reference=reference, rng=seed)
        with RoadStore.open(store_url) as store:
            n_seg, n_an = store_survey(store, survey, source=command)
            summary = _write_outputs(out, store, tiles=tiles)
        write_rows(out / "passes.csv", survey.passes, PassRow)
        if calibrate:
            write_rows(out / "calibration.csv", survey.gains, VehicleGain)
        config = {"drives": list(drive_paths), "network": None if network_path is None else str(network_path),
                  "store": str(store_url), "segment_length_m": segment_length, "gps_sigma_m": gps_sigma,
                  "bootstrap": bootstrap, "tiles": tiles, "calibrate": calibrate, "reference_vehicles": list(reference),
                  "band_low_per_m": {f"{k[0]}:{k[1]:+d}": v for k, v in survey.band_low_per_m.items()}}
        extra = {"written_segments": n_seg, "written_anomalies": n_an, **summary,
                 "elapsed_s": time.perf_counter() - t0}
        write_config(out / "config.json", command=command, seed=seed, config=config, extra=extra)
    return {**summary, "written_segments": n_seg, "written_anomalies": n_an, "passes": survey.passes,
            "out_dir": str(out_dir)}


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``map`` subcommand and its options.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="roads on a map: GPS drives -> road store, GeoJSON, GeoPackage, web map",
        does="Matches GPS drives to a road network (HMM map matching), estimates each lane's profile, IRI per "
             "segment and anomalies from every drive on it, adds them to the road store (history kept) and "
             "writes the store's content.",
        writes="into --out (replaced as a whole at the end): segments.geojson, anomalies.geojson, roads.gpkg, "
               "segments.csv (linear-reference events), profiles/*.crg (OpenCRG), map.html (offline web map), "
               "passes.csv, calibration.csv (with --calibrate), config.json; and updates --store.",
        example="roadcollab map --drive d1.csv --drive d2.csv --network roads.geojson --store roads.sqlite "
                "--out results/map")
    p.add_argument("--drive", action="append", required=True, metavar="FILE",
                   help="drive CSV with lat_deg,lon_deg columns (empty between fixes) and a .toml/.json beside it; "
                        "repeatable")
    p.add_argument("--network", metavar="FILE", default=None,
                   help="road network: GeoJSON FeatureCollection of LineStrings with a road_id property "
                        "(default: each drive's own GPS track is its road)")
    p.add_argument("--store", required=True, metavar="FILE",
                   help="road store: an SQLite file (created if missing), sqlite:///path or "
                        "postgresql://user@host/db (PostGIS)")
    p.add_argument("--out", type=out_path, required=True, metavar="DIR",
                   help="output folder: absent, empty or a previous map result")
    p.add_argument("--segment-length", type=SEGMENT_LENGTH, default=100.0, metavar="M",
                   help=f"segment length along each road (default 100; {help_range(SEGMENT_LENGTH)})")
    p.add_argument("--gps-sigma", type=_GPS_SIGMA, default=5.0, metavar="M",
                   help=f"GPS error standard deviation for the map matcher (default 5; {help_range(_GPS_SIGMA)})")
    p.add_argument("--bootstrap", type=_BOOTSTRAP, default=100, metavar="N",
                   help=f"bootstrap resamples for the IRI interval (default 100; 0: none; {help_range(_BOOTSTRAP)})")
    p.add_argument("--seed", type=SEED, default=0, help=f"seed of the bootstrap (default 0; {help_range(SEED)})")
    p.add_argument("--tiles", default=None, metavar="URL",
                   help="online tile layer for map.html, e.g. https://tile.openstreetmap.org/{z}/{x}/{y}.png "
                        "(default: none, the page works offline)")
    p.add_argument("--calibrate", action="store_true",
                   help="fit every vehicle's IRI gain from the segments it shares with other vehicles (drives of one "
                        "vehicle_id share a gain) and divide its inversions by it before fusing; writes calibration.csv")
    p.add_argument("--reference-vehicle", action="append", default=[], metavar="ID", type=_vehicle_id,
                   help="with --calibrate: a vehicle_id whose gain is 1 (its parameters identified on a reference "
                        "section); anchors its vehicles' gains instead of their mean; repeatable")
    add_limit_options(p, "each drive CSV")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run ``roadcollab map`` and print a summary.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        The command line.

    Returns
    -------
    int
        Exit status 0.
    """
    s = map_command(args.drive, args.out, store_url=args.store, command=command_line, network_path=args.network,
                    segment_length=args.segment_length, gps_sigma=args.gps_sigma, bootstrap=args.bootstrap,
                    seed=args.seed, tiles=args.tiles, limits=file_limits(args), calibrate=args.calibrate,
                    reference=args.reference_vehicle)
    roads = sorted({(p.road_id, p.direction) for p in s["passes"]})
    print(f"matched {len(s['passes'])} passes on {len(roads)} lane(s): "
          + ", ".join(f"{r}{d:+d}" for r, d in roads))
    for note in s["notes"]:
        print(f"note: {note}")
    print(f"store {args.store}: {s['n_segments']} segments, {s['n_anomalies']} anomalies; wrote {args.out}/map.html")
    return 0
