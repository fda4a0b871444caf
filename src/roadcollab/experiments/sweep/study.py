"""Where does Algorithm 1 beat a single vehicle? A sweep over observer, noise and model quality.

The sweep crosses three settings of :class:`~roadcollab.experiments.config.ExperimentConfig`:

- the observer parameter ``gamma`` of eq. 4 (corner ``gamma (1 + gamma) / 2`` rad/s; 1 is a
  weak observer, about 128 and beyond the strongest),
- the accelerometer noise standard deviation ``sensor_noise_std``, m/s^2,
- the relative parameter uncertainty of each vehicle's model
  (:attr:`~roadcollab.models.vehicle.FleetSpec.estimate_uncertainty`).

Every grid point runs the same ``n_runs`` Monte Carlo runs with the engine of the reproduction
(:class:`~roadcollab.experiments.pipeline.FleetPipeline` and
:func:`~roadcollab.experiments.reproduction.study.simulate_run`, privacy off: it changes no estimate). Each run draws
a *new* fleet and its own road, so the statistics are over fleets. The randomness of run ``r``
is the same at every grid point (common random numbers): the same road, the same standard-normal
sensor noise (scaled by the noise level) and the same fleet draw (true parameters, and
parameter-estimate errors scaled by the uncertainty). Differences between grid points are then
paired comparisons, free of most of the run-to-run scatter.

Seeds::

    SeedSequence(seed) -> run r (child r) -> (fleet draw, simulate_run) (children 0 and 1)

(:meth:`roadcollab.experiments.seeds.SeedPlan.sweep_run`).

Every (grid point, run) pair is an independent task rebuilt from these seeds, so the result
does not depend on the number of workers or on the scheduler.

The grid is :class:`~roadcollab.experiments.sweep.config.SweepConfig`, the result
:class:`~roadcollab.experiments.sweep.result.SweepResult` and its analysis
:mod:`roadcollab.experiments.sweep.findings`; this module runs the grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..._validation import check_int
from ...errors import ParameterError
from ...models.vehicle import sample_fleet
from ..pipeline import PipelineCache
from ..reproduction.study import simulate_run
from ..runner import map_runs
from .config import SWEPT_ESTIMATORS, SweepConfig
from .result import SweepResult
from ..seeds import SeedPlan

__all__ = ["run_sweep"]


def _run_seed_sequences(seed: int, n_runs: int, r: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """(fleet, simulation) SeedSequences of run ``r``, the same at every grid point.

    Built afresh on every call: ``SeedSequence.spawn`` advances the parent's child counter, so
    reusing a parent (or passing the same child to two ``simulate_run`` calls) would hand later
    grid points different randomness.
    """
    return SeedPlan(seed).sweep_run(r)


@dataclass(frozen=True)
class _SweepTask:
    """Picklable task: evaluates flat indices ``i = point * n_runs + run`` of a sweep."""

    config: SweepConfig
    seed: int

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[dict]:
        cfg = self.config
        points = cfg.points()
        out = []
        for i in indices:
            p, r = divmod(i, cfg.n_runs)
            exp = cfg.point_config(*points[p])
            fleet_ss, sim_ss = _run_seed_sequences(self.seed, cfg.n_runs, r)
            pipe = cache.fleet_pipeline(exp, sample_fleet(cfg.n_vehicles, exp.fleet,
                                                          rng=np.random.default_rng(fleet_ss)))
            res = simulate_run(pipe, sim_ss, privacy=False)
            out.append({k: np.asarray(res.mse[k], dtype=float) for k in SWEPT_ESTIMATORS})
        return out


def run_sweep(config: SweepConfig, seed: int, *, progress: Callable[[int], None] | None = None,
              workers: int | None = None, scheduler: str | None = None) -> SweepResult:
    """Run every grid point of a sweep, serially or on Dask.

    Cost: one fleet setup (:class:`~roadcollab.experiments.pipeline.FleetPipeline`, including the
    centralised and oracle estimators) and one run per (grid point, run) pair; about 0.8 s
    for 10 vehicles on one core.

    Parameters
    ----------
    config : SweepConfig
    seed : int
        Root seed (>= 0). Run ``r`` gets the same randomness at every grid point.
    progress : callable, optional
        Called with the number of finished (grid point, run) pairs, out of
        ``len(config.points()) * config.n_runs``.
    workers : int, optional
        Local process pool with this many worker processes (the result is identical).
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    SweepResult

    Raises
    ------
    ParameterError
        ``config`` is not a SweepConfig, ``seed`` is negative, or the parallel options clash.

    Examples
    --------
    >>> cfg = SweepConfig(gammas=(1, 128), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,),
    ...                   n_vehicles=3, n_runs=2)
    >>> rows = run_sweep(cfg, 0).table()  # doctest: +SKIP
    """
    if not isinstance(config, SweepConfig):
        raise ParameterError(f"config must be a SweepConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    P, R, V = len(config.points()), config.n_runs, config.n_vehicles
    runs = map_runs(_SweepTask(config, seed), P * R, workers=workers, scheduler=scheduler, progress=progress,
                    shared=PipelineCache())
    mse = {k: np.array([run[k] for run in runs]).reshape(P, R, V) for k in SWEPT_ESTIMATORS}
    return SweepResult(config=config, seed=seed, mse=mse)
