"""Ctrl-C and SIGTERM held off around a swap, and blocked in the processes started meanwhile."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest

from ngsim_graphs.interrupts import children_deaf_to_ctrl_c, interrupts_held

SHOW_MASK = (
    "import signal; print(sorted(int(s) for s in signal.pthread_sigmask(signal.SIG_BLOCK, [])))"
)


def test_held_interrupts_let_the_block_end_and_are_told() -> None:
    terminated: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, _frame: terminated.append(signum))
    try:
        steps = []
        with interrupts_held() as came:
            os.kill(os.getpid(), signal.SIGINT)
            steps.append("after Ctrl-C")
            os.kill(os.getpid(), signal.SIGTERM)
            steps.append("after SIGTERM")
        assert steps == ["after Ctrl-C", "after SIGTERM"]
        assert came == [signal.SIGINT, signal.SIGTERM]
        assert terminated == []  # the handler was held off, and is back
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_held_interrupts_outside_the_main_thread_change_nothing() -> None:
    seen = []

    def run() -> None:
        with interrupts_held() as came:
            seen.append((came, signal.getsignal(signal.SIGINT)))

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert seen == [([], signal.default_int_handler)]


def test_processes_started_meanwhile_start_with_ctrl_c_blocked() -> None:
    def mask() -> str:
        return subprocess.run(
            [sys.executable, "-c", SHOW_MASK], capture_output=True, text=True, check=True
        ).stdout.strip()

    assert mask() == "[]"
    with children_deaf_to_ctrl_c():
        assert mask() == f"[{int(signal.SIGINT)}]"  # Python keeps it blocked as it starts
    assert mask() == "[]"
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def test_a_ctrl_c_another_thread_takes_comes_once_the_block_has_ended() -> None:
    """The SIGINT a terminal sends goes to any thread that has it unblocked (Polars' threads):
    Python's handler, in the main thread, waits for the end of the block, where processes are
    started and handed their work."""
    go = threading.Event()
    other = threading.Thread(target=lambda: go.wait() and signal.raise_signal(signal.SIGINT))
    other.start()  # before the block: its SIGINT is not blocked
    steps = []
    with pytest.raises(KeyboardInterrupt), children_deaf_to_ctrl_c():
        go.set()
        other.join()
        steps.extend(range(1000))  # where Python would run the handler
        steps.append("end of the block")
    assert steps[-1] == "end of the block"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_held_while_the_block_failed_is_not_lost() -> None:
    go = threading.Event()
    other = threading.Thread(target=lambda: go.wait() and signal.raise_signal(signal.SIGINT))
    other.start()
    with pytest.raises(KeyboardInterrupt), children_deaf_to_ctrl_c():
        go.set()
        other.join()
        raise OSError("a worker could not be started")
