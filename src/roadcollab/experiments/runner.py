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

__all__ = ["map_runs", "pool_context", "local_dask_cluster"]

#: One run's result, as the task returns it.
_R = TypeVar("_R")

#: The task and shared object of this process when it is a pool worker (set once by the pool's
#: initializer, in the worker process only; the parent never writes it).
_WORKER: dict = {}


@dataclass(frozen=True)
class _SingleThreaded:
    """Run a task with single-threaded BLAS. Threaded BLAS sums in a different order, so
    serial and parallel runs would differ in the last bits; one thread everywhere makes them
    bit-identical (and avoids oversubscribing cores when several workers share a machine)."""

    task: Callable

    def __call__(self, indices, *shared):
        with threadpool_limits(limits=1):
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


def _init_worker(task: Callable, extra: tuple, parent: int) -> None:
    """Pool initializer: keep the task and the shared object for every chunk of this worker.

    A worker leaves interrupts to its parent: Ctrl-C reaches the whole process group, and a worker's
    own ``KeyboardInterrupt`` would print a traceback per worker; the parent stops the workers itself
    (:func:`_stop_workers`). SIGTERM gets its default action back (a forked worker inherits the
    parent's handler). A thread exits the worker when the parent dies.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="roadcollab-parent-watch").start()
    _WORKER["task"], _WORKER["extra"] = task, extra


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


def _run_chunk(indices: list) -> list:
    """A pool worker's chunk, with the task and shared object its initializer received."""
    return _WORKER["task"](indices, *_WORKER["extra"])


def _pool_map(task: Callable, extra: tuple, chunks: list[range], workers: int, progress) -> list:
    """Evaluate the chunks on a local process pool; results per chunk, in chunk order."""
    results: list = [None] * len(chunks)
    done = 0
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=pool_context(),
                               initializer=_init_worker, initargs=(task, extra, os.getpid()))
    try:
        pending = {pool.submit(_run_chunk, list(c)): k for k, c in enumerate(chunks)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                k = pending.pop(fut)
                results[k] = fut.result()
                done += len(chunks[k])
                if progress is not None:
                    progress(done)
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
    n_runs = check_int("n_runs", n_runs, low=1)
    if workers is not None:
        workers = check_int("workers", workers, low=1, high=256)
    if scheduler is not None and workers is not None:
        raise ParameterError("give either workers (a local pool) or scheduler (a Dask cluster), not both")
    single = _SingleThreaded(task)
    extra: tuple[Any, ...] = () if shared is None else (shared,)
    if workers is None and scheduler is None:
        out: list[_R] = []
        for i in range(n_runs):
            out.extend(single([i], *extra))
            if progress is not None:
                progress(i + 1)
        return out
    if scheduler is not None:
        results = _dask_map(single, extra, n_runs, scheduler, chunk_size, progress)
    else:
        assert workers is not None  # neither None above, and scheduler is None here
        chunks = _chunks(n_runs, chunk_size or max(1, -(-n_runs // (4 * workers))))
        results = _pool_map(single, extra, chunks, workers, progress)
    return [r for chunk in results for r in chunk]
