"""Parallel runs (local process pool, real Dask LocalCluster) give bit-identical results to serial runs."""

import dataclasses
import os

import numpy as np
import pytest

from roadcollab import ExperimentConfig, ParameterError, run_reproduction
from roadcollab.experiments.runner import local_dask_cluster, map_runs

CFG = ExperimentConfig(n_vehicles=3, n_runs=4, segment_length=90.0)


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_process_pool_matches_serial_bit_for_bit():
    serial = run_reproduction(CFG, 7).table()
    pool = run_reproduction(CFG, 7, workers=2).table()
    assert serial == pool


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_local_dask_cluster_matches_serial_bit_for_bit():
    cfg = dataclasses.replace(CFG, n_runs=3)
    serial = run_reproduction(cfg, 7).table()
    with local_dask_cluster(2) as address:
        dask = run_reproduction(cfg, 7, scheduler=address).table()
    assert serial == dask


@pytest.mark.slow     # end-to-end: two studies on a worker pool (make test-slow)
def test_reproductions_on_one_pool_match_each_alone_serially():
    """roadcollab reproduce's two studies (the synthetic road, then the measured profile with the IRI) on one pool:
    each result equals its study run alone and serially, bit for bit."""
    from roadcollab.experiments.reproduction.iri import IRI_SEGMENT_LENGTH
    from roadcollab.experiments.reproduction.study import run_reproductions

    measured = dataclasses.replace(CFG, n_runs=3, road_profile="packaged")
    (a, ta), (b, tb) = run_reproductions([CFG, measured], 7, workers=2, iri_segment_lengths=[None, IRI_SEGMENT_LENGTH])
    assert a.table() == run_reproduction(CFG, 7).table()
    alone = run_reproduction(measured, 7, iri_segment_length=IRI_SEGMENT_LENGTH)
    assert b.table() == alone.table() and b.iri_rows() == alone.iri_rows()
    assert 0 < min(ta, tb)


def test_pool_keeps_shared_per_worker_not_per_chunk():
    """Six one-run chunks on two workers: each worker process holds one shared object for all its
    chunks (a copy per chunk would count 1 every time)."""
    seen = map_runs(_CountChunks(), 6, workers=2, chunk_size=1, shared=_Counter())
    per_worker = {}
    for pid, calls in seen:
        per_worker.setdefault(pid, []).append(calls)
    assert len(per_worker) <= 2 and max(len(v) for v in per_worker.values()) >= 3
    assert all(sorted(v) == list(range(1, len(v) + 1)) for v in per_worker.values())


class _Counter:
    """A shared object that counts the chunks its worker ran."""

    def __init__(self):
        self.calls = 0


class _CountChunks:
    def __call__(self, indices, counter):
        counter.calls += 1
        return [(os.getpid(), counter.calls) for _ in indices]


def test_two_runners_do_not_share_state():
    """Each run owns its shared object (a study's cache): two runs, serial or on a pool, never see each
    other's, the workers' changes stay in the workers, and the parent keeps no worker state."""
    from roadcollab.experiments import runner

    a, b = _Counter(), _Counter()
    assert [c for _, c in map_runs(_CountChunks(), 3, shared=a)] == [1, 2, 3]
    assert [c for _, c in map_runs(_CountChunks(), 2, shared=b)] == [1, 2]
    pa = map_runs(_CountChunks(), 2, workers=1, chunk_size=1, shared=a)
    pb = map_runs(_CountChunks(), 2, workers=1, chunk_size=1, shared=b)
    assert [c for _, c in pa] == [4, 5] and [c for _, c in pb] == [3, 4]   # each from its own object's state
    assert {p for p, _ in pa}.isdisjoint({p for p, _ in pb}) and os.getpid() not in {p for p, _ in pa}
    assert (a.calls, b.calls) == (3, 2)
    assert runner._WORKER == {}

def test_jobs_share_one_pool_and_each_gets_its_own_results():
    """map_jobs: two jobs on one pool of two workers: the same per-job results as map_runs, one shared object per
    worker across both jobs (its chunk count keeps rising from the first job to the second), progress per job, and
    each job's finishing time no later than the call's end."""
    from roadcollab.experiments.runner import Job, map_jobs

    seen: dict = {0: [], 1: []}
    jobs = [Job(_Tagged(0), 5, seen[0].append), Job(_Tagged(1), 3, seen[1].append)]
    (a, ta), (b, tb) = map_jobs(jobs, workers=2, chunk_size=1, shared=_Counter())
    assert [(job, i) for job, i, _, _ in a] == [(0, i) for i in range(5)]
    assert [(job, i) for job, i, _, _ in b] == [(1, i) for i in range(3)]
    per_worker: dict = {}
    for _, _, pid, calls in a + b:
        per_worker.setdefault(pid, []).append(calls)
    assert len(per_worker) <= 2 and sorted(c for v in per_worker.values() for c in v) != [1] * 8
    assert all(sorted(v) == list(range(1, len(v) + 1)) for v in per_worker.values())   # one object per worker
    assert seen[0][-1] == 5 and seen[1][-1] == 3 and 0 < min(ta, tb)
    (sa, _), (sb, _) = map_jobs([Job(_Tagged(0), 5), Job(_Tagged(1), 3)], shared=_Counter())   # serially
    assert [x[:2] for x in sa] == [x[:2] for x in a] and [x[:2] for x in sb] == [x[:2] for x in b]
    with pytest.raises(ParameterError, match="non-empty list of Job"):
        map_jobs([])


class _Tagged:
    def __init__(self, job):
        self.job = job

    def __call__(self, indices, counter):
        counter.calls += 1
        return [(self.job, i, os.getpid(), counter.calls) for i in indices]


def _kernel_path_task(indices):
    from roadcollab.lti.kernels import kernel_path

    return [kernel_path() for _ in indices]


@pytest.mark.parametrize("path", ["compiled", "reference"])
def test_every_worker_runs_with_the_callers_kernel_path(monkeypatch, path):
    """The caller's use_kernels choice reaches the pool's workers, against an environment variable that says the
    other: spawned workers (as on a platform without fork, or Dask's) inherit the environment, not the choice."""
    import multiprocessing

    from roadcollab.experiments import runner
    from roadcollab.lti.kernels import compiled_available, use_kernels

    monkeypatch.setattr(runner, "pool_context", lambda: multiprocessing.get_context("spawn"))
    monkeypatch.setenv("ROADCOLLAB_KERNELS", "reference" if path == "compiled" else "compiled")
    expected = path if compiled_available() else "reference"
    with use_kernels(path):
        assert map_runs(_kernel_path_task, 4, workers=2, chunk_size=1) == [expected] * 4
        assert map_runs(_kernel_path_task, 2) == [expected] * 2


def test_pool_propagates_task_errors():
    with pytest.raises(ParameterError, match="run 3 refused"):
        map_runs(_Refuse(), 5, workers=2, chunk_size=1)


class _Refuse:
    def __call__(self, indices):
        if 3 in indices:
            raise ParameterError("run 3 refused")
        return list(indices)


def test_chunking_does_not_change_results():
    cfg = dataclasses.replace(CFG, n_runs=3)
    one = run_reproduction(cfg, 3).table()
    progress = []
    again = run_reproduction(cfg, 3, progress=progress.append).table()
    assert one == again and progress == [1, 2, 3]


def test_bad_parallel_arguments():
    with pytest.raises(ParameterError, match="either workers .* or scheduler"):
        map_runs(lambda idx: list(idx), 2, workers=1, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(ParameterError, match="workers must be >= 1, got 0"):
        map_runs(lambda idx: list(idx), 2, workers=0)


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_attack_study_on_dask_matches_serial():
    from roadcollab.experiments.security.study import AttackStudyConfig, run_attack_study

    cfg = AttackStudyConfig(experiment=ExperimentConfig(n_vehicles=3, n_runs=1, segment_length=90.0), n_runs=2,
                            paillier_bits=512, paillier_sample=2, physical_fit_runs=1, dp_epsilons=(1.0,),
                            replica_runs=1, replica_targets=1, poisoning_runs=1)
    a, b = run_attack_study(cfg, 5), run_attack_study(cfg, 5, workers=2)
    assert [repr(r) for r in a.attack_rows] == [repr(r) for r in b.attack_rows]
    assert a.linkability_rows == b.linkability_rows
    assert [r.mse_vehicle2 for r in a.baseline_rows] == [r.mse_vehicle2 for r in b.baseline_rows]
    assert [repr(r) for r in a.poisoning_rows] == [repr(r) for r in b.poisoning_rows]   # NaN != NaN


def test_seed_plan_streams_are_stateless_and_match_spawn():
    """Named streams equal numpy's spawn tree of a fresh parent, however often they are asked for."""
    from roadcollab.experiments.seeds import RUN_STREAMS, SeedPlan, descendant, run_stream

    plan = SeedPlan(7)
    fleet, runs = np.random.SeedSequence(7).spawn(2)
    assert plan.fleet().spawn_key == fleet.spawn_key
    run3 = runs.spawn(5)[3]
    assert plan.run(3).generate_state(4).tolist() == run3.generate_state(4).tolist()
    children = np.random.SeedSequence(7).spawn(2)[1].spawn(5)[3].spawn(len(RUN_STREAMS))
    for k, name in enumerate(RUN_STREAMS):
        a, b = run_stream(plan.run(3), name), run_stream(plan.run(3), name)   # asked twice
        assert a.generate_state(4).tolist() == b.generate_state(4).tolist() == children[k].generate_state(4).tolist()
    assert descendant(plan.root, 1, 3).spawn_key == (1, 3)
    with pytest.raises(ValueError, match="name must be one of"):
        run_stream(plan.run(0), "weather")


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_fleet_scale_run_matches_serial_on_pool_and_dask():
    from roadcollab.experiments.bench.scale import run_scale, run_segments

    cfg = ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=60.0)
    serial = run_segments(cfg, 3, 4)
    pool = run_segments(cfg, 3, 4, workers=2)
    assert [s.index for s in pool] == [0, 1, 2, 3]
    assert all(np.array_equal(a.mse, b.mse) for a, b in zip(serial, pool))
    assert not np.array_equal(serial[0].mse, serial[1].mse)   # segments differ: the check can fail
    res = run_scale([2, 3], n_vehicles=2, workers=2, seed=3, segment_length=60.0, check_segments=2)
    assert res.identical_to_serial is True and res.serial_check_segments == 2
    assert [p.segments for p in res.points] == [2, 3] and all(1 <= p.worker_processes <= 2 for p in res.points)
    assert all(p.peak_rss_mb_per_worker > 0 for p in res.points)
    with pytest.raises(ParameterError, match="mechanism must be one of"):
        run_segments(cfg, 0, 1, mechanism="rot13")


def test_pipeline_cache_shares_estimators_across_roads_only():
    """The same fleet on the measured profile reuses the synthetic road's estimators, not its road moment;
    another design (gamma) builds its own; both give the results of a fresh cache."""
    from roadcollab.experiments.pipeline import PipelineCache, design_key

    cfg = ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=60.0)
    measured = dataclasses.replace(cfg, road_profile="packaged", n_runs=5)
    other = dataclasses.replace(cfg, gamma=32.0)
    assert design_key(cfg) == design_key(measured) != design_key(other)
    cache = PipelineCache()
    a, b, c = cache.pipeline(cfg, 4), cache.pipeline(measured, 4), cache.pipeline(other, 4)
    assert all(x is y for x, y in zip(a.estimators, b.estimators))
    assert not any(x is y for x, y in zip(a.estimators, c.estimators))
    assert not np.array_equal(a.road_moment, b.road_moment)
    assert b.profile_file is b.profile_file and a.profile_file is None
    shared = run_reproduction(measured, 4, cache=cache).table()
    assert shared == run_reproduction(measured, 4).table()
    with pytest.raises(ParameterError, match="cache must be a PipelineCache"):
        run_reproduction(cfg, 4, cache={})
