"""Peak resident memory of this process and every process it started, sampled while it runs.

`ru_maxrss` is one process's peak; a build with `--jobs N` runs in N + 1 processes at once, so
the benchmarks sum the resident memory of the whole process tree every SAMPLE_S seconds (Linux's
/proc) and keep the largest sum. A peak shorter than one sample can be missed; the sum is then a
lower bound, and `ru_maxrss` of this process and of its largest child are printed beside it.
"""

from __future__ import annotations

import contextlib
import os
import resource
import threading
import time
from pathlib import Path

SAMPLE_S = 0.05
PAGE_BYTES = os.sysconf("SC_PAGE_SIZE")


def _children(pid: int) -> list[int]:
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        with contextlib.suppress(OSError):  # the thread or process ended meanwhile
            found += [int(c) for c in task.read_text().split()]
    return found


def _tree_rss_bytes(pid: int) -> int:
    total, pending = 0, [pid]
    while pending:
        current = pending.pop()
        try:
            total += int(Path(f"/proc/{current}/statm").read_text().split()[1]) * PAGE_BYTES
        except (OSError, IndexError, ValueError):
            continue  # it ended meanwhile
        pending += _children(current)
    return total


class TreeMemory:
    """`with TreeMemory() as memory: ...`, then memory.peak_bytes: the largest sum seen (of this
    process's tree, or of process `pid`'s), and
    memory.samples: (time.perf_counter(), bytes) of every sample, to tell the peak of a stage."""

    def __init__(self, pid: int | None = None) -> None:
        self._pid = os.getpid() if pid is None else pid  # the root of the tree summed
        self.peak_bytes = 0
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            size = _tree_rss_bytes(self._pid)
            self.samples.append((time.perf_counter(), size))
            self.peak_bytes = max(self.peak_bytes, size)

    def peak_between(self, start: float, end: float) -> int:
        """The largest sum sampled between two time.perf_counter() readings (0: none)."""
        return max((size for at, size in self.samples if start <= at <= end), default=0)

    def __enter__(self) -> TreeMemory:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()


def process_peaks_gb() -> tuple[float, float]:
    """(ru_maxrss of this process, of its largest finished child) in GB (1024**3 bytes)."""
    kib = 1024**2
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kib
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / kib
    return own, child
