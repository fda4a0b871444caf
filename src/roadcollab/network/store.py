"""The roadside service's own protocol state and per-segment results, in one SQLite file.

Every change is one transaction (``with self.db``), so a service killed at any point leaves either the
whole of a message's effect or none of it: restarted on the same file it continues, and a redelivered
message is recognised by its digest and applied once.

Tables: ``meta`` (the plan), ``vehicles`` (first-seen order, the drive summary), ``contributions`` (one
row per vehicle and segment, the contribution as received), ``waiting`` (the envelope waiting at each
segment), ``fused`` (running sums of the inversions per segment), ``events`` (refusals and notes),
and for secure aggregation ``rounds`` (one row per round: roster, phase, who was used or silent) and
``round_journal`` (what each open round's coordinator accepted, in order: it holds no secret, and a
restarted service replays it, :meth:`RoundCoordinator.replay <roadcollab.network.secround.RoundCoordinator.replay>`)
and ``round_owners`` (which service coordinates each open round, and until when its lease runs: several
``serve --shared`` on one store claim rounds here and take over those of a service whose lease ran out).
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from .engine import Contribution, SegmentSums
from .plan import RoadPlan
from .roundstore import RoundTables

__all__ = ["ServiceStore"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS vehicles (vid TEXT PRIMARY KEY, order_no INTEGER NOT NULL, hello TEXT NOT NULL,
                                     first_s REAL NOT NULL);
CREATE TABLE IF NOT EXISTS contributions (segment INTEGER NOT NULL, vid TEXT NOT NULL, seq INTEGER NOT NULL,
                                          i0 INTEGER NOT NULL, n INTEGER NOT NULL, data BLOB NOT NULL,
                                          envelope BLOB NOT NULL, digest TEXT NOT NULL, received_s REAL NOT NULL,
                                          PRIMARY KEY (segment, vid));
CREATE TABLE IF NOT EXISTS fused (segment INTEGER PRIMARY KEY, total BLOB NOT NULL, count BLOB NOT NULL,
                                  n_vehicles INTEGER NOT NULL, updated_s REAL NOT NULL);
CREATE TABLE IF NOT EXISTS events (id INTEGER PRIMARY KEY AUTOINCREMENT, t REAL NOT NULL, kind TEXT NOT NULL,
                                   vid TEXT, topic TEXT, reason TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS rounds (segment INTEGER NOT NULL, epoch INTEGER NOT NULL, roster TEXT NOT NULL,
                                   phase TEXT NOT NULL, opened_s REAL NOT NULL, closed_s REAL, used TEXT,
                                   silent TEXT, reason TEXT, PRIMARY KEY (segment, epoch));
CREATE TABLE IF NOT EXISTS round_journal (id INTEGER PRIMARY KEY AUTOINCREMENT, segment INTEGER NOT NULL,
                                          epoch INTEGER NOT NULL, kind TEXT NOT NULL, topic TEXT, payload BLOB);
CREATE TABLE IF NOT EXISTS round_owners (segment INTEGER NOT NULL, epoch INTEGER NOT NULL, owner TEXT NOT NULL,
                                         lease_s REAL NOT NULL, PRIMARY KEY (segment, epoch));
"""

class ServiceStore(RoundTables):
    """The service's SQLite file.

    Parameters
    ----------
    path : str or Path
        The file (created with its tables if missing; ``":memory:"`` for an in-memory run).
    plan : RoadPlan, optional
        Required for a new file; an existing file must hold the same plan.

    Raises
    ------
    ParameterError
        Not a roadcollab store, a store of another plan, or a new store without a plan.
    """

    def __init__(self, path, plan: RoadPlan | None = None) -> None:
        self.path = str(path)
        if self.path != ":memory:" and Path(self.path).exists() and not Path(self.path).is_file():
            raise ParameterError(f"--store {path}: expected a file, got a folder")
        try:
            # Autocommit mode with explicit BEGIN IMMEDIATE: a message's reads and writes are one
            # transaction holding the write lock, so two services on one file never interleave.
            self.db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            self.db.execute("PRAGMA journal_mode=WAL")
            # WAL + NORMAL: a commit survives the process being killed at any point (the fault tests);
            # only a power cut may lose the last commits, which the vehicles then send again.
            self.db.execute("PRAGMA synchronous=NORMAL")
            with self._tx():
                for stmt in _SCHEMA.split(";"):
                    if stmt.strip():
                        self.db.execute(stmt)
            row = self.db.execute("SELECT value FROM meta WHERE key = 'plan'").fetchone()
        except sqlite3.DatabaseError as err:
            raise ParameterError(f"--store {path}: not a roadcollab service store ({err})") from None
        if row is None:
            if plan is None:
                raise ParameterError(f"--store {path}: an empty store (run 'roadcollab serve' on it first)")
            with self._tx():
                self.db.execute("INSERT INTO meta VALUES ('plan', ?)", (json.dumps(plan.to_dict(), sort_keys=True),))
            self.plan = plan
        else:
            self.plan = RoadPlan.from_dict(json.loads(row[0]), f"--store {path}")
            if plan is not None and plan != self.plan:
                raise ParameterError(f"--store {path}: holds the results of another fleet plan ({self.plan}); "
                                     f"use a new store for {plan}")

    @contextmanager
    def _tx(self):
        """One write transaction (BEGIN IMMEDIATE ... COMMIT; ROLLBACK on any error)."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.db.execute("COMMIT")

    def close(self) -> None:
        self.db.close()

    # -- vehicles --------------------------------------------------------------------------------
    def add_vehicle(self, vid: str, hello: dict) -> int:
        """Record a vehicle's hello (first one wins); its first-seen order number.

        Parameters
        ----------
        vid : str
            Vehicle id.
        hello : dict
            Its hello.
        """
        with self._tx():
            row = self.db.execute("SELECT order_no FROM vehicles WHERE vid = ?", (vid,)).fetchone()
            if row is not None:
                return int(row[0])
            n = self.db.execute("SELECT COUNT(*) FROM vehicles").fetchone()[0]
            self.db.execute("INSERT INTO vehicles VALUES (?, ?, ?, ?)", (vid, n, json.dumps(hello), time.time()))
            return int(n)

    def vehicle(self, vid: str) -> dict | None:
        row = self.db.execute("SELECT hello FROM vehicles WHERE vid = ?", (vid,)).fetchone()
        return None if row is None else json.loads(row[0])

    def vehicles(self) -> list[tuple[str, dict]]:
        """``(vid, hello)`` in first-seen order."""
        return [(v, json.loads(h)) for v, h in self.db.execute("SELECT vid, hello FROM vehicles ORDER BY order_no")]

    # -- contributions ---------------------------------------------------------------------------
    def add_contribution(self, vid: str, c: Contribution, data: bytes, envelope: bytes, *, fuse: bool = True) -> str:
        """Apply one contribution once: ``"accepted"``, ``"duplicate"`` (the same bytes again) or
        ``"conflict"`` (another contribution of this vehicle on this segment is already applied).

        Parameters
        ----------
        vid : str
            Sender.
        c : Contribution
            Decoded.
        data : bytes
            Its wire form (digest).
        envelope : bytes
            The signed envelope as received (forwarded as the waiting message).
        fuse : bool
            Add its inversion to the segment's running sums (False under secure aggregation: the sums
            come from the rounds, :meth:`close_round`).
        """
        digest = hashlib.sha256(data).hexdigest()
        with self._tx():
            row = self.db.execute("SELECT digest FROM contributions WHERE segment = ? AND vid = ?",
                                  (c.segment, vid)).fetchone()
            if row is not None:
                return "duplicate" if row[0] == digest else "conflict"
            seq = self.db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM contributions").fetchone()[0]
            now = time.time()
            self.db.execute("INSERT INTO contributions VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                            (c.segment, vid, seq, c.i0, c.n, data, envelope, digest, now))
            if fuse:
                sums = self._sums(c.segment).add(self.plan, c)
                self._write_sums(sums, int(self.db.execute("SELECT COUNT(*) FROM contributions WHERE segment = ?",
                                                           (c.segment,)).fetchone()[0]), now)
        return "accepted"

    def add_sealed(self, vid: str, segment: int, data: bytes, envelope: bytes) -> str:
        """Record a sealed contribution (secure aggregation) once; outcomes as :meth:`add_contribution`.

        Parameters
        ----------
        vid : str
        segment : int
        data : bytes
            Its body (the service cannot read the sealed inversion).
        envelope : bytes
        """
        digest = hashlib.sha256(data).hexdigest()
        with self._tx():
            row = self.db.execute("SELECT digest FROM contributions WHERE segment = ? AND vid = ?",
                                  (segment, vid)).fetchone()
            if row is not None:
                return "duplicate" if row[0] == digest else "conflict"
            seq = self.db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM contributions").fetchone()[0]
            self.db.execute("INSERT INTO contributions VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                            (segment, vid, seq, 0, 0, data, envelope, digest, time.time()))
        return "accepted"

    def _write_sums(self, sums: SegmentSums, n_vehicles: int, now: float) -> None:
        self.db.execute("INSERT OR REPLACE INTO fused VALUES (?, ?, ?, ?, ?)",
                        (sums.segment, sums.total.tobytes(), sums.count.tobytes(), n_vehicles, now))

    def contributors(self, segment: int) -> list[tuple[str, float]]:
        """``(vid, received_s)`` of every contribution on ``segment``, in arrival order.

        Parameters
        ----------
        segment : int
        """
        return [(v, t) for v, t in self.db.execute(
            "SELECT vid, received_s FROM contributions WHERE segment = ? ORDER BY seq", (segment,))]

    def contributed_segments(self) -> list[int]:
        """Segments with at least one contribution."""
        return [s for (s,) in self.db.execute("SELECT DISTINCT segment FROM contributions ORDER BY segment")]

    def _sums(self, segment: int) -> SegmentSums:
        row = self.db.execute("SELECT total, count FROM fused WHERE segment = ?", (segment,)).fetchone()
        if row is None:
            return SegmentSums.empty(self.plan, segment)
        m = self.plan.points_per_segment
        return SegmentSums(segment, np.frombuffer(row[0]).reshape(m, 2).copy(),
                           np.frombuffer(row[1], dtype=np.int64).copy())

    def fused(self) -> dict[int, SegmentSums]:
        """``{segment: SegmentSums}`` of every segment with a contribution."""
        return {s: self._sums(s) for (s,) in self.db.execute("SELECT segment FROM fused ORDER BY segment")}

    def done_segments(self, vid: str) -> list[int]:
        return [s for (s,) in self.db.execute("SELECT segment FROM contributions WHERE vid = ? ORDER BY segment",
                                              (vid,))]

    def predecessor(self, vid: str, segment: int) -> tuple[str, bytes] | None:
        """The message waiting for ``vid`` on ``segment``: the last contribution of another vehicle
        before ``vid``'s own (or the last one if ``vid`` has none), as ``(sender, envelope)``.

        Parameters
        ----------
        vid : str
            The asking vehicle.
        segment : int
            Segment index.
        """
        own = self.db.execute("SELECT seq FROM contributions WHERE segment = ? AND vid = ?",
                              (segment, vid)).fetchone()
        limit = own[0] if own is not None else 2 ** 62
        row = self.db.execute("SELECT vid, envelope FROM contributions WHERE segment = ? AND vid != ? AND seq < ? "
                              "ORDER BY seq DESC LIMIT 1", (segment, vid, limit)).fetchone()
        return None if row is None else (row[0], bytes(row[1]))

    def latest(self) -> list[tuple[int, str, bytes]]:
        """``(segment, sender, envelope)`` of the last contribution on every segment (the retained set)."""
        return [(s, v, bytes(e)) for s, v, e in self.db.execute(
            "SELECT c.segment, c.vid, c.envelope FROM contributions c JOIN (SELECT segment, MAX(seq) AS m FROM "
            "contributions GROUP BY segment) l ON c.segment = l.segment AND c.seq = l.m ORDER BY c.segment")]

    def contributions(self) -> list[tuple[str, int, bytes, float]]:
        """``(vid, segment, data, received_s)`` in arrival order."""
        return [(v, s, bytes(d), t) for v, s, d, t in self.db.execute(
            "SELECT vid, segment, data, received_s FROM contributions ORDER BY seq")]

    # -- events ----------------------------------------------------------------------------------
    def log(self, kind: str, reason: str, *, vid: str | None = None, topic: str | None = None) -> None:
        with self._tx():
            self.db.execute("INSERT INTO events (t, kind, vid, topic, reason) VALUES (?, ?, ?, ?, ?)",
                            (time.time(), kind, vid, topic, reason))

    def events(self, kind: str | None = None) -> list[tuple[str, str | None, str | None, str]]:
        q = "SELECT kind, vid, topic, reason FROM events" + (" WHERE kind = ?" if kind else "") + " ORDER BY id"
        return list(self.db.execute(q, (kind,) if kind else ()))

    def status(self) -> dict:
        """Counts for ``roadcollab status``: vehicles, segments, contributions, refusals by reason."""
        one = lambda q: self.db.execute(q).fetchone()[0]  # noqa: E731
        refused: dict[str, int] = {}
        for (reason,) in self.db.execute("SELECT reason FROM events WHERE kind = 'refused'"):
            key = reason.split(":")[0][:80]
            refused[key] = refused.get(key, 0) + 1
        rounds: dict = {}
        for (phase,) in self.db.execute("SELECT phase FROM rounds"):
            key = phase if phase in ("finished", "aborted") else "open"
            rounds[key] = rounds.get(key, 0) + 1
        return {"vehicles": one("SELECT COUNT(*) FROM vehicles"), "segments": one("SELECT COUNT(*) FROM fused"),
                "contributions": one("SELECT COUNT(*) FROM contributions"),
                "duplicates": one("SELECT COUNT(*) FROM events WHERE kind = 'duplicate'"),
                "refused": refused, "rounds": rounds}
