"""What both programs share on the terminal: a progress bar (plain lines where stderr is not a
terminal), one-line errors on stderr, and one line for an interrupt."""

from __future__ import annotations

import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from types import FrameType
from typing import Any, Protocol

import typer
from rich.console import Console
from rich.measure import Measurement
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table
from typer.core import TyperGroup

from ngsim_graphs.errors import NgsimError
from ngsim_graphs.interrupts import HELD_SIGNALS

# Lines are never broken by us: a path or a number stays whole on a narrow terminal and in a
# pipe (the terminal wraps what is too long; a pipe gets the line as it is).
stderr = Console(stderr=True, soft_wrap=True)
stdout = Console(soft_wrap=True)


def usage_error(message: str) -> typer.Exit:
    """One line on stderr; the caller raises the returned exit (status 2: a bad option)."""
    stderr.print(f"error: {message}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(2)


def shown_text(text: str) -> str:
    """`text` as it can be printed: the bytes of a name that is not UTF-8 (which Python passes
    on as lone surrogates) as escapes, 'lat\\xe9'."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


class TextArguments(TyperGroup):
    """A program's commands, whose arguments must be UTF-8 text: a path named in another
    encoding cannot be opened by Polars nor recorded in a manifest or a run's JSON, so it is one
    line and exit status 2 before any command runs, not a traceback halfway through one."""

    def parse_args(self, ctx: typer.Context, args: list[str]) -> list[str]:
        for arg in args:
            if shown_text(arg) != arg:
                raise usage_error(
                    f"the argument {shown_text(arg)} is not UTF-8 text: builds and runs record "
                    "their paths as text; rename it in UTF-8"
                )
        return super().parse_args(ctx, args)


def print_table(table: Table) -> None:
    """A table on stdout at its natural width where the terminal (or a pipe's 80 columns) is
    narrower: rich would squeeze its columns and cut their values ("52…")."""
    natural = Measurement.get(stdout, stdout.options.update(width=10_000), table).maximum
    if natural <= stdout.width:
        stdout.print(table)
    else:  # print() cannot widen the console
        Console(width=natural, force_terminal=stdout.is_terminal).print(table)


# Where stderr is not a terminal (a file, a pipe, a job scheduler's log): a plain progress line
# at each stage's end, and within a stage every this many seconds.
PLAIN_PROGRESS_INTERVAL_S = 30.0
TIMESTAMP = "%Y-%m-%d %H:%M:%S"  # before each line of a command's course in a log (progress_line)


class ProgressCallback(Protocol):
    """What is being done (a stage: a new one where it changes), the steps done of its total (0:
    a step without a count), and a detail that changes within the stage (a running loss)."""

    def __call__(self, what: str, done: int, total: int, detail: str = "") -> None: ...


@contextmanager
def progress_bar() -> Iterator[ProgressCallback]:
    """A callback (what, done, total, detail="") drawn as one bar on stderr, with the time
    elapsed and the time left at the recent rate (ETA); where stderr is not a terminal, plain
    lines (PlainProgress), each after its wall-clock time (progress_line)."""
    if not stderr.is_terminal:
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
    with Progress(*columns, console=stderr, transient=True) as bar:
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
    (TIMESTAMP) and after the progress lines held before it (_HeldLines); on a terminal, as it
    is (the bar shows the times)."""
    if stderr.is_terminal:
        _write_line(line)
        return
    if _HELD:
        _HELD[-1].flush()
    _write_line(_stamped(line))


def _stamped(line: str) -> str:
    return f"{time.strftime(TIMESTAMP)} {line}"


def _write_line(line: str) -> None:
    stderr.print(line, markup=False, highlight=False, soft_wrap=True)


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
            self.lines.append(_stamped(line))
            return
        self.flush()
        _write_line(_stamped(line))

    def flush(self) -> None:
        for line in self.lines or []:
            _write_line(line)
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


# Help as plain text wrapped to the terminal, up to 100 columns: the boxed tables of rich's help
# squeeze an option's help into a narrow column next to its names and types.
HELP_SETTINGS = {"rich_markup_mode": None, "context_settings": {"max_content_width": 100}}


def naming_the_other_program(program: str, module: str) -> type[TyperGroup]:
    """A command group of UTF-8 arguments (`TextArguments`) that answers a command of the other
    program (`program`, whose typer app is `module`'s `app`) with where it is: `aigem show` ->
    "No such command 'show': it is `ngsim-graphs show`". The other program is loaded only then."""

    class Group(TextArguments):
        def resolve_command(
            self, ctx: typer.Context, args: list[str]
        ) -> tuple[str | None, Any, list[str]]:
            name = args[0] if args else None
            if name and self.get_command(ctx, name) is None and name in _commands_of(module):
                ctx.fail(f"No such command {name!r}: it is `{program} {name}`.")
            return super().resolve_command(ctx, args)

    return Group


def _commands_of(module: str) -> list[str]:
    """The command names of `module`'s typer app."""
    import importlib

    app = importlib.import_module(module).app
    return [
        info.name or info.callback.__name__.replace("_", "-") for info in app.registered_commands
    ]


def add_version_option(app: typer.Typer, program: str, version: str) -> None:
    """Give `app` an eager `--version` that prints `program version` and exits 0."""

    def show(value: bool) -> None:
        if value:
            stdout.print(f"{program} {version}", markup=False, highlight=False)
            raise typer.Exit(0)

    # A default, not an Annotated hint: the hint would name `show`, a local that typer cannot see
    # when it evaluates the (postponed) annotations.
    def options(
        version: bool = typer.Option(
            False,
            "--version",
            help="Print the program's version and exit.",
            callback=show,
            is_eager=True,
        ),
    ) -> None:
        pass

    options.__doc__ = app.info.help
    app.callback()(options)


def option_names(fields: Iterable[str], renamed: Mapping[str, str] | None = None) -> dict[str, str]:
    """Each config field's option: `--` and the field with hyphens (batch_size -> --batch-size),
    unless `renamed` says otherwise (patience_epochs -> --patience)."""
    renamed = renamed or {}
    return {field: renamed.get(field, "--" + field.replace("_", "-")) for field in fields}


def in_option_words(message: str, options: Mapping[str, str]) -> str:
    """A config's error as the command line says it: each field of `options` replaced by its
    option ("batch_size must be >= 1" -> "--batch-size must be >= 1"). A field with an underscore
    is replaced wherever it stands; a field of one word (epochs, split, seed) is also a plain
    word, so only where a setting is named: before " must ", or before its value and "->", ","
    or ":" ("seed 3 -> 4", "split time, ...")."""
    joined = sorted((name for name in options if "_" in name), key=len, reverse=True)
    single = [name for name in options if "_" not in name]
    words = lambda names: r"(?<![\w-])(" + "|".join(map(re.escape, names)) + r")\b"
    patterns = [words(joined)] if joined else []
    if single:
        patterns.append(words(single) + r"(?= must | \S+ -> | [^\s,:]+[,:])")
    if not patterns:
        return message
    return re.sub("|".join(patterns), lambda m: options[m.group(1) or m.group(2)], message)


@contextmanager
def option_values(options: Mapping[str, str] | None = None) -> Iterator[None]:
    """A value the block refuses (a config's ValueError, or ngsim_graphs.config's checks) as one
    line naming the option (in_option_words: `options` maps each field to its option) and exit
    status 2. Every option's range is checked so, never by typer's `min=`, whose error is a box
    of four lines."""
    try:
        yield
    except ValueError as err:
        raise usage_error(in_option_words(str(err), options or {})) from None


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """'1 epoch', '2 epochs', '1,024 rows': a count and its noun, singular for one."""
    return f"{count:,} {noun if count == 1 else plural or noun + 's'}"


def print_warning(message: str) -> None:
    """One line `warning: ...` on stderr, never wrapped or marked up."""
    stderr.print(f"warning: {message}", markup=False, highlight=False, soft_wrap=True)


def print_error(message: str) -> None:
    """One line `error: ...` on stderr, never wrapped or marked up."""
    stderr.print(f"error: {message}", markup=False, highlight=False, soft_wrap=True)


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
        stderr.print(f"{what}; {said}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(128 + (signal.SIGTERM if terminated else signal.SIGINT)) from None
    finally:
        _SIGNALS_CAME.pop()  # this block's: the blocks nest
        sys.unraisablehook = report_unraisable
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
