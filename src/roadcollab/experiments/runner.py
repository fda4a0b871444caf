"""Run independent Monte Carlo runs serially, on a local process pool or on a Dask cluster.

Every run gets its own :class:`numpy.random.SeedSequence` child, and each task rebuilds what
it needs from plain, picklable inputs, so the results are identical for every worker count and
backend. What the runs share (e.g. a study's :class:`~roadcollab.experiments.pipeline.PipelineCache`)
is passed once as ``shared``:

- serially, the same object serves every task;
- ``workers=N`` starts a local :class:`concurrent.futures.ProcessPoolExecutor` whose workers receive
  the task and ``shared`` once, in their initializer. With the ``fork`` start method (Linux) that is
  not even a copy: a cache the parent warmed before the call is inherited as it is, so per-fleet setup
  is built once in all; with ``spawn`` the copy arrives empty and is built once per worker process;
- ``scheduler=ADDRESS`` (an existing Dask cluster, e.g. many machines) scatters ``shared`` once to every
  worker, so it is built once per worker process, not once per chunk.

Several studies that share ``shared`` can run on one pool (:func:`map_jobs`): a reproduction and its
measured-profile runs then pay for one pool and its workers' warm-up, not two, and the second study's
runs start while the first's last chunks finish. Every task runs with the kernel path in effect where
the call was made (:func:`~roadcollab.lti.kernels.use_kernels`), in every worker and backend.

Nothing is kept between calls.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

from threadpoolctl import threadpool_limits

from .._validation import check_int
from ..errors import ParameterError
from ..lti.kernels import kernel_path, use_kernels

__all__ = ["Job", "map_jobs", "map_runs", "pool_context", "local_dask_cluster"]

#: One run's result, as the task returns it.
_R = TypeVar("_R")

#: The tasks and shared object of this process when it is a pool worker (set once by the pool's
#: initializer, in the worker process only; the parent never writes it).
_WORKER: dict = {}


@dataclass(frozen=True)
class Job:
    """One study's runs for :func:`map_jobs`.

    Attributes
    ----------
    task : callable
        Picklable ``task(indices) -> list of results`` (``task(indices, shared)`` with ``shared``).
    n_runs : int
        The runs are ``range(n_runs)``.
    progress : callable, optional
        Called with the number of this job's finished runs.
    """

    task: Callable
    n_runs: int
    progress: Callable[[int], None] | None = None


@dataclass(frozen=True)
class _SingleThreaded:
    """Run a task with single-threaded BLAS and the caller's kernel path. Threaded BLAS sums in a
    different order, so serial and parallel runs would differ in the last bits; one thread everywhere
    makes them bit-identical (and avoids oversubscribing cores when several workers share a machine).
    The kernel path is carried explicitly: a spawned or Dask worker does not inherit the caller's
    :func:`~roadcollab.lti.kernels.use_kernels` choice."""

    task: Callable
    kernels: str

    def __call__(self, indices, *shared):
        with threadpool_limits(limits=1), use_kernels(self.kernels):
            return self.task(indices, *shared)


def _chunks(n: int, size: int) -> list[range]:
    return [range(i, min(i + size, n)) for i in range(0, n, size)]


def pool_context() -> multiprocessing.context.BaseContext:
    """The start method of the local pool: ``fork`` where the platform has it, ``spawn`` otherwise.

    Returns
    -------
    multiprocessing.context.BaseContext
    """
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


#: How often a pool worker checks that its parent is alive, s.
PARENT_POLL_S = 0.2


def _watch_parent(parent: int) -> None:
    """Exit this worker as soon as its parent is gone (a SIGKILLed parent cannot stop its workers)."""
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != parent:
            os._exit(1)


def _init_worker(tasks: tuple, extra: tuple, parent: int) -> None:
    """Pool initializer: keep the tasks and the shared object for every chunk of this worker.

    A worker leaves interrupts to its parent: Ctrl-C reaches the whole process group, and a worker's
    own ``KeyboardInterrupt`` would print a traceback per worker; the parent stops the workers itself
    (:func:`_stop_workers`). SIGTERM gets its default action back (a forked worker inherits the
    parent's handler). A thread exits the worker when the parent dies.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="roadcollab-parent-watch").start()
    _WORKER["tasks"], _WORKER["extra"] = tasks, extra


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Kill the pool's worker processes now (``shutdown`` would wait for their running chunks)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # private, but the only handle
    for p in procs:
        with contextlib.suppress(OSError, ValueError):
            p.kill()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            p.join(timeout=2.0)


def _run_chunk(job: int, indices: list) -> list:
    """A pool worker's chunk of job ``job``, with the tasks and shared object its initializer received."""
    return _WORKER["tasks"][job](indices, *_WORKER["extra"])


def _pool_map(tasks: tuple, extra: tuple, chunks: list[tuple[int, range]], workers: int,
              on_done: Callable[[int, int], None]) -> list:
    """Evaluate ``(job, runs)`` chunks on one local process pool, submitted in order; results per chunk.
    ``on_done(job, runs)`` is called as each chunk finishes."""
    results: list = [None] * len(chunks)
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=pool_context(),
                               initializer=_init_worker, initargs=(tasks, extra, os.getpid()))
    try:
        pending = {pool.submit(_run_chunk, job, list(c)): k for k, (job, c) in enumerate(chunks)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                k = pending.pop(fut)
                results[k] = fut.result()
                on_done(chunks[k][0], len(chunks[k][1]))
    except BaseException:  # an error, Ctrl-C or SIGTERM: no worker may outlive the run
        _stop_workers(pool)
        raise
    pool.shutdown(wait=True)
    return results


@contextlib.contextmanager
def local_dask_cluster(workers: int, *, memory_limit: str | None = None):
    """A Dask ``LocalCluster`` of ``workers`` single-threaded worker processes, closed on exit.

    Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which pins glibc's mmap threshold at
    128 KiB: every FFT-sized temporary is then mmapped and page-faulted afresh (a run took 0.46 s on a
    worker vs 0.23 s serially). A high mmap threshold restores heap reuse.

    Parameters
    ----------
    workers : int
        Worker processes (one thread each: the kernels are BLAS/FFT heavy and single-threaded).
    memory_limit : str, optional
        Per-worker memory limit in Dask's notation (default: Dask's, the machine's share).

    Yields
    ------
    str
        The scheduler's address, for ``map_runs(..., scheduler=...)``.
    """
    import dask
    from dask.distributed import LocalCluster

    workers = check_int("workers", workers, low=1, high=256)
    dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 1 << 30,
                     "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": 1 << 26})
    kw = {} if memory_limit is None else {"memory_limit": memory_limit}
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=40, **kw)
    try:
        yield cluster.scheduler_address
    finally:
        cluster.close()


@contextlib.contextmanager
def _client(scheduler: str):
    from dask.distributed import Client

    client = Client(scheduler)
    try:
        yield client
    finally:
        client.close()


def _dask_map(task: Callable, extra: tuple, n_runs: int, scheduler: str, chunk_size, progress) -> list:
    """Evaluate the runs on an existing Dask cluster; results per chunk, in chunk order."""
    from dask.distributed import as_completed

    with _client(scheduler) as client:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})))
        chunks = _chunks(n_runs, chunk_size or max(1, -(-n_runs // (4 * n_workers))))
        if extra:
            extra = (client.scatter(extra[0], broadcast=True, hash=False),)
        futures = {client.submit(task, list(c), *extra, pure=False): k for k, c in enumerate(chunks)}
        results: list = [None] * len(chunks)
        done = 0
        for fut in as_completed(futures):
            k = futures[fut]
            results[k] = fut.result()
            done += len(chunks[k])
            if progress is not None:
                progress(done)
    return results


def map_runs(task: Callable[..., list[_R]], n_runs: int, *, workers: int | None = None,
             scheduler: str | None = None, progress: Callable[[int], None] | None = None,
             chunk_size: int | None = None, shared: object | None = None) -> list[_R]:
    """Evaluate ``task(indices) -> list of results`` over ``range(n_runs)`` in chunks.

    With ``shared``, the task is called as ``task(indices, shared)``.

    Parameters
    ----------
    task : callable
        Picklable function of a sequence of run indices returning one result per index.
    n_runs : int
    workers : int, optional
        Run on a local process pool (``concurrent.futures``, :func:`pool_context`) with this many
        worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler (e.g. ``tcp://10.0.0.5:8786``).
    progress : callable, optional
        Called with the number of finished runs.
    chunk_size : int, optional
        Runs per task (default: serial one by one; parallel about 4 tasks per worker).
    shared : object, optional
        Passed to every call of ``task``: the same object in a serial run, one per worker process
        otherwise (inherited by a forked pool worker, a copy with ``spawn``, scattered once on Dask),
        so a cache in it persists across that worker's chunks.

    Returns
    -------
    list
        Results in run order.

    Raises
    ------
    ParameterError
        ``workers`` and ``scheduler`` both given, or ``workers`` outside 1..256.

    Examples
    --------
    >>> map_runs(lambda idx: [10 * i for i in idx], 3)
    [0, 10, 20]
    """
    return map_jobs([Job(task, n_runs, progress)], workers=workers, scheduler=scheduler, chunk_size=chunk_size,
                    shared=shared)[0][0]


def map_jobs(jobs: list[Job], *, workers: int | None = None, scheduler: str | None = None,
             chunk_size: int | None = None, shared: object | None = None) -> list[tuple[list, float]]:
    """Evaluate several jobs (:class:`Job`) that share ``shared``, on one pool, in order.

    Serially the jobs run one after the other. On a local pool every chunk of every job is submitted at
    once, the first job's first, so the pool starts once and the next job's chunks fill the workers while
    the previous job's last chunks finish; the results are the same as from :func:`map_runs` per job.
    On Dask the jobs run one after the other.

    Parameters
    ----------
    jobs : list of Job
    workers, scheduler, chunk_size, shared
        As for :func:`map_runs` (``chunk_size`` per job).

    Returns
    -------
    list of (list, float)
        Per job: its results in run order, and the wall time from this call's start until its last run
        finished, s.

    Raises
    ------
    ParameterError
        ``workers`` and ``scheduler`` both given, ``workers`` outside 1..256, or a job with no run.

    Examples
    --------
    >>> [r for r, _ in map_jobs([Job(lambda idx: list(idx), 2), Job(lambda idx: [-i for i in idx], 3)])]
    [[0, 1], [0, -1, -2]]
    """
    jobs = list(jobs)
    if not jobs or not all(isinstance(j, Job) for j in jobs):
        raise ParameterError("jobs must be a non-empty list of Job")
    sizes = [check_int("n_runs", j.n_runs, low=1) for j in jobs]
    if workers is not None:
        workers = check_int("workers", workers, low=1, high=256)
    if scheduler is not None and workers is not None:
        raise ParameterError("give either workers (a local pool) or scheduler (a Dask cluster), not both")
    path = kernel_path()
    singles = tuple(_SingleThreaded(j.task, path) for j in jobs)
    extra: tuple[Any, ...] = () if shared is None else (shared,)
    t0 = time.perf_counter()
    out: list[tuple[list, float]] = []
    if workers is None:
        for job, single, n in zip(jobs, singles, sizes):
            if scheduler is not None:
                results = [r for chunk in _dask_map(single, extra, n, scheduler, chunk_size, job.progress)
                           for r in chunk]
            else:   # one BLAS limit around the job's runs: entering it costs 1.3 ms (measured), per run 2 %
                results = []
                with threadpool_limits(limits=1), use_kernels(path):
                    for i in range(n):
                        results.extend(job.task([i], *extra))
                        if job.progress is not None:
                            job.progress(i + 1)
            out.append((results, time.perf_counter() - t0))
        return out
    chunks = [(k, c) for k, n in enumerate(sizes) for c in _chunks(n, chunk_size or max(1, -(-n // (4 * workers))))]
    done, finished = [0] * len(jobs), [0.0] * len(jobs)
    left = [sum(1 for k, _ in chunks if k == j) for j in range(len(jobs))]      # chunks not yet finished

    def on_done(job: int, runs: int) -> None:
        done[job] += runs
        left[job] -= 1
        if not left[job]:
            finished[job] = time.perf_counter() - t0
        report = jobs[job].progress
        if report is not None:
            report(done[job])

    results = _pool_map(singles, extra, chunks, workers, on_done)
    for k in range(len(jobs)):
        out.append(([r for (job, _), chunk in zip(chunks, results) if job == k for r in chunk], finished[k]))
    return out
