"""A task's pieces on threads: one thread's results and errors, no more pieces held than threads."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import polars as pl
import pytest
from conftest import set_budget

from ngsim_graphs.threads import in_order


def slow_first(item: int) -> int:
    """The earlier an item, the longer it takes: on threads, the later ones finish first."""
    time.sleep(0.01 * (5 - item % 5))
    return item * item


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_results_come_in_the_items_order(threads: int) -> None:
    assert list(in_order(slow_first, range(12), threads)) == [i * i for i in range(12)]
    assert list(in_order(slow_first, [], threads)) == []


def most_at_once(run: Callable[[Callable[[int], int]], list[int]]) -> int:
    """The most items that `run` (given the function) had running at once."""
    lock, running, most = threading.Lock(), [0], [0]

    def function(item: int) -> int:
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        time.sleep(0.05)
        with lock:
            running[0] -= 1
        return item

    assert run(function) == list(range(12))
    return most[0]


def test_as_many_run_at_once_as_threads_at_most_the_budget_s(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    assert most_at_once(lambda f: list(in_order(f, range(12), 4))) == 4
    monkeypatch.setattr(pl, "thread_pool_size", lambda: 16)
    set_budget(monkeypatch, pieces_at_once=3)
    assert most_at_once(lambda f: list(in_order(f, range(12)))) == 3
    monkeypatch.setattr(pl, "thread_pool_size", lambda: 2)
    assert most_at_once(lambda f: list(in_order(f, range(12)))) == 2


def test_a_piece_s_own_pieces_run_on_its_thread() -> None:
    """Nested: the inner pieces run where their outer piece runs, not on threads of their own
    (threads times threads of them at once)."""

    together = threading.Barrier(3, timeout=10)  # the outer pieces run at once

    def outer(_item: int) -> set[int]:
        together.wait()
        return set(in_order(lambda _: threading.get_ident(), range(6), 4))

    inner = list(in_order(outer, range(3), 3))
    assert all(len(idents) == 1 for idents in inner)
    assert len(set().union(*inner)) == 3  # the three outer pieces, each on a thread
    assert threading.get_ident() not in set().union(*inner)


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


def test_a_stop_before_the_end_ends_the_threads() -> None:
    before = threading.active_count()
    results = in_order(slow_first, range(10), 3)
    assert next(results) == 0
    assert threading.active_count() == before + 3
    results.close()  # as a consumer's error or break does, once the generator is dropped
    assert threading.active_count() == before


def fails_at(*failing: int) -> Callable[[int], int]:
    def function(item: int) -> int:
        time.sleep(0.01 * (5 - item % 5))  # a later failure is met first on threads
        if item in failing:
            raise ValueError(f"item {item}")
        return item

    return function


def until_error(results: Iterator[int]) -> tuple[list[int], BaseException | None]:
    got = []
    try:
        for result in results:
            got.append(result)
    except (ValueError, OSError) as err:
        return got, err
    return got, None


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_the_results_before_the_first_error_then_it(threads: int) -> None:
    got, err = until_error(in_order(fails_at(2, 3), range(8), threads))
    assert got == [0, 1] and str(err) == "item 2"

    def items() -> Iterator[int]:  # reading the fourth item fails, after the third's error
        yield from range(3)
        raise OSError("cannot read item 3")

    got, err = until_error(in_order(fails_at(2), items(), threads))
    assert got == [0, 1] and str(err) == "item 2"
    got, err = until_error(in_order(fails_at(), items(), threads))
    assert got == [0, 1, 2] and str(err) == "cannot read item 3"
    assert err.__context__ is None
