"""Run independent Monte Carlo runs serially or on a Dask cluster.

Every run gets its own :class:`numpy.random.SeedSequence` child, and each task rebuilds what
it needs from plain, picklable inputs, so the results are identical for every worker count and
scheduler. What the runs share (e.g. a study's
:class:`~roadcollab.experiments.pipeline.PipelineCache`) is passed once as ``shared``: a serial
run hands the same object to every task, Dask scatters it once to every worker, so per-fleet
setup is built once per worker process, not once per task or chunk. Nothing is kept between calls.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Callable, Sequence

from threadpoolctl import threadpool_limits

from .._validation import check_int
from ..errors import ParameterError

__all__ = ["map_runs"]

@dataclass(frozen=True)
class _SingleThreaded:
    """Run a task with single-threaded BLAS. Threaded BLAS sums in a different order, so
    serial and Dask runs would differ in the last bits; one thread everywhere makes them
    bit-identical (and avoids oversubscribing cores when several workers share a machine)."""

    task: Callable

    def __call__(self, indices, *shared):
        with threadpool_limits(limits=1):
            return self.task(indices, *shared)


def _chunks(n: int, size: int) -> list[range]:
    return [range(i, min(i + size, n)) for i in range(0, n, size)]


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None):
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        client = Client(scheduler)
        try:
            yield client
        finally:
            client.close()
        return
    # One thread per worker process: the numerical kernels are BLAS/FFT heavy and the
    # workers' BLAS is single-threaded by Dask's defaults, so processes do not oversubscribe.
    # Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which pins glibc's mmap threshold
    # at 128 KiB: every FFT-sized temporary is then mmapped and page-faulted afresh (a run
    # took 0.46 s on a worker vs 0.23 s serially). A high mmap threshold restores heap reuse.
    import dask

    dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 1 << 30,
                     "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": 1 << 26})
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=40)
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def map_runs(task: Callable[[Sequence[int]], list], n_runs: int, *, workers: int | None = None,
             scheduler: str | None = None, progress: Callable[[int], None] | None = None,
             chunk_size: int | None = None, shared: object | None = None) -> list:
    """Evaluate ``task(indices) -> list of results`` over ``range(n_runs)`` in chunks.

    With ``shared``, the task is called as ``task(indices, shared)``.

    Parameters
    ----------
    task : callable
        Picklable function of a sequence of run indices returning one result per index.
    n_runs : int
    workers : int, optional
        Start a local Dask cluster with this many worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler (e.g. ``tcp://10.0.0.5:8786``).
    progress : callable, optional
        Called with the number of finished runs.
    chunk_size : int, optional
        Runs per task (default: serial all at once one by one; parallel about 4 tasks per
        worker).
    shared : object, optional
        Passed to every call of ``task``: the same object in a serial run, one copy per worker
        process on Dask (scattered once, so a cache in it persists across that worker's chunks).

    Returns
    -------
    list
        Results in run order.
    """
    n_runs = check_int("n_runs", n_runs, low=1)
    if workers is not None:
        workers = check_int("workers", workers, low=1, high=256)
    if scheduler is not None and workers is not None:
        raise ParameterError("give either workers (a local cluster) or scheduler (an existing one), not both")
    task = _SingleThreaded(task)
    extra = () if shared is None else (shared,)
    if workers is None and scheduler is None:
        out = []
        for i in range(n_runs):
            out.extend(task([i], *extra))
            if progress is not None:
                progress(i + 1)
        return out
    from dask.distributed import as_completed

    with _client(workers, scheduler) as client:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or (workers or 1))
        size = chunk_size or max(1, -(-n_runs // (4 * n_workers)))
        chunks = _chunks(n_runs, size)
        if extra:
            extra = (client.scatter(shared, broadcast=True, hash=False),)
        futures = {client.submit(task, list(c), *extra, pure=False): k for k, c in enumerate(chunks)}
        results: list = [None] * len(chunks)
        done = 0
        for fut in as_completed(futures):
            k = futures[fut]
            results[k] = fut.result()
            done += len(chunks[k])
            if progress is not None:
                progress(done)
    return [r for chunk in results for r in chunk]
