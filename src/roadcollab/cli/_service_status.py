"""What ``roadcollab serve`` prints while it runs: one line per event, and on a terminal a live status.

On a terminal (rich decides, ``Console.is_terminal``) the event lines scroll above a status line that
rich keeps current: vehicles seen, segments with a fused estimate, contributions, secure-aggregation
rounds and refusals. Anywhere else (a log file, a pipe, the tests) each event line carries the same
counts in brackets, so a log read later says as much as the terminal did.
"""

from __future__ import annotations

from rich.console import Console
from rich.live import Live
from rich.text import Text

__all__ = ["ServiceStatus"]


class ServiceStatus:
    """The event printer of one ``serve`` run.

    Parameters
    ----------
    secure : bool
        Show the rounds' counts (a secure-aggregation fleet).
    console : rich.console.Console, optional
        Where to print (default: standard output).
    """

    def __init__(self, secure: bool, console: Console | None = None) -> None:
        self.secure = secure
        self.console = console or Console()
        self.live: Live | None = None
        if self.console.is_terminal:
            self.live = Live(Text("starting"), console=self.console, refresh_per_second=4, transient=True)
            self.live.start()

    def counts(self, st: dict) -> str:
        """The running counts of :meth:`ServiceStore.status <roadcollab.network.store.ServiceStore.status>`.

        Parameters
        ----------
        st : dict
        """
        r = st["rounds"]
        rounds = (f", rounds {r.get('finished', 0)} finished/{r.get('open', 0)} open/{r.get('aborted', 0)} aborted"
                  if self.secure else "")
        return (f"{st['vehicles']} vehicles, {st['segments']} segments, {st['contributions']} contributions{rounds}, "
                f"{sum(st['refused'].values())} refused")

    def event(self, line: str, st: dict) -> None:
        """Print one event with the store's counts after it.

        Parameters
        ----------
        line : str
        st : dict
            The store's status.
        """
        if self.live is None:
            print(f"{line}  [{self.counts(st)}]", flush=True)
            return
        self.console.print(line, markup=False, highlight=False)
        self.live.update(Text(f"serving: {self.counts(st)}", style="bold"))

    def stop(self) -> None:
        """End the live status (the terminal keeps the event lines)."""
        if self.live is not None:
            self.live.stop()
            self.live = None
