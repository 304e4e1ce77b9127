"""Profile: where one build's time goes, function by function, by sampling its stack.

Builds the given input files in this process with one job and one Polars thread, and samples
the main thread's stack every 5 ms: for each function of ngsim_graphs, the share of the samples
it was on the stack (its own time and its callees', Polars' and numpy's native work included,
which cProfile would charge to `collect` or a thread's wait), and the lines where the samples
were. With one thread, a task's pieces (`threads.in_order`) run in this thread: they are seen.
Synthetic data: these are not NGSIM results.

    python bench/profile_build.py bench/out/raw-txt-r6-m15/us-101/trajectories-0820am-0835am.txt
    python bench/profile_build.py FILE --protocol cs-lstm --top 40
"""

from __future__ import annotations

import os

os.environ["POLARS_MAX_THREADS"] = "1"  # before Polars is imported: one core

import argparse  # noqa: E402
import collections  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from ngsim_graphs.config import BuildConfig  # noqa: E402
from ngsim_graphs.pipeline import run_build  # noqa: E402
from ngsim_graphs.schema import Protocol  # noqa: E402

PACKAGE = "ngsim_graphs/"


class StackSampler:
    """Samples a thread's stack every `period_s`: its innermost package line, and each package
    function on it."""

    def __init__(self, thread_id: int, period_s: float = 0.005) -> None:
        self.thread_id, self.period_s = thread_id, period_s
        self.lines: collections.Counter[str] = collections.Counter()
        self.functions: collections.Counter[str] = collections.Counter()
        self.samples = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> StackSampler:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            frame = sys._current_frames().get(self.thread_id)
            ours = []
            while frame is not None:
                name = frame.f_code.co_filename
                if PACKAGE in name:
                    where = name.split(PACKAGE, 1)[1]
                    ours.append((where, frame.f_lineno, frame.f_code.co_name))
                frame = frame.f_back
            self.samples += 1
            if ours:
                where, line, function = ours[0]
                self.lines[f"{where}:{line} {function}"] += 1
                for function in {f"{where} {name}" for where, _, name in ours}:
                    self.functions[function] += 1


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("paths", type=Path, nargs="+")
    parser.add_argument("--protocol", choices=[p.value for p in Protocol], default="aigem")
    parser.add_argument("--top", type=int, default=30, help="rows of each table")
    args = parser.parse_args()
    config = BuildConfig(protocol=Protocol(args.protocol))
    stages: list[tuple[str, float]] = []

    def progress(what: str, _done: int, _total: int, _detail: str = "") -> None:
        if not stages or stages[-1][0] != what:
            stages.append((what, time.perf_counter()))

    with tempfile.TemporaryDirectory(dir=Path(__file__).parent / "out") as scratch:
        start = time.perf_counter()
        with StackSampler(threading.get_ident()) as sampler:
            run_build(args.paths, Path(scratch) / "build", config, jobs=1, progress=progress)
        end = time.perf_counter()
    print(f"{', '.join(map(str, args.paths))}: {end - start:.1f} s, one job, one thread")
    for (what, at), (_, until) in zip(stages, [*stages[1:], ("", end)], strict=True):
        print(f"  {until - at:6.1f} s  {what}")
    total = max(1, sampler.samples)
    print(f"functions of {PACKAGE} on the stack (share of {sampler.samples:,} samples):")
    for function, n in sampler.functions.most_common(args.top):
        print(f"  {100 * n / total:5.1f} %  {function}")
    print("innermost lines of the package:")
    for line, n in sampler.lines.most_common(args.top):
        print(f"  {100 * n / total:5.1f} %  {line}")


if __name__ == "__main__":
    main()
