"""Progress on stderr, one callback for every long command (what, done, total, detail): on a
terminal a bar with the time elapsed and left; elsewhere (a file, a pipe, a job scheduler's log)
plain lines, each after its date and time, one at each stage's end and one every
PLAIN_PROGRESS_INTERVAL_S within a stage, held while the command is young (a quick command that
fails says its one error line alone). progress_line: a line of the command's course written at
once (an epoch's losses). Where the command has a log open (`logs`), the plain lines and the
course's lines go into it too, at once."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Protocol

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from ngsim_cli import console, logs
from ngsim_cli.console import write_stderr
from ngsim_cli.logs import stamped

# Where stderr is not a terminal (a file, a pipe, a job scheduler's log): a plain progress line
# at each stage's end, and within a stage every this many seconds.
PLAIN_PROGRESS_INTERVAL_S = 30.0


class ProgressCallback(Protocol):
    """What is being done (a stage: a new one where it changes), the steps done of its total (0:
    a step without a count), and a detail that changes within the stage (a running loss)."""

    def __call__(self, what: str, done: int, total: int, detail: str = "") -> None: ...


@contextmanager
def progress_bar() -> Iterator[ProgressCallback]:
    """A callback (what, done, total, detail="") drawn as one bar on stderr, with the time
    elapsed and the time left at the recent rate (ETA); where stderr is not a terminal, plain
    lines (PlainProgress), each after its wall-clock time (progress_line). Where the command has
    a log open, its plain lines also go there (never held)."""
    with _on_stderr() as shown:
        if not logs.logging():
            yield shown
            return
        logged = PlainProgress(logs.log_line, PLAIN_PROGRESS_INTERVAL_S)

        def both(what: str, done: int, total: int, detail: str = "") -> None:
            shown(what, done, total, detail)
            logged(what, done, total, detail)

        yield both


@contextmanager
def _on_stderr() -> Iterator[ProgressCallback]:
    """The progress on stderr alone: a bar on a terminal, else plain lines held while young."""
    if not console.stderr.is_terminal:
        with _lines_held(PLAIN_PROGRESS_INTERVAL_S) as held:
            yield PlainProgress(held.write, PLAIN_PROGRESS_INTERVAL_S)
        return
    columns = (
        TextColumn("{task.description:<40}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console.stderr, transient=True) as bar:
        task = bar.add_task("starting", total=None)
        totals: list[int] = []

        def update(what: str, done: int, total: int, detail: str = "") -> None:
            described = f"{what} {detail}" if detail else what
            if totals != [total]:  # a new count (or a resumed run's first): a new rate, no jump
                totals[:] = [total]
                bar.reset(task, total=total, completed=done, description=described)
            bar.update(task, description=described, completed=done, total=total)

        yield update


def progress_line(line: str) -> None:
    """A line of a command's course on stderr that is written at once (an epoch's losses: its
    checkpoint is kept): where stderr is not a terminal (a log), after the wall-clock time
    (logs.TIMESTAMP) and after the progress lines held before it (_HeldLines); on a terminal, as
    it is (the bar shows the times). Also into the command's log."""
    logs.log_line(line)
    if console.stderr.is_terminal:
        write_stderr(line)
        return
    if _HELD:
        _HELD[-1].flush()
    write_stderr(stamped(line))


class _HeldLines:
    """A log's progress lines while its command is young, each after the time it was made: kept
    in order until the command has run `hold_s` (they are written then, and each later line at
    once), a line written at once comes (progress_line), or the progress ends well. An error or
    an interrupt before that drops them: a quick command that fails says its one error line
    alone, and a command that runs longer logs every line it made."""

    def __init__(self, hold_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.until_s, self.clock = clock() + hold_s, clock
        self.lines: list[str] | None = []  # None: written at once from now on

    def write(self, line: str) -> None:
        if self.lines is not None and self.clock() < self.until_s:
            self.lines.append(stamped(line))
            return
        self.flush()
        write_stderr(stamped(line))

    def flush(self) -> None:
        for line in self.lines or []:
            write_stderr(line)
        self.lines = None


_HELD: list[_HeldLines] = []  # the running progress_bar's held lines (innermost last)


@contextmanager
def _lines_held(hold_s: float) -> Iterator[_HeldLines]:
    """Progress lines held in the block (_HeldLines): written where it ends well or once it has
    run `hold_s`, dropped where it ends on an error or an interrupt before that."""
    held = _HeldLines(hold_s)
    _HELD.append(held)
    try:
        yield held
    except BaseException:
        held.lines = None  # dropped: the error's line is the command's one line
        raise
    else:
        held.flush()
    finally:
        _HELD.pop()


class PlainProgress:
    """The progress bar as plain lines, `what: done/total (share), elapsed, about T left; detail`:
    one at the end of each stage (done reaching its total, once: another call at its end, with
    another detail, writes nothing) and, within a stage, one once `interval_s` seconds have
    passed since the last line. A stage starts where `what` or the total changes, or where the
    count goes back; its elapsed time is its own, its time left at its average rate so far. No
    line repeats the count of the line before. A stage's start says nothing: a command that
    stops on an error in its first stage prints its error line alone."""

    def __init__(
        self,
        write: Callable[[str], None],
        interval_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.write, self.interval_s, self.clock = write, interval_s, clock
        self.what: str | None = None
        self.total: int | None = None
        self.done = 0
        self.started_s, self.started_done = 0.0, 0
        self.written_s = clock()
        self.written: tuple[str, int, int] | None = None  # the last line's count
        self.ended = False  # the stage's end has been reached

    def __call__(self, what: str, done: int, total: int, detail: str = "") -> None:
        now = self.clock()
        started = what != self.what or total != self.total or done < self.done
        if started:
            self.what, self.total, self.started_s, self.started_done = what, total, now, done
            self.ended = False
        self.done = done
        ending = 0 < total <= done and not self.ended
        due = now - self.written_s >= self.interval_s
        if (ending or due) and self.written != (what, done, total):
            self.write(self._line(what, done, total, now, detail))
            self.written_s, self.written = now, (what, done, total)
        self.ended = self.ended or ending

    def _line(self, what: str, done: int, total: int, now: float, detail: str) -> str:
        if total <= 0:  # a step without a count
            return f"{what}; {detail}" if detail else what
        elapsed_s = now - self.started_s
        line = f"{what}: {done:,}/{total:,} ({done / total:.0%}), {_clock_time(elapsed_s)} elapsed"
        steps = done - self.started_done
        if done < total and steps > 0 and elapsed_s > 0:
            line += f", about {_clock_time((total - done) * elapsed_s / steps)} left"
        return f"{line}; {detail}" if detail else line


def _clock_time(seconds: float) -> str:
    """'0:01:05' for 65 s, as the bar shows its times."""
    whole = round(seconds)
    return f"{whole // 3600}:{whole % 3600 // 60:02d}:{whole % 60:02d}"
