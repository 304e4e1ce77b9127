"""The CPU a run uses: intra-op threads and DataLoader workers, from the cores it may use.

PyTorch starts one intra-op thread per core of the machine. Its OpenMP threads wait for each
other at every operator, so when another process holds a core, every operator waits for the
thread that is not running: on a 2-core machine with one core busy, AiGem's step at batch 32 ran
3.5 times slower with 2 threads than with 1 (bench/bench_train.py). Without `--threads`, training
therefore uses the cores that the other processes leave idle, looked at again every
`LOOK_EVERY_S` seconds (/proc/stat on Linux, at no cost; elsewhere every usable core).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import torch

LOOK_EVERY_S = 10.0
PROBE_S = 0.2  # how long `idle_cores` looks at the others' load before training starts
STAT = Path("/proc/stat")


def usable_cores() -> int:
    """The cores this process may run on (its affinity; all of them where that is unknown)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def default_workers(device_type: str, cores: int) -> int:
    """DataLoader workers when not given: on a GPU the loader must keep up with the step, so
    all cores but two (for the step and the main process), at most 12; on the CPU the step
    is about ten times slower than loading, so one worker where there are 4 cores or more, to
    overlap loading with the step, and none below."""
    if device_type == "cuda":
        return max(1, min(12, cores - 2))
    return 1 if cores >= 4 else 0


def _busy_and_total(cpus: set[int]) -> tuple[int, int] | None:
    """(busy, total) jiffies of `cpus` since boot, from /proc/stat; None where unreadable."""
    try:
        lines = STAT.read_text().splitlines()
    except OSError:
        return None
    busy = total = 0
    for line in lines:
        name, *values = line.split()
        if not name.startswith("cpu") or name == "cpu" or int(name[3:]) not in cpus:
            continue
        numbers = [
            int(value) for value in values[:8]
        ]  # user nice system idle iowait irq softirq steal
        total += sum(numbers)
        busy += sum(numbers) - numbers[3] - numbers[4]
    return (busy, total) if total else None


def idle_cores(cpus: set[int], over_s: float = PROBE_S) -> float | None:
    """How many of `cpus` no process kept busy over the next `over_s` seconds (this process
    sleeps meanwhile), from /proc/stat; None where that is unreadable (not Linux)."""
    first = _busy_and_total(cpus)
    if first is None:
        return None
    time.sleep(over_s)
    second = _busy_and_total(cpus)
    if second is None or second[1] <= first[1]:
        return None
    busy_share = (second[0] - first[0]) / (second[1] - first[1])
    return len(cpus) * (1.0 - busy_share)


def busy_cores_warning(threads: int, idle: float | None = None) -> str | None:
    """What to tell a user who fixed `threads` intra-op threads while other processes keep some
    of the usable cores busy (`idle`: idle cores, measured by `idle_cores` when not given); None
    when every thread has an idle core, or where the load cannot be seen. PyTorch's threads wait
    for each other at every operator, so a thread without a core of its own stalls them all: on
    2 cores with one kept busy, `--threads 2` trained at 6 graphs/s where the default took 314."""
    cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    if idle is None:
        idle = idle_cores(cpus) if cpus else None
    if idle is None or threads <= max(1.0, idle + 0.5):  # one thread never waits for another
        return None
    busy = max(0.0, len(cpus) - idle)
    return (
        f"--threads {threads} with {idle:.1f} of {len(cpus)} usable cores idle (other processes "
        f"keep {busy:.1f} busy): every step waits for the threads without a core, which made "
        f"training 50 times slower; give --threads {max(1, math.floor(idle + 0.5))} or leave "
        "--threads out (it follows the idle cores)"
    )


class ThreadChooser:
    """Sets torch's intra-op threads to the usable cores that other processes leave idle.

    `threads` given: that many, always. Otherwise: all usable cores at first, then, from each call
    of `look` at least LOOK_EVERY_S after the last, the cores other processes kept busy in between
    (all busy jiffies minus this process's own CPU time) are taken off, leaving at least one.
    """

    def __init__(self, threads: int | None) -> None:
        self.fixed = threads is not None
        self.cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
        self.cores = usable_cores()
        self.threads = threads if threads is not None else self.cores
        torch.set_num_threads(self.threads)
        self._last = self._sample()
        if not self.fixed:  # a first look over a quarter of a second, before the work starts
            time.sleep(0.25)
            self.look(at_once=True)

    def _sample(self) -> tuple[float, float, tuple[int, int] | None]:
        return time.monotonic(), time.process_time(), _busy_and_total(self.cpus)

    def look(self, at_once: bool = False) -> int:
        """The thread count now (changed if others' load changed); cheap between looks."""
        if self.fixed or (not at_once and time.monotonic() - self._last[0] < LOOK_EVERY_S):
            return self.threads
        now = self._sample()
        (wall0, own0, jiffies0), (wall1, own1, jiffies1) = self._last, now
        self._last = now
        if jiffies0 is None or jiffies1 is None or jiffies1[1] <= jiffies0[1]:
            return self.threads
        busy_share = (jiffies1[0] - jiffies0[0]) / (jiffies1[1] - jiffies0[1])
        others = busy_share * len(self.cpus) - (own1 - own0) / (wall1 - wall0)
        threads = min(self.cores, max(1, round(self.cores - max(others, 0.0))))
        if threads != self.threads:
            self.threads = threads
            torch.set_num_threads(threads)
        return threads
