"""Work spread over processes: the build's `--jobs`, one task per input file or recording.

Tasks run in a pool of spawned processes (a forked child would inherit Polars' running thread
pool, which Polars warns against) and their results come back in task order, so that a build
made with N jobs is the build made with one, byte for byte. Each worker holds one task's data at
a time, so peak memory grows with the number of jobs, never with the number of tasks; the cores
are shared out among the workers for Polars' own threads (unless POLARS_MAX_THREADS says).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context
from typing import Any, TypeVar

from ngsim_graphs.errors import NgsimError

Result = TypeVar("Result")
POLARS_THREADS = "POLARS_MAX_THREADS"


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


@contextmanager
def _threads_per_worker(threads: int) -> Iterator[None]:
    """POLARS_MAX_THREADS for the workers started inside (the user's own setting wins)."""
    if POLARS_THREADS in os.environ:
        yield
        return
    os.environ[POLARS_THREADS] = str(threads)
    try:
        yield
    finally:
        os.environ.pop(POLARS_THREADS, None)


def _first_failure(futures: list[Future]) -> BaseException | None:
    """The exception of the earliest task, in task order, that failed (None: none did)."""
    for future in futures:
        if future.done() and not future.cancelled() and future.exception() is not None:
            return future.exception()
    return None


def map_in_order(
    function: Callable[..., Result],
    tasks: Sequence[tuple[Any, ...]],
    jobs: int,
    finished: Callable[[int], None] = lambda _done: None,
) -> list[Result]:
    """[function(*task) for task in tasks], over up to `jobs` processes when jobs > 1.

    `finished(n)` is called in this process after each of the n tasks done so far. The first
    failure stops the tasks not yet started and is raised here, as the task raised it.
    """
    if jobs <= 1 or len(tasks) <= 1:
        results = []
        for task in tasks:
            results.append(function(*task))
            finished(len(results))
        return results
    workers = min(jobs, len(tasks))
    context = get_context("spawn")
    with (
        _threads_per_worker(max(1, available_cores() // workers)),
        ProcessPoolExecutor(workers, mp_context=context) as pool,
    ):
        futures = [pool.submit(function, *task) for task in tasks]
        remaining = set(futures)
        while remaining:
            _done, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            failure = _first_failure(futures)
            if failure is not None:
                pool.shutdown(wait=True, cancel_futures=True)
                if isinstance(failure, BrokenProcessPool):
                    raise NgsimError(
                        None,
                        "a worker process of the build stopped (killed, perhaps for want of "
                        "memory): build again with a lower --jobs",
                    ) from None
                raise failure
            finished(len(futures) - len(remaining))
        return [future.result() for future in futures]
