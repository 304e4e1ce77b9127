"""Ctrl-C and SIGTERM around what must not stop halfway, and around starting worker processes.

In the programs, Ctrl-C (SIGINT) and SIGTERM raise KeyboardInterrupt in the main thread (the
command line turns SIGTERM into one), and every writer cleans up on it as on any failure. Two
places need more: a swap of finished output (two renames) must not stop between them, and a
worker process must not take a Ctrl-C meant for its parent (a terminal sends it to the whole
foreground process group, workers included, even while their interpreter starts): the parent
stops them itself.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def interrupts_held() -> Iterator[list[int]]:
    """Hold the Python handlers of SIGINT and SIGTERM off for the block; yields the signals that
    came meanwhile. The block runs to its end: use it only for what is short and leaves a
    finished output (the caller may act on the signals after it). Only the main thread runs
    signal handlers: elsewhere nothing changes.
    """
    came: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield came
        return

    def note(signum: int, _frame: FrameType | None) -> None:
        came.append(signum)

    handlers = {signum: signal.getsignal(signum) for signum in HELD_SIGNALS}
    held = [signum for signum, handler in handlers.items() if callable(handler)]
    for signum in held:
        signal.signal(signum, note)
    try:
        yield came
    finally:
        for signum in held:
            signal.signal(signum, handlers[signum])


@contextmanager
def children_deaf_to_ctrl_c() -> Iterator[None]:
    """Block SIGINT in this thread for the block, so that the processes started from it, and
    from threads it starts meanwhile, start with SIGINT blocked: a signal mask is inherited
    across fork and exec, and Python does not unblock it at start-up, so a worker never sees a
    Ctrl-C (its parent stops it).

    Another thread of this process may still take the SIGINT, and Python then runs its handler
    in the main thread: the handlers are held off too (`interrupts_held`), and a signal that came
    is raised again once the block ends, also where it ended in an error. A KeyboardInterrupt
    between starting a process and handing it its work had left the process to die with a
    traceback of its own.
    """
    if not hasattr(signal, "pthread_sigmask"):  # not POSIX: nothing to inherit
        yield
        return
    came: list[int] = []
    try:
        with interrupts_held() as came:
            before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                yield
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)
    finally:  # also after an error in the block: the interrupt is what the user asked for
        for signum in came:
            signal.raise_signal(signum)
