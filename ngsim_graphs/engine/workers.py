"""Work spread over processes: the build's `--jobs`, one task per input file or recording.

Tasks run in a pool of spawned processes (a forked child would inherit Polars' running thread
pool, which Polars warns against) and their results come back in task order, so that a build
made with N jobs is the build made with one, byte for byte. Each worker holds one task's data at
a time, so peak memory grows with the number of jobs, never with the number of tasks; the cores
are shared out among the workers for Polars' own threads (unless POLARS_MAX_THREADS says). A
worker keeps to one malloc arena with fixed thresholds and gives back what a task freed when
it ends (glibc's documented tunables and `malloc_trim`; elsewhere nothing is set).

Workers end with their parent. They start with Ctrl-C blocked (`interrupts`), so that the one a
terminal sends to the whole process group reaches only the parent, which then stops them at
once (SIGTERM), without waiting for their running tasks; and a worker whose parent is gone,
killed with no chance to stop them, ends itself the moment it sees that.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import connection, get_context
from types import FrameType
from typing import Any, TypeVar

from ngsim_graphs.budget import available_cores
from ngsim_graphs.errors import NgsimError
from ngsim_graphs.interrupts import children_deaf_to_ctrl_c
from ngsim_graphs.threads import SIGNAL_CHECK_S

Result = TypeVar("Result")
POLARS_THREADS = "POLARS_MAX_THREADS"
# glibc's malloc (numpy's) reads this when a process starts: see `one_malloc_arena`.
MALLOC_ARENAS = "MALLOC_ARENA_MAX"
# And these: blocks this large and under come from the heap, and as much freed at its top is
# kept for the next ones. By default both start small and grow with the blocks freed, and so a
# build task whose grid rows are mapped from their files, not held (`tasks.build_recording`),
# had its neighbourhoods' temporaries given back and faulted in anew for every chunk of ego rows:
# twice the page faults, a third slower, and no less memory at its peak than with these.
MALLOC_THRESHOLDS = {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "33554432"}
_M_ARENA_MAX = -8  # glibc's mallopt parameter of the same
STOP_GRACE_S = 5.0  # after SIGTERM, before a worker that is still there is killed


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The C library, where it is glibc (on Linux; musl has neither mallopt nor malloc_trim)."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None)
    return libc if hasattr(libc, "malloc_trim") else None


def one_malloc_arena() -> None:
    """Have glibc's malloc serve every thread of this process from one arena.

    A task frees what it allocated, piece by piece; with an arena per thread (numpy's work in
    the neighbourhoods' threads, Polars' own) each arena keeps the memory freed into it, and a
    worker's resident memory grew with every piece of a recording (1.10 GB against 0.65 GB for
    the densest one, and no slower on 2 cores). Arenas that exist already are kept: call it
    before threads allocate (a worker has MALLOC_ARENAS set instead, from its start: by the time
    a pool's initializer ran, importing the caller's main module had started threads, and its
    build tasks peaked 0.2 GB higher). Elsewhere than glibc this does nothing.
    """
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_ARENA_MAX, 1)


def worker_environment(environment: dict[str, str], size: int) -> dict[str, str]:
    """What a pool of `size` workers adds to `environment` for its processes: the cores shared
    out among them for Polars' threads, and one malloc arena each with fixed thresholds
    (MALLOC_THRESHOLDS; glibc's documented tunables). The user's own settings win."""
    settings = {}
    if POLARS_THREADS not in environment:
        settings[POLARS_THREADS] = str(max(1, available_cores() // size))
    if MALLOC_ARENAS not in environment:
        settings[MALLOC_ARENAS] = "1"
    return settings | {k: v for k, v in MALLOC_THRESHOLDS.items() if k not in environment}


def _releasing(function: Callable[..., Result], *args: Any) -> Result:
    """function(*args), then what malloc keeps of the memory the task freed given back to the
    system: the next task starts from what it needs (0.1-0.3 GB less in a build's workers)."""
    try:
        return function(*args)
    finally:
        libc = _glibc()
        if libc is not None:
            libc.malloc_trim(0)


def start_worker() -> None:
    """A worker's start (the pool's initializer): it ends the moment its parent has ended, and
    leaves on SIGTERM by SystemExit.

    multiprocessing's parent process of a spawned worker ends (`join` returns) when the pipe
    that the parent holds open to it closes, which the kernel does when the parent dies, by
    kill -9 included: no polling, and no task of an abandoned build goes on writing. SystemExit
    unwinds what the worker holds: a worker killed outright while it waited for a task could
    leave the pool's queue locked, and another worker, and the pool's shutdown, waiting on it
    for ever.
    """
    parent = multiprocessing.parent_process()
    if parent is None:  # not a worker process
        return

    def watch() -> None:
        parent.join()
        os._exit(1)  # nothing to hand results to; what it wrote is its parent's partial output

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()
    signal.signal(signal.SIGTERM, _leave)


def _leave(_signum: int, _frame: FrameType | None) -> None:
    # Stopped by its parent, which says why: nothing to say, also where the SystemExit comes
    # while the worker was ending already (Python reports an exception in an exit handler).
    sys.stderr = open(os.devnull, "w")  # noqa: SIM115
    raise SystemExit(1)


def _kill_stragglers(processes: list[multiprocessing.process.BaseProcess]) -> None:
    """Kill the `processes` that SIGTERM has not ended after STOP_GRACE_S: one whose SystemExit
    came while its task ran (the task's error, to the pool) waits for the next task, and the
    pool's shutdown for it, for ever. Their sentinels tell which have ended, without reaping
    them (the pool's own thread does)."""
    sentinels = {process.sentinel: process for process in processes}
    ended = set(connection.wait(list(sentinels), timeout=STOP_GRACE_S))
    for sentinel, process in sentinels.items():
        if sentinel not in ended:
            with contextlib.suppress(ProcessLookupError):
                os.kill(process.pid, signal.SIGKILL)  # type: ignore[arg-type]


def _failed(future: Future) -> bool:
    return future.done() and not future.cancelled() and future.exception() is not None


class Workers:
    """Up to `jobs` worker processes, kept from one `map` to the next while as many are needed.

    Use as a context manager; the processes end with it. With jobs == 1, or a single task, the
    tasks run in this process.
    """

    def __init__(self, jobs: int) -> None:
        if jobs < 1:
            raise ValueError(f"jobs must be at least 1, got {jobs}")
        self.jobs = jobs
        self._pool: ProcessPoolExecutor | None = None
        self._size = 0  # the running pool's
        self._saved_environment: dict[str, str | None] = {}
        # The processes this one had started before the running pool: not its workers.
        self._others: set[multiprocessing.process.BaseProcess] | None = None

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_exc: object) -> None:
        self._close(cancel=exc_type is not None)  # after an error or Ctrl-C, start nothing more

    def _close(self, cancel: bool = False) -> None:
        """End the processes: once their tasks are done, or with `cancel` at once (their running
        tasks are stopped, the others never start)."""
        pool, self._pool = self._pool, None
        others, self._others = self._others, None
        try:
            if cancel and others is not None:  # an interrupt may have come before `_pool` was set
                ours = [p for p in multiprocessing.active_children() if p not in others]
                for process in ours:
                    process.terminate()  # SIGTERM: the worker leaves by SystemExit
                threading.Thread(target=_kill_stragglers, args=(ours,), daemon=True).start()
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=cancel)
        finally:  # a second Ctrl-C while waiting: the environment is still given back
            for name, value in self._saved_environment.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
            self._saved_environment = {}

    def _start(self, size: int) -> ProcessPoolExecutor:
        """A pool of `size` processes, the cores shared out among them for Polars' threads (the
        environment is read when each process starts; see `worker_environment`)."""
        self._close()
        settings = worker_environment(dict(os.environ), size)
        self._saved_environment = {name: os.environ.get(name) for name in settings}
        os.environ.update(settings)
        self._others = set(multiprocessing.active_children())
        self._pool = ProcessPoolExecutor(
            size,
            mp_context=get_context("spawn"),
            initializer=start_worker,
        )
        self._size = size
        return self._pool

    def map(
        self,
        function: Callable[..., Result],
        tasks: Sequence[tuple[Any, ...]],
        finished: Callable[[int], None] = lambda _done: None,
        sizes: Sequence[float] | None = None,
    ) -> list[Result]:
        """[function(*task) for task in tasks], spread over the processes.

        `finished(n)` is called in this process after each of the n tasks done so far. A failure
        stops the tasks after it; the earliest failure in task order is raised here, as the task
        raised it, the one a single job would have met. `sizes`, a guess of each task's work,
        starts the largest first: no large task is left to run alone at the end.
        """
        size = min(self.jobs, len(tasks))
        if size <= 1:
            results = []
            for task in tasks:
                results.append(_releasing(function, *task))
                finished(len(results))
            return results
        order = (
            range(len(tasks))
            if sizes is None
            else sorted(range(len(tasks)), key=sizes.__getitem__, reverse=True)
        )
        same = self._pool is not None and self._size == size
        pool = self._pool if same else self._start(size)
        # The processes start as the tasks are submitted, or later from the pool's own thread
        # (which starts at the first submit) after a worker died: both with Ctrl-C blocked here.
        # Not from before the pool is made: its queue starts multiprocessing's resource tracker,
        # which unblocks SIGINT in the thread it was started from (test_engine_workers checks
        # that workers start with SIGINT blocked).
        with children_deaf_to_ctrl_c():
            submitted = {i: pool.submit(_releasing, function, *tasks[i]) for i in order}
        futures = [submitted[i] for i in range(len(tasks))]
        remaining = set(futures)
        n_done = 0
        while remaining:
            done, remaining = wait(remaining, SIGNAL_CHECK_S, FIRST_COMPLETED)
            failed = next((i for i, future in enumerate(futures) if _failed(future)), None)
            if failed is not None:
                for future in futures[failed + 1 :]:
                    future.cancel()
                wait(futures[:failed])  # an earlier task may fail too: its error comes first
                self._close(cancel=True)
                failure = next(f.exception() for f in futures if _failed(f))
                if isinstance(failure, BrokenProcessPool):
                    raise NgsimError(
                        None,
                        "a worker process of the build stopped unexpectedly (killed, perhaps "
                        "for want of memory): build again with a lower --jobs",
                    ) from None
                raise failure
            for _ in done:
                n_done += 1
                finished(n_done)
        return [future.result() for future in futures]
