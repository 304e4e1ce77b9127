"""A task's pieces on its process's threads, in order.

numpy and Polars let go of the GIL in their loops over large arrays, so the independent pieces
of one task (a file's text chunks, a part's groups of vehicles, a recording's ranges of steps, a
range's chunks of ego rows) run at once on as many threads as Polars may use in the process (a
build worker's share of the cores, all of them in a build of one file), at most
`budget.Budget.pieces_at_once`. Their results come back in the pieces' order, as one thread
gives them, and only as many pieces as there are threads are held at once.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sized
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import TypeVar

import polars as pl

from ngsim_graphs import budget

Item = TypeVar("Item")
Result = TypeVar("Result")

# How often a wait (for a piece, or `engine.workers` for its workers) looks up to run the
# signal handlers: a Ctrl-C taken by another thread (Polars' start some) does not wake a wait
# without a timeout, and was handled only once a task ended, seconds later.
SIGNAL_CHECK_S = 0.1
_piece = threading.local()  # `inside` in the threads of an in_order: one within runs inline


def in_order(
    function: Callable[[Item], Result], items: Iterable[Item], threads: int | None = None
) -> Iterator[Result]:
    """function(item) for each of `items`, on `threads` threads (by default Polars' number,
    at most `budget.Budget.pieces_at_once`), yielded in the items' order; no more than
    `threads` items are taken ahead of the result last yielded. With one thread, one item, or
    within a piece that an in_order runs on a thread already (its threads are taken), each runs
    here, one after the other. Iterate it to its end (as `list` does): its threads end there.

    Errors come as one thread would meet them: the results before an error are yielded, and
    the error raised is the first in the items' order, a function's where its result would
    come, one of `items` itself (reading the next, say) where that item would be taken."""
    if threads is None:
        threads = min(pl.thread_pool_size(), budget.BUDGET.pieces_at_once)
    if isinstance(items, Sized):
        threads = min(threads, len(items))
    if threads <= 1 or getattr(_piece, "inside", False):
        yield from map(function, items)
        return

    def piece(item: Item) -> Result:
        _piece.inside = True
        return function(item)

    with ThreadPoolExecutor(threads) as pool:
        running: deque[Future[Result]] = deque()
        taken, failed = iter(items), None
        while True:
            try:
                item = next(taken)
            except StopIteration:
                break
            except Exception as err:  # after the results of the items before it
                failed = err
                break
            running.append(pool.submit(piece, item))
            if len(running) == threads:
                yield _result(running.popleft())
        while running:
            yield _result(running.popleft())
    if failed is not None:
        raise failed


def _result(future: Future[Result]) -> Result:
    """The future's result (or its error), waited for with a look up every SIGNAL_CHECK_S."""
    while not future.done():
        wait([future], SIGNAL_CHECK_S)
    return future.result()
