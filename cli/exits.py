"""How a command ends on an error or a signal: the project's errors and OS errors as one line on
stderr and exit status 1 (exit_on_error), Ctrl-C and SIGTERM as one line and 130 or 143
(exit_on_interrupt), a device PyTorch cannot use here as one line as soon as PyTorch has loaded
(check_device)."""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

import typer

from ngsim_cli.console import print_error, print_line
from ngsim_graphs.errors import NgsimError
from ngsim_graphs.interrupts import HELD_SIGNALS


def check_device(device: str) -> None:
    """Exit 1 with one line where `device` is one PyTorch cannot use here (--device cuda without
    CUDA), as soon as PyTorch is loaded (seconds), before the model, the data and PyTorch
    Geometric load (seconds more)."""
    from aigem.devices import DeviceUnavailableError, pick_device

    try:
        pick_device(device)
    except DeviceUnavailableError as err:
        print_error(str(err))
        raise typer.Exit(1) from None


@contextmanager
def exit_on_error() -> Iterator[None]:
    """Turn the project's errors, and any OS error (a full disk, a permission), into one line on
    stderr naming the file, and exit status 1. Inside `exit_on_interrupt`, once a signal has
    come, the error is left to it: an interrupt that a library turned into an error of its own."""
    try:
        yield
    except (NgsimError, OSError) as err:
        if any(_SIGNALS_CAME):
            raise
        if isinstance(err, NgsimError):
            print_error(str(err))
        else:
            where = f"{err.filename}: " if err.filename else ""
            print_error(f"{where}{err.strerror or err}")
        raise typer.Exit(1) from None


# The signals that came in each running `exit_on_interrupt` block (innermost last).
_SIGNALS_CAME: list[list[int]] = []


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as an interrupt is: whatever a program writes is cleaned up on it as on
    Ctrl-C."""


@contextmanager
def exit_on_interrupt(left: str | Callable[[], str]) -> Iterator[None]:
    """Turn Ctrl-C (SIGINT) and SIGTERM in the block into one line on stderr, `interrupted;
    LEFT` (`terminated; LEFT`), and exit status 130 (143), the shells' 128 + the signal. `left`
    says what the interrupted work leaves, e.g. `nothing written (OUT is as it was)`; a function
    gives it when the signal comes (what is left depends on how far the work got).

    The work cleans up as it unwinds; the worker processes of a build never see the Ctrl-C
    that a terminal sends to them too (`ngsim_graphs.engine.workers`). An interrupt that lands in a
    library's callback may come out as the library's own error (Polars reports the
    KeyboardInterrupt as "Exception ignored" and raises a TypeError): once a signal has come,
    the error that ends the block is the interrupt, and Python's report of the ignored
    KeyboardInterrupt is not printed.
    """
    came: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        came.append(signum)
        raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt

    in_main = threading.current_thread() is threading.main_thread()
    handlers = {signum: signal.getsignal(signum) for signum in HELD_SIGNALS} if in_main else {}
    for signum, handler in handlers.items():
        if handler is not signal.SIG_IGN:  # `nohup`, a shell's background job: left ignored
            signal.signal(signum, on_signal)
    report_unraisable = sys.unraisablehook

    def unraisable(info: sys.UnraisableHookArgs) -> None:
        if not isinstance(info.exc_value, KeyboardInterrupt):
            report_unraisable(info)

    sys.unraisablehook = unraisable
    _SIGNALS_CAME.append(came)
    try:
        yield
    except (typer.Exit, SystemExit):
        raise
    except BaseException as err:
        if not came and not isinstance(err, KeyboardInterrupt):
            raise
        terminated = came[:1] == [signal.SIGTERM] or isinstance(err, Terminated)
        what = "terminated" if terminated else "interrupted"
        said = left() if callable(left) else left
        print_line(f"{what}; {said}")
        raise typer.Exit(128 + (signal.SIGTERM if terminated else signal.SIGINT)) from None
    finally:
        _SIGNALS_CAME.pop()  # this block's: the blocks nest
        sys.unraisablehook = report_unraisable
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
