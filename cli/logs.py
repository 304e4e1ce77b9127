"""The log file of a long command: `ngsim-graphs build` (BUILD/build.log), `aigem fit`
(RUN/fit.log) and `aigem paper` (PAPER/paper.log), each path its folder's module's
(ngsim_graphs.layout, aigem.runs.records, aigem.paper.folder).

Every line the command writes on stderr goes also into its log, after its date and time
(TIMESTAMP): warnings, the error or interrupt line that ends it, each epoch's line, and its
progress in the plain form that stderr has off a terminal (progress.PlainProgress: a line at each
stage's end and one every PLAIN_PROGRESS_INTERVAL_S within a stage), never held back as stderr's
are while a command is young.

A log is appended to, never replaced (a resumed fit or a continued paper goes on in the same
log), and never written through a link. It is opened once its folder is the command's (`ready`,
or `settle`: a build that landed, a fit that trains, a paper folder with its paper.json); the
lines before are kept until then, and dropped where the command ends first: a refused or failed
call writes nothing into a folder it did not take. A log that cannot be written is one warning
on stderr, and the command goes on without it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ngsim_cli import console

TIMESTAMP = "%Y-%m-%d %H:%M:%S"  # before each line of a log, and of stderr off a terminal


def stamped(line: str) -> str:
    """`line` after the wall-clock time: '2026-11-28 14:03:07 epoch 1: ...'."""
    return f"{time.strftime(TIMESTAMP)} {line}"


class CommandLog:
    """A log file that lines are appended to once `ready()` (each after the time it was made);
    the lines before are kept until then."""

    def __init__(self, path: Path, ready: Callable[[], bool]) -> None:
        self.path, self.ready = path, ready
        self.kept: list[str] = []  # stamped lines not yet written
        self.fd: int | None = None
        self.failed = False

    def write(self, line: str) -> None:
        if not self.failed:
            self.kept.append(stamped(line))
            self.flush()

    def settle(self) -> None:
        """The folder is the command's from now on (a build that landed, a fit that trains):
        write what was kept, and each line from now on."""
        if self.fd is None:
            self.ready = lambda: True
            self.flush()

    def flush(self) -> None:
        """Append the kept lines, once the folder is ready (the file opened at the first)."""
        if self.failed or not self.kept or (self.fd is None and not self.ready()):
            return
        text, self.kept = "".join(f"{line}\n" for line in self.kept), []
        try:
            if self.fd is None:
                flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
                self.fd = os.open(self.path, flags, 0o644)
            os.write(self.fd, text.encode("utf-8", "backslashreplace"))
        except OSError as err:
            self.failed = True  # before the warning: it is no line of this log
            console.print_warning(f"{self.path}: {err.strerror or err}; no log is written")

    def close(self) -> None:
        """Write what is left where the folder is ready; what never was ready is dropped."""
        try:
            self.flush()
        finally:
            if self.fd is not None:
                os.close(self.fd)
                self.fd = None


_OPEN: list[CommandLog] = []  # the running command's log (none, or one)


def log_line(line: str) -> None:
    """`line` into the command's open log, if any (not on stderr)."""
    for log in _OPEN:
        log.write(line)


def logging() -> bool:
    """Whether the running command has a log open."""
    return bool(_OPEN)


@contextmanager
def command_log(path: Path, ready: Callable[[], bool] = lambda: True) -> Iterator[CommandLog]:
    """In the block, every line on stderr (console.print_line), every progress line and epoch
    line also into the log `path`, once `ready()`; closed at the block's end."""
    log = CommandLog(path, ready)
    _OPEN.append(log)
    console.line_sinks.append(log.write)
    try:
        yield log
    finally:
        console.line_sinks.remove(log.write)
        _OPEN.remove(log)
        log.close()
