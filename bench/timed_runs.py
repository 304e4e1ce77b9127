"""A program run in a process of its own, its output read as it comes: how long it took to end
after its last line, and how long its output stayed open after that (a process it started and
left running holds it open). bench/bench_exit.py measures the commands against EXIT_S with it;
the tests hold them to LINGER_S (tests/test_cli_exit.py, tests/test_aigem_paper.py)."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

EXIT_S = 5.0  # the target: a command ends within this long of its last line (bench_exit.py)
# What a test holds a command to: a timing, so far above the target that a busy machine passes,
# and far below what something a command leaves behind holds it (Inductor's compile workers wait
# up to 300 s to shut down; a worker process left running holds the output open).
LINGER_S = 30.0
# The programs as their installed scripts run them (pyproject.toml), with their own names.
AIGEM = "import sys; from ngsim_cli.entry import aigem; sys.argv[0] = 'aigem'; aigem()"
NGSIM_GRAPHS = (
    "import sys; from ngsim_cli.entry import ngsim_graphs; sys.argv[0] = 'ngsim-graphs'; "
    "ngsim_graphs()"
)


def ngsim_graphs(*args: object) -> list[str]:
    """The command line of `ngsim-graphs ARGS` as its installed script runs it."""
    return [sys.executable, "-c", NGSIM_GRAPHS, *map(str, args)]


def aigem(*args: object) -> list[str]:
    """The command line of `aigem ARGS` as its installed script runs it."""
    return [sys.executable, "-c", AIGEM, *map(str, args)]


@dataclass(frozen=True)
class TimedRun:
    returncode: int
    stdout: str
    stderr: str
    after_last_line_s: float  # from the last output read to the program's end
    open_after_end_s: float  # from the program's end to its output's end; inf: still open

    def ended_within(self, seconds: float) -> bool:
        """Whether it ended, and its output with it, within `seconds` of its last line."""
        return self.after_last_line_s < seconds and self.open_after_end_s < seconds


def run_timed(argv: list[str], stop_on: str | None = None, timeout_s: float = 300.0) -> TimedRun:
    """Run `argv`, reading stdout and stderr as they come (stamped to 20 ms); with `stop_on`,
    send it SIGTERM once its output holds that text. Killed past `timeout_s`."""
    program = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert program.stdout is not None and program.stderr is not None
    out, err = program.stdout.fileno(), program.stderr.fileno()
    texts = {out: bytearray(), err: bytearray()}
    selector = selectors.DefaultSelector()
    for stream in (program.stdout, program.stderr):
        selector.register(stream, selectors.EVENT_READ)
    start = last = time.monotonic()
    ended: float | None = None
    stopped = stop_on is None
    while selector.get_map():
        for key, _ in selector.select(timeout=0.02):
            chunk = os.read(key.fd, 1 << 16)
            if not chunk:
                selector.unregister(key.fileobj)
                continue
            texts[key.fd] += chunk
            last = time.monotonic()
            if not stopped and stop_on is not None and stop_on.encode() in texts[key.fd]:
                program.send_signal(signal.SIGTERM)
                stopped = True
        now = time.monotonic()
        if ended is None and program.poll() is not None:
            ended = now
        if ended is not None and now - ended > LINGER_S:  # held open by what it left
            break
        if ended is None and now - start > timeout_s:
            program.kill()
    if ended is None:  # its output closed before it ended
        program.wait()
        ended = time.monotonic()
    closed = time.monotonic() if not selector.get_map() else None
    selector.close()
    program.stdout.close()
    program.stderr.close()
    return TimedRun(
        program.returncode,
        texts[out].decode(errors="replace"),
        texts[err].decode(errors="replace"),
        max(0.0, ended - last),
        float("inf") if closed is None else max(0.0, closed - ended),
    )
