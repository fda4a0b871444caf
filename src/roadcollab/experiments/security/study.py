"""The security study behind ``roadcollab attack``: attacks (the paper's, informed ones and the replica
attacker), linkability, exactness, poisoning and the conventional baselines (DP with composition,
Paillier, AEAD, secure aggregation) measured side by side on the same segments.

One run is one segment (a fresh road, fresh sensor noise, fresh obfuscators; see
:mod:`roadcollab.experiments.security.segment`); the fleet is the same in every run, so messages of
one vehicle on different runs are what a curious receiver could try to link. The replica attacks and
secure aggregation use the first ``replica_runs`` segments
(:mod:`~roadcollab.experiments.security.replica`); the poisoning measurements their own runs
(:mod:`.poisoning`, :mod:`.fusion_poisoning`). The tables are built in
:mod:`~roadcollab.experiments.security.tables`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..._validation import check_int
from ...errors import ParameterError
from ...privacy import baselines
from ..anomalies.config import AnomalyStudyConfig
from .collusion import collusion_rows
from .fusion_poisoning import PoisoningSummary, fusion_poisoning_rows
from ..pipeline import PipelineCache
from .poisoning import poisoning_rows, summarize
from .receiver_attacks import receiver_attack_rows
from ..runner import map_runs
from .config import AttackStudyConfig
from .replica import run_replica_attacks
from .rows import AttackRow, BaselineRow, CompositionRow, ExactnessRow, FrontierPoint, LinkabilityRow
from .segment import SegmentAttacks, attack_segment
from .tables import (attack_rows, baseline_rows, composition_rows, exactness_rows, frontier_points,
                     linkability_rows)
from ..seeds import SeedPlan

__all__ = ["AttackStudyConfig", "AttackStudyResult", "run_attack_study"]


@dataclass(frozen=True, eq=False)
class AttackStudyResult:
    """Everything ``roadcollab attack`` writes.

    Attributes
    ----------
    config : AttackStudyConfig
        The study.
    seed : int
        Root seed.
    attack_rows : tuple of AttackRow
        ``attack.csv``.
    exactness_rows : tuple of ExactnessRow
        ``exactness.csv``.
    linkability_rows : tuple of LinkabilityRow
        ``linkability.csv``.
    baseline_rows : tuple of BaselineRow
        ``baselines.csv``.
    poisoning_rows : tuple of PoisoningSummary
        ``poisoning.csv``: hostile messages against a receiver, one malicious vehicle against the fusion.
    composition_rows : tuple of CompositionRow
        ``dp_composition.csv``.
    frontier : tuple of FrontierPoint
        The privacy/accuracy frontier (``frontier.csv`` and its figure).
    pole_examples : tuple of dict
        First segment, vehicles 1..3: true poles and the attacks' estimates (rad/s).
    secagg_clipped : bool
        Whether an honest input reached secure aggregation's clipping bound.
    """

    config: AttackStudyConfig
    seed: int
    attack_rows: tuple[AttackRow, ...]
    exactness_rows: tuple[ExactnessRow, ...]
    linkability_rows: tuple[LinkabilityRow, ...]
    baseline_rows: tuple[BaselineRow, ...]
    poisoning_rows: tuple[PoisoningSummary, ...]
    composition_rows: tuple[CompositionRow, ...]
    frontier: tuple[FrontierPoint, ...]
    pole_examples: tuple[dict, ...]
    secagg_clipped: bool


@dataclass(frozen=True)
class _AttackTask:
    """Picklable task: the attacks of runs ``indices``, with the pipeline from the shared cache."""

    config: AttackStudyConfig
    seed: int
    key: bytes

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[SegmentAttacks]:
        pipe = cache.pipeline(self.config.experiment, self.seed)
        seeds = SeedPlan(self.seed).runs(self.config.n_runs)
        return [attack_segment(pipe, self.config, r, seeds[r], self.key) for r in indices]


def _poisoning(config: AttackStudyConfig, seed: int, pipe) -> list[PoisoningSummary]:
    """Hostile messages against vehicle 2 (guarded), one malicious vehicle against the fusion node."""
    receiver = summarize(poisoning_rows(config.experiment, seed=seed, n_runs=config.poisoning_runs, receiver=1,
                                        pipe=pipe))
    # Guard-aware coherent lies (scaled to 0.8 x the threshold, fake pothole at 0.9 x, slow drift; issue 20).
    receiver += receiver_attack_rows(config.experiment, seed=seed, n_runs=config.poisoning_runs, receiver=1, pipe=pipe)
    malicious = min(4, config.experiment.n_vehicles - 1)
    fused = fusion_poisoning_rows(AnomalyStudyConfig(experiment=config.experiment), seed,
                                  n_runs=config.poisoning_runs, malicious=malicious, pipe=pipe)
    # Pooling colluders c = 1 ... 4 against the robust node (issue 20, section 3).
    colluding = collusion_rows(AnomalyStudyConfig(experiment=config.experiment), seed, n_runs=config.poisoning_runs,
                               fleet_sizes=(config.experiment.n_vehicles,), pipe=pipe)
    return receiver + fused + colluding


def run_attack_study(config: AttackStudyConfig, seed: int, *, progress: Callable[[int], None] | None = None,
                     workers: int | None = None, scheduler: str | None = None) -> AttackStudyResult:
    """Run the security study (see the module docstring); segments serially or on Dask.

    Results do not depend on ``workers``/``scheduler`` except the timing columns.

    Parameters
    ----------
    config : AttackStudyConfig
    seed : int
        Root seed (>= 0) of the fleet and of every run.
    progress : callable, optional
        Called with the number of finished steps: the ``n_runs`` segments, then the replica fits.
    workers : int, optional
        Run the segments on a local process pool with this many worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler (e.g. ``tcp://host:8786``); not with ``workers``.

    Returns
    -------
    AttackStudyResult

    Raises
    ------
    ParameterError
        If ``config`` is not an AttackStudyConfig, ``seed`` is negative, or both ``workers``
        and ``scheduler`` are given.
    """
    if not isinstance(config, AttackStudyConfig):
        raise ParameterError(f"config must be an AttackStudyConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    cache = PipelineCache()
    pipe = cache.pipeline(config.experiment, seed)
    runs = map_runs(_AttackTask(config, seed, baselines.new_key()), config.n_runs, workers=workers,
                    scheduler=scheduler, progress=progress, shared=cache)
    replica = run_replica_attacks(config, seed, pipe, progress=None if progress is None else
                                  (lambda k: progress(config.n_runs + k)))
    attacks = attack_rows(config, pipe, runs, replica)
    last_z = runs[0].last_z
    if last_z is None:                  # every attack run records its last hardened message
        raise ParameterError("the first attack run recorded no hardened message")
    he = baselines.paillier_cost(last_z.ravel(), key_bits=config.paillier_bits,
                                 sample=config.paillier_sample, rng=np.random.default_rng(seed))
    base = baseline_rows(config, runs, he, replica)
    return AttackStudyResult(
        config=config, seed=seed, attack_rows=tuple(attacks), exactness_rows=tuple(exactness_rows(runs, replica)),
        linkability_rows=tuple(linkability_rows(runs, config.experiment.n_vehicles)), baseline_rows=tuple(base),
        poisoning_rows=tuple(_poisoning(config, seed, pipe)), composition_rows=tuple(composition_rows(config)),
        frontier=tuple(frontier_points(attacks, base, replica, config.experiment.n_vehicles)), pole_examples=tuple(runs[0].pole_examples),
        secagg_clipped=replica.secagg_clipped)
