"""The road-condition store shared by ``map`` (and later ``serve`` and ``export``): SQLite by default."""

from .roadstore import RoadStore, StoredAnomaly, StoredSegment

__all__ = ["RoadStore", "StoredSegment", "StoredAnomaly"]
