"""The seed plan: named, stateless random streams below one root seed.

Every study derives its randomness from one root seed through :class:`numpy.random.SeedSequence`
descendants addressed by a path of child indices, so a stream is the same however often, in
whichever order and in whichever process it is asked for. (``SeedSequence.spawn`` is stateful:
spawning twice from one parent hands out different children; addressing children by path
avoids that.) The trees, below ``SeedSequence(seed)``:

- reproduction, security study, anomaly study, anomaly calibration: the fleet is ``(0,)`` and
  run ``i`` is ``(1, i)``; with a new fleet per run (``--redraw-fleet``) run ``i``'s fleet is
  ``(1, i, 0)`` and its simulation ``(1, i, 1)``;
- sweep: run ``r`` is ``(r,)``, its fleet ``(r, 0)`` and its simulation ``(r, 1)`` (the same at
  every grid point: common random numbers);
- within one run's simulation seed, the named streams of :data:`RUN_STREAMS`: the road, the
  sensor noise, the obfuscators (privacy), the DP noise and the road the attacker uses as its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_int
from ..errors import ParameterError

__all__ = ["RUN_STREAMS", "descendant", "as_seed_sequence", "run_stream", "SeedPlan"]

#: Named streams of one run, in child order.
RUN_STREAMS = ("road", "noise", "privacy", "dp", "own_road")


def descendant(ss: np.random.SeedSequence, *path: int) -> np.random.SeedSequence:
    """The descendant of ``ss`` at ``path``: what ``ss.spawn(...)[path[0]].spawn(...)[path[1]]...``
    returns from a fresh ``ss``, without changing any state.

    Parameters
    ----------
    ss : numpy.random.SeedSequence
    *path : int
        Child indices, outermost first.

    Returns
    -------
    numpy.random.SeedSequence
    """
    return np.random.SeedSequence(ss.entropy, spawn_key=tuple(ss.spawn_key) + tuple(int(i) for i in path),
                                  pool_size=ss.pool_size)


def as_seed_sequence(rng) -> np.random.SeedSequence:
    """A SeedSequence as is; anything else seeds a Generator whose first 63-bit integer becomes one.

    Parameters
    ----------
    rng : numpy.random.SeedSequence | numpy.random.Generator | int | None

    Returns
    -------
    numpy.random.SeedSequence
    """
    if isinstance(rng, np.random.SeedSequence):
        return rng
    return np.random.SeedSequence(np.random.default_rng(rng).integers(2**63))


def run_stream(ss: np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """One named stream of a run.

    Parameters
    ----------
    ss : numpy.random.SeedSequence
        The run's simulation seed.
    name : str
        One of :data:`RUN_STREAMS`.

    Returns
    -------
    numpy.random.SeedSequence
    """
    if name not in RUN_STREAMS:
        raise ParameterError(f"name must be one of {RUN_STREAMS}, got {name!r}")
    return descendant(ss, RUN_STREAMS.index(name))


@dataclass(frozen=True)
class SeedPlan:
    """The streams of a study with root seed ``seed`` (see the module docstring for the trees).

    Parameters
    ----------
    seed : int
        Root seed (>= 0).
    """

    seed: int

    def __post_init__(self) -> None:
        check_int("seed", self.seed, low=0)

    @property
    def root(self) -> np.random.SeedSequence:
        """``SeedSequence(seed)``."""
        return np.random.SeedSequence(self.seed)

    def fleet(self) -> np.random.SeedSequence:
        """The fleet of a study that keeps one fleet for all runs."""
        return descendant(self.root, 0)

    def run(self, i: int) -> np.random.SeedSequence:
        """Run ``i``'s seed.

        Parameters
        ----------
        i : int
            Run index.

        Returns
        -------
        numpy.random.SeedSequence
        """
        return descendant(self.root, 1, i)

    def runs(self, n: int) -> list[np.random.SeedSequence]:
        """The seeds of runs ``0 .. n-1``.

        Parameters
        ----------
        n : int

        Returns
        -------
        list of numpy.random.SeedSequence
        """
        return [self.run(i) for i in range(n)]

    def run_fleet(self, i: int) -> np.random.SeedSequence:
        """Run ``i``'s own fleet (a new fleet per run).

        Parameters
        ----------
        i : int

        Returns
        -------
        numpy.random.SeedSequence
        """
        return descendant(self.root, 1, i, 0)

    def run_simulation(self, i: int) -> np.random.SeedSequence:
        """Run ``i``'s simulation seed when the run draws its own fleet.

        Parameters
        ----------
        i : int

        Returns
        -------
        numpy.random.SeedSequence
        """
        return descendant(self.root, 1, i, 1)

    def sweep_run(self, r: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
        """(fleet, simulation) seeds of sweep run ``r``, the same at every grid point.

        Parameters
        ----------
        r : int

        Returns
        -------
        (numpy.random.SeedSequence, numpy.random.SeedSequence)
        """
        return descendant(self.root, r, 0), descendant(self.root, r, 1)
