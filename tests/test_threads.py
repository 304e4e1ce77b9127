"""A task's pieces on threads: one thread's results and errors, no more pieces held than threads."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from ngsim_graphs.threads import in_order


def slow_first(item: int) -> int:
    """The earlier an item, the longer it takes: on threads, the later ones finish first."""
    time.sleep(0.01 * (5 - item % 5))
    return item * item


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_results_come_in_the_items_order(threads: int) -> None:
    assert list(in_order(slow_first, range(12), threads)) == [i * i for i in range(12)]
    assert list(in_order(slow_first, [], threads)) == []


def test_each_runs_on_a_thread_of_its_own_at_once() -> None:
    """Four items on four threads: all four are running at once (a barrier of four passes)."""
    barrier = threading.Barrier(4, timeout=10)
    assert list(in_order(lambda i: barrier.wait() * 0 + i, range(4), 4)) == [0, 1, 2, 3]


def test_no_more_items_are_taken_than_threads_ahead() -> None:
    taken: list[int] = []

    def items() -> Iterator[int]:
        for i in range(10):
            taken.append(i)
            yield i

    results = in_order(slow_first, items(), 3)
    assert next(results) == 0
    assert len(taken) == 3  # the first yielded, two more running
    assert next(results) == 1
    assert len(taken) == 4
    assert list(results) == [i * i for i in range(2, 10)]


def fails_at(*failing: int):  # noqa: ANN201
    def function(item: int) -> int:
        time.sleep(0.01 * (5 - item % 5))  # a later failure is met first on threads
        if item in failing:
            raise ValueError(f"item {item}")
        return item

    return function


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_the_first_error_in_the_items_order_is_raised(threads: int) -> None:
    with pytest.raises(ValueError, match="item 2"):
        list(in_order(fails_at(2, 3), range(8), threads))

    def items() -> Iterator[int]:  # reading the fourth item fails, after the third's error
        yield from range(3)
        raise OSError("cannot read item 3")

    with pytest.raises(ValueError, match="item 2"):
        list(in_order(fails_at(2), items(), threads))
    with pytest.raises(OSError, match="item 3"):
        list(in_order(fails_at(), items(), threads))
