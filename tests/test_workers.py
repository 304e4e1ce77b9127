"""The build's worker processes: results in task order, errors as raised, the environment kept.

The tasks are module-level functions of this file: a spawned worker imports them by name.
"""

from __future__ import annotations

import os
import time

import pytest

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.workers import POLARS_THREADS, Workers, available_cores


def square_with_pid(value: int) -> tuple[int, int]:
    return value * value, os.getpid()


def polars_threads(_: int) -> str | None:
    return os.environ.get(POLARS_THREADS)


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
    with Workers(2) as workers:
        threads = workers.map(polars_threads, [(0,), (1,)])
    assert threads == [str(max(1, available_cores() // 2))] * 2
    assert POLARS_THREADS not in os.environ


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
