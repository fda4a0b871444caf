"""The secure-aggregation tables of the service store: ``rounds``, ``round_journal``, ``round_owners``.

A mixin of :class:`~roadcollab.network.store.ServiceStore` (its connection ``db``, its write transaction
``_tx`` and its running sums): the rounds' records, the coordinators' journals (no secret in them; a
restarted service replays them) and which service holds each open round until when (several
``serve --shared`` on one store claim rounds here, and take over those of a service whose lease ran out).
"""

from __future__ import annotations

import json
import sqlite3
import time
from contextlib import AbstractContextManager

import numpy as np

from .engine import SegmentSums

__all__ = ["RoundTables", "LostRound", "CLOSED"]

#: Phases of a round that is no longer open.
CLOSED = ("finished", "aborted")


class LostRound(Exception):
    """The round is coordinated by another service now (its lease ran out here and was taken over)."""


class RoundTables:
    """The round methods of the service store (a mixin: ``db``, ``_tx``, ``_sums``, ``_write_sums``)."""

    db: sqlite3.Connection

    def _tx(self) -> AbstractContextManager:
        raise NotImplementedError

    def _sums(self, segment: int) -> SegmentSums:
        raise NotImplementedError

    def _write_sums(self, sums: SegmentSums, n_vehicles: int, now: float) -> None:
        raise NotImplementedError

    def open_round(self, segment: int, epoch: int, roster: list[str], *, owner: str = "serve",
                   lease_s: float = float("inf")) -> bool:
        """Claim and record a new round and its roster (the first entry of its journal).

        The claim is one write transaction: it fails if ``segment`` has an open round (of any service)
        or round ``(segment, epoch)`` exists, so two services on one store never open the same round.

        Parameters
        ----------
        segment, epoch : int
        roster : list of str
        owner : str
            The claiming service.
        lease_s : float
            Wall-clock second until which the claim holds without a renewal (:meth:`adopt_rounds`).

        Returns
        -------
        bool
            False if the round was not opened (another service holds the segment).
        """
        with self._tx():
            phases = [p for (p,) in self.db.execute("SELECT phase FROM rounds WHERE segment = ? AND (epoch = ? OR "
                                                    "phase NOT IN (?, ?))", (segment, epoch, *CLOSED))]
            if phases:
                return False
            self.db.execute("INSERT INTO rounds (segment, epoch, roster, phase, opened_s) VALUES (?, ?, ?, ?, ?)",
                            (segment, epoch, json.dumps(list(roster)), "adverts", time.time()))
            self.db.execute("INSERT INTO round_journal (segment, epoch, kind, topic, payload) VALUES (?, ?, ?, ?, ?)",
                            (segment, epoch, "open", json.dumps(list(roster)), b""))
            self.db.execute("INSERT INTO round_owners VALUES (?, ?, ?, ?)", (segment, epoch, owner, lease_s))
        return True

    def adopt_rounds(self, owner: str, now_s: float, lease_s: float) -> list[tuple[int, int]]:
        """Renew ``owner``'s leases, and take over the open rounds whose lease ran out.

        A round without an owner row (a store written before leases) is adopted too.

        Parameters
        ----------
        owner : str
        now_s, lease_s : float
            The wall clock now, and the new lease's end.

        Returns
        -------
        list of (int, int)
            ``(segment, epoch)`` of every open round ``owner`` now holds (its own included: the caller
            replays those it does not hold in memory, e.g. after a restart).
        """
        with self._tx():
            rows = list(self.db.execute(
                "SELECT r.segment, r.epoch, o.owner, o.lease_s FROM rounds r LEFT JOIN round_owners o ON "
                "o.segment = r.segment AND o.epoch = r.epoch WHERE r.phase NOT IN (?, ?) ORDER BY r.segment, "
                "r.epoch", CLOSED))
            got = [(int(s), int(e)) for s, e, o, t in rows if o is None or o == owner or t < now_s]
            for s, e in got:
                self.db.execute("DELETE FROM round_owners WHERE segment = ? AND epoch = ?", (s, e))
                self.db.execute("INSERT INTO round_owners VALUES (?, ?, ?, ?)", (s, e, owner, lease_s))
        return got

    def _fence(self, segment: int, epoch: int, owner: str | None) -> None:
        """Inside a transaction: raise :class:`LostRound` unless ``owner`` (if given) holds the round."""
        if owner is None:
            return
        row = self.db.execute("SELECT owner FROM round_owners WHERE segment = ? AND epoch = ?",
                              (segment, epoch)).fetchone()
        if row is None:
            raise LostRound(f"round {segment}/{epoch} is closed or was never this service's")
        if row[0] != owner:
            raise LostRound(f"round {segment}/{epoch} is coordinated by {row[0]}")

    def journal_add(self, segment: int, epoch: int, entries, phase: str, *, owner: str | None = None) -> None:
        """Append coordinator journal entries (``("msg", topic, payload)`` or ``("advance",)``).

        Parameters
        ----------
        segment, epoch : int
        entries : iterable of tuple
        phase : str
            The round's phase after them.
        owner : str, optional
            The writing service: :class:`LostRound` (nothing written) if another one holds the round.
        """
        with self._tx():
            self._fence(segment, epoch, owner)
            for e in entries:
                self.db.execute("INSERT INTO round_journal (segment, epoch, kind, topic, payload) "
                                "VALUES (?, ?, ?, ?, ?)", (segment, epoch, e[0], e[1] if len(e) > 1 else None,
                                                           bytes(e[2]) if len(e) > 2 else b""))
            self.db.execute("UPDATE rounds SET phase = ? WHERE segment = ? AND epoch = ?", (phase, segment, epoch))

    def journal(self, segment: int, epoch: int) -> list[tuple]:
        """The journal of round ``(segment, epoch)``, as :meth:`RoundCoordinator.replay` takes it.

        Parameters
        ----------
        segment, epoch : int
        """
        out: list[tuple] = []
        for kind, topic, payload in self.db.execute(
                "SELECT kind, topic, payload FROM round_journal WHERE segment = ? AND epoch = ? ORDER BY id",
                (segment, epoch)):
            out.append(("open", json.loads(topic)) if kind == "open" else
                       ("msg", topic, bytes(payload)) if kind == "msg" else ("advance",))
        return out

    def close_round(self, segment: int, epoch: int, phase: str, *, used: list[str], silent: list[str], reason: str,
                    total: np.ndarray | None = None, count: np.ndarray | None = None,
                    owner: str | None = None) -> None:
        """End a round; a finished round's sum is added to the segment's fused sums in the same transaction.

        Parameters
        ----------
        segment, epoch : int
        phase : str
            ``finished`` or ``aborted``.
        used, silent : list of str
            Vehicles whose masked input it consumed; vehicles that never answered.
        reason : str
        total : (m, 2) ndarray, optional
        count : (m,) ndarray, optional
            The round's sums (:func:`~roadcollab.network.aggregation.sums_from_total`), when finished.
        owner : str, optional
            As :meth:`journal_add` (a round's sum is added once, by the service that holds it).
        """
        now = time.time()
        with self._tx():
            self._fence(segment, epoch, owner)
            self.db.execute("UPDATE rounds SET phase = ?, closed_s = ?, used = ?, silent = ?, reason = ? "
                            "WHERE segment = ? AND epoch = ?",
                            (phase, now, json.dumps(used), json.dumps(silent), reason, segment, epoch))
            self.db.execute("DELETE FROM round_journal WHERE segment = ? AND epoch = ?", (segment, epoch))
            self.db.execute("DELETE FROM round_owners WHERE segment = ? AND epoch = ?", (segment, epoch))
            if total is not None and count is not None:
                old = self._sums(segment)
                sums = SegmentSums(segment, old.total + total, old.count + count)
                row = self.db.execute("SELECT n_vehicles FROM fused WHERE segment = ?", (segment,)).fetchone()
                self._write_sums(sums, (0 if row is None else int(row[0])) + len(used), now)

    def rounds(self, segment: int | None = None) -> list[dict]:
        """Every round (of ``segment``), oldest first: ``segment, epoch, roster, phase, opened_s, closed_s,
        used, silent, reason``.

        Parameters
        ----------
        segment : int, optional
        """
        q = "SELECT segment, epoch, roster, phase, opened_s, closed_s, used, silent, reason FROM rounds"
        rows = self.db.execute(q + (" WHERE segment = ?" if segment is not None else "") +
                               " ORDER BY segment, epoch", (segment,) if segment is not None else ())
        return [{"segment": s, "epoch": e, "roster": json.loads(r), "phase": p, "opened_s": o, "closed_s": c,
                 "used": json.loads(u) if u else [], "silent": json.loads(si) if si else [], "reason": why}
                for s, e, r, p, o, c, u, si, why in rows]

