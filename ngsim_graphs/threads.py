"""A task's pieces on its process's threads, in order.

numpy and Polars let go of the GIL in their loops over large arrays, so the independent pieces
of one task (a file's text chunks, a recording's ranges of steps) run at once on as many threads
as Polars may use in the process: a build worker's share of the cores, all of them in a build
of one file. Their results come back in the pieces' order, as one thread gives them, and only
as many pieces as there are threads are held at once.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import polars as pl

Item = TypeVar("Item")
Result = TypeVar("Result")


def in_order(
    function: Callable[[Item], Result], items: Iterable[Item], threads: int | None = None
) -> Iterator[Result]:
    """function(item) for each of `items`, on `threads` threads (Polars' own number by
    default), yielded in the items' order; no more than `threads` items are taken ahead of the
    result last yielded. With one thread, each runs here, one after the other.

    The error raised is the first in the items' order, as one thread would meet it: a
    function's where its result would come, and one of `items` itself (reading the next, say)
    after those of the items taken before it."""
    threads = max(1, pl.thread_pool_size() if threads is None else threads)
    if threads == 1:
        yield from map(function, items)
        return
    with ThreadPoolExecutor(threads) as pool:
        running: deque[Future[Result]] = deque()
        try:
            for item in items:
                running.append(pool.submit(function, item))
                if len(running) == threads:
                    yield running[0].result()
                    running.popleft()
        except Exception:
            for future in running:  # the one that failed first, where it is one of them
                future.result()
            raise
        while running:
            yield running.popleft().result()
