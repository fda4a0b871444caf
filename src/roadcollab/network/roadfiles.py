"""``export --fleet DIR``: the GIS files of a fleet on a road, from the service's store.

The service store holds the contributions on the road's measure; with the fleet's road
(:class:`~roadcollab.network.fleetroad.FleetRoad`) they become what ``serve --roads`` writes:
:class:`~roadcollab.network.roadsync.RoadSync` runs once into a road store of its own (an SQLite file
in a temporary folder, removed afterwards), and that store's content is written with ``roadcollab
map``'s writers (:mod:`roadcollab.geo.export`): ``segments.geojson``, ``anomalies.geojson`` and, when
there is a segment, ``roads.gpkg``. So ``export``'s GIS files equal the road store of a ``serve --roads``
that saw the same contributions (one history row per segment).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from ..geo import export
from ..store import RoadStore
from .fleetroad import FleetRoad
from .roadsync import RoadSync
from .store import ServiceStore

__all__ = ["write_road_files"]


def write_road_files(store: ServiceStore, road: FleetRoad, out, *, segment_length: float = 100.0,
                     source: str = "roadcollab export") -> dict:
    """Write ``segments.geojson``, ``anomalies.geojson`` and ``roads.gpkg`` of a fleet on a road.

    Parameters
    ----------
    store : ServiceStore
        The service's store (its plan's ``road_id`` is ``road``'s).
    road : FleetRoad
    out : Path
        Output folder (from ``staged_output``).
    segment_length : float
        IRI segment length, m.
    source : str
        Recorded as each row's source.

    Returns
    -------
    dict
        ``n_segments``, ``n_anomalies``, ``files``.
    """
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="roadcollab-export-") as tmp:
        with RoadStore.open(Path(tmp) / "roads.sqlite") as roads:
            sync = RoadSync(roads, store, segment_length=segment_length, source=source, road=road)
            sync.flush()
            segs, anoms = roads.segments(), roads.anomalies()
    export.write_geojson(out / "segments.geojson", export.segments_geojson(segs))
    export.write_geojson(out / "anomalies.geojson", export.anomalies_geojson(anoms))
    files = ["segments.geojson", "anomalies.geojson"]
    if segs:
        export.write_geopackage(out / "roads.gpkg", segs, anoms)
        files.append("roads.gpkg")
    return {"n_segments": len(segs), "n_anomalies": len(anoms), "files": files}
