"""A vehicle's persistent record of its secure-aggregation sessions (what it sent, what it signed).

Bonawitz et al.'s protocol is secure against an active aggregator only if every honest vehicle keeps
state across rounds *and restarts*: it sends its masked input at most once per segment and epoch
(otherwise two sessions on one segment, one without the victim, difference its ``z`` out), and it
signs and answers at most one survivor set ``U_3`` per session (otherwise, told "dropped" by one
announcement and "survived" by another, it would reveal both shares of a vehicle). This module is that
record: a small SQLite file (``sqlite3`` of the standard library; every change is one committed
transaction, so a crash leaves the old or the new state, never half of one).

The session key is the 16-byte :func:`~roadcollab.privacy.secagg_messages.session_id` of the
*measurement* (segment, epoch): one ``z`` of the vehicle per key.
"""

from __future__ import annotations

import hashlib
import sqlite3
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .._validation import StrPath
from ..errors import FileFormatError
from .secagg_messages import AggregationRefused

__all__ = ["SessionLedger", "ReleaseLog", "view_digest", "segment_key"]

_SCHEMA = ("CREATE TABLE IF NOT EXISTS secagg_sessions (session BLOB PRIMARY KEY, roster BLOB NOT NULL, "
           "view BLOB)")
_MAGIC_TABLE = "secagg_sessions"
_RELEASE_SCHEMA = ("CREATE TABLE IF NOT EXISTS prio_releases (session BLOB NOT NULL, phase INTEGER NOT NULL, "
                   "accepted TEXT NOT NULL, PRIMARY KEY (session, phase))")
_QUERY_SCHEMA = ("CREATE TABLE IF NOT EXISTS prio_queries (session BLOB NOT NULL, phase INTEGER NOT NULL, "
                 "PRIMARY KEY (session, phase))")


def segment_key(segment: int) -> bytes:
    """The ledger key of a vehicle's measurement of ``segment`` given to a session of any epoch (16 bytes).

    A vehicle whose input is its measurement of a segment (not of one (segment, epoch)) records this key
    beside the session's, before the input leaves, and refuses a session of the segment once it is
    recorded: an aggregator that opens another session on the segment under any other epoch, earlier or
    later, also after a restart of the vehicle, gets nothing to difference.

    Parameters
    ----------
    segment : int
    """
    return hashlib.sha256(b"roadcollab/secagg/segment|" + str(int(segment)).encode()).digest()[:16]


def _check_existing(path: Path, table: str, what: str) -> None:
    """Refuse (never replace) an existing ``path`` that is not an SQLite file with ``table`` (or empty)."""
    if not path.is_file():
        raise FileFormatError(f"{path}: not a regular file (expected a {what})")
    try:
        with path.open("rb") as fh:
            head = fh.read(16)
        if head and head != b"SQLite format 3\x00":
            raise FileFormatError(f"{path}: not an SQLite file (expected a {what})")
        if head:
            db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
            names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            db.close()
            if names and table not in names:
                raise FileFormatError(f"{path}: an SQLite file without table {table!r} (expected a {what})")
    except sqlite3.DatabaseError as err:
        raise FileFormatError(f"{path}: unreadable SQLite file ({err})") from None


def _open_db(path: Path | None, table: str, schema: str, what: str) -> sqlite3.Connection:
    """An autocommit connection (every statement its own transaction, ``synchronous = FULL``) with ``schema``."""
    if path is not None and path.exists():
        _check_existing(path, table, what)
    try:
        db = sqlite3.connect(":memory:" if path is None else str(path), isolation_level=None)
        db.execute("PRAGMA synchronous = FULL")
        db.execute(schema)
    except sqlite3.DatabaseError as err:
        raise FileFormatError(f"{path}: cannot open as a {what} ({err})") from None
    return db


def view_digest(ids: Iterable[int]) -> bytes:
    """SHA-256 of a sorted set of vehicle ids (a roster or a survivor set), 32 bytes.

    Parameters
    ----------
    ids : iterable of int

    Returns
    -------
    bytes
    """
    return hashlib.sha256(b"roadcollab/secagg/ids/v1|" + b",".join(str(i).encode() for i in sorted(ids))).digest()


class SessionLedger:
    """Per-session state of one vehicle: masked input sent (with its roster), survivor set signed.

    Parameters
    ----------
    path : str or os.PathLike or None
        The SQLite file (created if missing; an existing file that is not a ledger is refused, never
        replaced). ``None``: in memory (simulation and tests; lost on restart).

    Raises
    ------
    FileFormatError
        ``path`` exists and is not a ledger written by this class.
    """

    def __init__(self, path: StrPath | None = None) -> None:
        self.path = None if path is None else Path(path)
        self._db = _open_db(self.path, _MAGIC_TABLE, _SCHEMA, "secure-aggregation ledger")

    def close(self) -> None:
        """Close the database (further calls fail)."""
        self._db.close()

    def _row(self, session: bytes) -> Any:
        return self._db.execute("SELECT roster, view FROM secagg_sessions WHERE session = ?",
                                (bytes(session),)).fetchone()

    def contributed(self, session: bytes) -> bool:
        """Whether this vehicle already sent a masked input for ``session`` (segment, epoch).

        Parameters
        ----------
        session : bytes

        Returns
        -------
        bool
        """
        return self._row(session) is not None

    def record_contribution(self, session: bytes, roster: Iterable[int]) -> None:
        """Record, before it is sent, that the masked input of ``session`` goes to ``roster``.

        Parameters
        ----------
        session : bytes
            ``session_id(segment, epoch)`` of the measurement.
        roster : iterable of int
            The verified ``U_1`` (its digest is kept).

        Raises
        ------
        AggregationRefused
            A masked input of this session (segment and epoch) was already sent, in any session attempt:
            a second one would let the aggregator difference two aggregates.
        """
        try:
            self._db.execute("INSERT INTO secagg_sessions (session, roster, view) VALUES (?, ?, NULL)",
                             (bytes(session), view_digest(roster)))
        except sqlite3.IntegrityError:
            raise AggregationRefused("this vehicle already contributed its input for this segment and epoch; "
                                     "a second session gets nothing") from None

    def record_view(self, session: bytes, view: Iterable[int]) -> None:
        """Record the survivor set this vehicle signs in ``session`` (the same set again is accepted).

        Parameters
        ----------
        session : bytes
        view : iterable of int
            The announced ``U_3``.

        Raises
        ------
        AggregationRefused
            No masked input was sent in ``session`` (a vehicle outside ``U_2`` does not take part in
            unmasking), or another survivor set was already signed (equivocation).
        """
        row = self._row(session)
        if row is None:
            raise AggregationRefused("no masked input of this vehicle in this session: it does not sign or reveal")
        digest = view_digest(view)
        if row[1] is None:
            cur = self._db.execute("UPDATE secagg_sessions SET view = ? WHERE session = ? AND view IS NULL",
                                   (digest, bytes(session)))
            if cur.rowcount == 1:
                return
            row = self._row(session)
        if row[1] != digest:
            raise AggregationRefused("another survivor set was already signed in this session (equivocation)")

    def signed_view(self, session: bytes) -> bytes | None:
        """The digest of the survivor set signed in ``session``, or None.

        Parameters
        ----------
        session : bytes

        Returns
        -------
        bytes or None
        """
        row = self._row(session)
        return None if row is None else row[1]


class ReleaseLog:
    """An aggregator's persistent record of the sum shares it released (validated sessions, issue 20).

    Each aggregator of :mod:`.secagg_validity` reveals its sum share at most once per (session, phase), and
    a later phase of a phased session only over phase 1's accepted set (:mod:`.secagg_phased`): two sums
    over sets that differ by one vehicle would give that vehicle's input away. Kept in SQLite like
    :class:`SessionLedger`, so a restarted aggregator refuses what it released before the restart.

    Parameters
    ----------
    path : str or os.PathLike or None
        The SQLite file (created if missing; a file that is not a release log is refused, never replaced).
        ``None``: in memory.

    Raises
    ------
    FileFormatError
        ``path`` exists and is not a release log.
    """

    def __init__(self, path: StrPath | None = None) -> None:
        self.path = None if path is None else Path(path)
        self._db = _open_db(self.path, "prio_releases", _RELEASE_SCHEMA, "validated-aggregation release log")
        self._db.execute(_QUERY_SCHEMA)        # added later: an older log gets the table on opening

    def close(self) -> None:
        """Close the database."""
        self._db.close()

    def coin(self, session: bytes, phase: int) -> None:
        """Record, before this aggregator reveals its coin of ``(session, phase)``, that it does so (once, ever).

        With three aggregators (:mod:`.secagg_replicated`) the proofs' query point is a hash of the coins. A
        proof whose joint verifier is known at two points gives its input away, so an aggregator takes part
        in one coin toss per (session, phase) only: an aggregator that replays the uploads (also after a
        restart, or after the session was forgotten) gets no second query point.

        Parameters
        ----------
        session : bytes
            The measurement's ``session_id(segment, epoch)``.
        phase : int

        Raises
        ------
        AggregationRefused
            This aggregator revealed a coin of ``(session, phase)`` before.
        """
        try:
            self._db.execute("INSERT INTO prio_queries (session, phase) VALUES (?, ?)", (bytes(session), int(phase)))
        except sqlite3.IntegrityError:
            raise AggregationRefused(f"a coin of phase {phase} of this session was already revealed: its proofs "
                                     "get no second query point") from None

    def released(self, session: bytes, phase: int) -> tuple[int, ...] | None:
        """The accepted set of the sum share released for ``(session, phase)``, or None.

        Parameters
        ----------
        session : bytes
            The measurement's ``session_id(segment, epoch)``.
        phase : int
        """
        row = self._db.execute("SELECT accepted FROM prio_releases WHERE session = ? AND phase = ?",
                               (bytes(session), int(phase))).fetchone()
        return None if row is None else tuple(int(i) for i in row[0].split(",") if i)

    def release(self, session: bytes, phase: int, accepted: Iterable[int]) -> None:
        """Record, before the sum share is sent, that ``(session, phase)`` is released over ``accepted``.

        Parameters
        ----------
        session : bytes
        phase : int
            1 for the first (or only) phase.
        accepted : iterable of int
            Protocol ids.

        Raises
        ------
        AggregationRefused
            ``(session, phase)`` was released before (also before a restart), or a later phase's set is
            not phase 1's.
        """
        ids = tuple(sorted(int(i) for i in accepted))
        if phase > 1 and self.released(session, 1) != ids:
            raise AggregationRefused(f"phase {phase} is summed only over phase 1's accepted set")
        try:
            self._db.execute("INSERT INTO prio_releases (session, phase, accepted) VALUES (?, ?, ?)",
                             (bytes(session), int(phase), ",".join(map(str, ids))))
        except sqlite3.IntegrityError:
            raise AggregationRefused(f"a sum share of phase {phase} of this session was already released") from None
