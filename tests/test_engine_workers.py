"""The build's worker processes: results in task order, errors as raised, the environment kept.

The tasks are module-level functions of this file: a spawned worker imports them by name.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ngsim_graphs.budget import available_cores
from ngsim_graphs.engine.workers import (
    MALLOC_ARENAS,
    MALLOC_THRESHOLDS,
    POLARS_THREADS,
    STOP_GRACE_S,
    Workers,
    worker_environment,
)
from ngsim_graphs.errors import NgsimInputError


def square_with_pid(value: int) -> tuple[int, int]:
    return value * value, os.getpid()


def pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def polars_threads(_: int) -> str | None:
    return os.environ.get(POLARS_THREADS)


def allocator_settings(_: int) -> tuple[str | None, ...]:
    return tuple(os.environ.get(name) for name in (MALLOC_ARENAS, *MALLOC_THRESHOLDS))


def sigint_blocked(_: int) -> bool:
    return signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def pid_file_then_work(folder: str, index: int, seconds: float) -> None:
    """Say which process runs the task, then work for `seconds`, as a long computation in C
    would: a Ctrl-C does not stop it."""
    (Path(folder) / f"pid-{index}").write_text(str(os.getpid()))
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        with contextlib.suppress(KeyboardInterrupt):
            time.sleep(0.05)


def fail_last(index: int) -> int:
    """Task 2 fails at once; the others take a moment."""
    if index == 2:
        raise ValueError("task 2")
    time.sleep(0.3)
    return index


# Failed maps, one after the other: when task 2 fails, the process that ran it waits for a task.
FAILING_MAPS = """
import sys
sys.path.insert(0, {tests!r})
from test_engine_workers import fail_last
from ngsim_graphs.engine.workers import Workers
for _ in range({runs}):
    try:
        with Workers(2) as workers:
            tasks = [(i,) for i in range(3)]
            workers.map(fail_last, tasks, sizes=[3, 2, 1])
    except ValueError:
        pass
print("done")
"""


def test_a_failed_map_never_waits_for_ever_on_its_workers() -> None:
    # A worker stopped while it waited for a task could hold the pool's queue: the shutdown that
    # followed waited for ever on a worker that waited for the queue (a build refused by a
    # worker's error hung about one time in two).
    code = FAILING_MAPS.format(tests=str(Path(__file__).parent), runs=6)
    program = subprocess.Popen(
        [sys.executable, "-c", code],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        out, err = program.communicate(timeout=60)
    finally:
        if program.poll() is None:
            os.killpg(program.pid, signal.SIGKILL)
    assert (out, err) == ("done\n", "")


def deaf_to_sigterm(index: int) -> int:
    """Task 1 will not end on SIGTERM and would run for a minute; task 0 fails after it began."""
    if index == 0:
        time.sleep(0.5)
        raise ValueError("task 0")
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    time.sleep(60)
    return index


def test_a_worker_that_sigterm_does_not_end_is_killed() -> None:
    # A worker that SIGTERM did not end (it came as the task's error, say) held the pool's
    # shutdown until it ended: for ever where it waited for a task that never came.
    start = time.monotonic()
    with Workers(2) as workers, pytest.raises(ValueError, match="task 0"):
        workers.map(deaf_to_sigterm, [(0,), (1,)])
    assert time.monotonic() - start < STOP_GRACE_S + 10


def fail_on(value: int, bad: int) -> int:
    if value == bad:
        raise NgsimInputError("input.txt", f"value {value} is bad", line=value)
    return value


def test_results_come_back_in_task_order_from_other_processes() -> None:
    done: list[int] = []
    tasks = [(v,) for v in range(7)]
    with Workers(2) as workers:
        results = workers.map(square_with_pid, tasks, done.append, sizes=[1, 9, 2, 8, 3, 7, 4])
    assert [r for r, _ in results] == [v * v for v in range(7)]
    assert {pid for _, pid in results} - {os.getpid()}, "the tasks ran in worker processes"
    assert done == list(range(1, 8))


def test_one_job_runs_in_this_process() -> None:
    done: list[int] = []
    with Workers(1) as workers:
        results = workers.map(square_with_pid, [(2,), (3,)], done.append)
    assert results == [(4, os.getpid()), (9, os.getpid())]
    assert done == [1, 2]


@pytest.mark.skipif(POLARS_THREADS in os.environ, reason="the user's own setting is kept")
def test_workers_share_the_cores_and_leave_the_environment_as_it_was() -> None:
    before = dict(os.environ)
    with Workers(2) as workers:
        threads = workers.map(polars_threads, [(0,), (1,)])
    assert threads == [str(max(1, available_cores() // 2))] * 2
    assert dict(os.environ) == before


def test_worker_environment_shares_cores_and_lets_the_users_settings_win() -> None:
    cores = str(max(1, available_cores() // 2))
    malloc = {MALLOC_ARENAS: "1", **MALLOC_THRESHOLDS}
    assert worker_environment({}, 2) == {POLARS_THREADS: cores, **malloc}
    users = {POLARS_THREADS: "3", MALLOC_ARENAS: "4", "MALLOC_TRIM_THRESHOLD_": "0"}
    assert worker_environment(users, 2) == {
        "MALLOC_MMAP_THRESHOLD_": MALLOC_THRESHOLDS["MALLOC_MMAP_THRESHOLD_"]
    }
    assert worker_environment(users | MALLOC_THRESHOLDS, 2) == {}


@pytest.mark.skipif(
    MALLOC_ARENAS in os.environ or any(name in os.environ for name in MALLOC_THRESHOLDS),
    reason="the user's own allocator settings are kept",
)
def test_workers_start_with_the_allocators_settings() -> None:
    with Workers(2) as workers:
        settings = workers.map(allocator_settings, [(0,), (1,)])
    assert settings == [("1", *MALLOC_THRESHOLDS.values())] * 2
    assert allocator_settings(0) == (None, None, None)  # this process's environment as it was


def test_a_worker_error_comes_back_whole() -> None:
    with Workers(2) as workers, pytest.raises(NgsimInputError) as raised:
        workers.map(fail_on, [(v, 3) for v in range(6)])
    assert str(raised.value) == "input.txt, line 3: value 3 is bad"
    assert raised.value.path == "input.txt" and raised.value.line == 3


def fail_first_and_last(value: int) -> int:
    """Tasks 0 and 5 fail at once, the others succeed after a while."""
    if value in (0, 5):
        raise NgsimInputError(f"file{value}.txt", "bad")
    time.sleep(0.3)
    return value


def test_the_earliest_failure_in_task_order_is_raised_as_with_one_job() -> None:
    """Largest first runs task 5 first and task 0 last: task 0 still runs, and its error wins."""
    tasks = [(v,) for v in range(6)]
    for jobs in (1, 2):
        with Workers(jobs) as workers, pytest.raises(NgsimInputError) as raised:
            workers.map(fail_first_and_last, tasks, sizes=[0, 1, 2, 3, 4, 5])
        assert str(raised.value) == "file0.txt: bad"


def test_jobs_must_be_positive() -> None:
    with pytest.raises(ValueError, match="jobs must be at least 1"):
        Workers(0)


# --- workers end with their parent -----------------------------------------------------------

# A program of two workers, one at a task of a minute, the other done with its task and waiting
# for the next; it says `interrupted` on Ctrl-C.
TWO_WORKERS = """
import sys
sys.path.insert(0, {tests!r})
from test_engine_workers import pid_file_then_work
from ngsim_graphs.engine.workers import Workers
try:
    with Workers(2) as workers:
        workers.map(pid_file_then_work, [({folder!r}, 0, 60), ({folder!r}, 1, 0)])
except KeyboardInterrupt:
    sys.stderr.write("interrupted\\n")
    sys.exit(130)
"""


def alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, ended but not yet reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def start_two_workers(folder: Path) -> tuple[subprocess.Popen, list[int]]:
    """The program above, in a process group of its own, once its second worker waits."""
    code = TWO_WORKERS.format(tests=str(Path(__file__).parent), folder=str(folder))
    program = subprocess.Popen(
        [sys.executable, "-c", code], stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    files = [folder / "pid-0", folder / "pid-1"]
    deadline = time.monotonic() + 60
    while not all(f.exists() and f.read_text() for f in files):
        assert time.monotonic() < deadline and program.poll() is None, "workers did not start"
        time.sleep(0.02)
    time.sleep(0.3)  # the second worker's task ends at once
    return program, [int(f.read_text()) for f in files]


def gone_within(pids: list[int], seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.02)
    return not any(alive(pid) for pid in pids)


def test_workers_start_with_ctrl_c_blocked() -> None:
    with Workers(2) as workers:
        assert workers.map(sigint_blocked, [(i,) for i in range(4)]) == [True] * 4
    assert not sigint_blocked(0)  # this process takes its Ctrl-C as before


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_when_their_parent_is_killed(tmp_path: Path) -> None:
    program, workers = start_two_workers(tmp_path)
    program.kill()  # kill -9: no chance to stop its workers
    program.communicate()
    assert gone_within(workers, 5), "the workers outlived their parent"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_to_the_process_group_stops_the_workers_without_a_word(tmp_path: Path) -> None:
    """A terminal's Ctrl-C reaches the workers too: a waiting worker stopped by it printed its
    traceback, and a busy one went on to its task's end. Both are stopped at once, silently."""
    program, workers = start_two_workers(tmp_path)
    os.killpg(program.pid, signal.SIGINT)
    try:
        _, stderr = program.communicate(timeout=30)
    finally:
        if program.poll() is None:  # not stopped: its workers are not left behind either
            os.killpg(program.pid, signal.SIGKILL)
    assert (program.returncode, stderr) == (130, "interrupted\n")
    assert gone_within(workers, 1)
