"""What both programs share on the terminal: a progress bar, one-line errors on stderr, and
one line for an interrupt."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

import typer
from rich.console import Console
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ngsim_graphs.errors import NgsimError

stderr = Console(stderr=True)
stdout = Console()


def print_table(table: Table) -> None:
    """A table on stdout; piped or redirected, at its natural width rather than cut to 80 columns."""
    if stdout.is_terminal:
        stdout.print(table)
    else:
        natural = Measurement.get(stdout, stdout.options.update(width=10_000), table).maximum
        Console(width=max(stdout.width, natural)).print(table)  # print() cannot widen the console


@contextmanager
def progress_bar() -> Iterator[Callable[[str, int, int], None]]:
    """A callback (what, done, total) drawn as one bar on stderr; silent unless it is a terminal."""
    if not stderr.is_terminal:
        yield lambda _what, _done, _total: None
        return
    columns = (
        TextColumn("{task.description:<40}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=stderr, transient=True) as bar:
        task = bar.add_task("starting", total=None)

        def update(what: str, done: int, total: int) -> None:
            bar.update(task, description=what, completed=done, total=total)

        yield update


# Help as plain text wrapped to the terminal, up to 100 columns: the boxed tables of rich's help
# squeeze an option's help into a narrow column next to its names and types.
HELP_SETTINGS = {"rich_markup_mode": None, "context_settings": {"max_content_width": 100}}


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


def print_error(message: str) -> None:
    """One line `error: ...` on stderr, never wrapped or marked up."""
    stderr.print(f"error: {message}", markup=False, highlight=False, soft_wrap=True)


@contextmanager
def exit_on_error() -> Iterator[None]:
    """Turn the project's errors, and any OS error (a full disk, a permission), into one line on
    stderr naming the file, and exit status 1."""
    try:
        yield
    except NgsimError as err:
        print_error(str(err))
        raise typer.Exit(1) from None
    except OSError as err:
        where = f"{err.filename}: " if err.filename else ""
        print_error(f"{where}{err.strerror or err}")
        raise typer.Exit(1) from None


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as an interrupt is: whatever a program writes is cleaned up on it as on
    Ctrl-C."""


def _terminated(_signum: int, _frame: FrameType | None) -> None:
    raise Terminated


@contextmanager
def exit_on_interrupt(left: str) -> Iterator[None]:
    """Turn Ctrl-C (SIGINT) and SIGTERM in the block into one line on stderr, `interrupted;
    LEFT` (`terminated; LEFT`), and exit status 130 (143), the shells' 128 + the signal. `left`
    says what the interrupted work leaves, e.g. `nothing written (OUT is as it was)`.

    The work cleans up as it unwinds; the worker processes of a build never see the Ctrl-C
    that a terminal sends to them too (`ngsim_graphs.workers`).
    """
    in_main = threading.current_thread() is threading.main_thread()
    before = signal.signal(signal.SIGTERM, _terminated) if in_main else None
    try:
        yield
    except KeyboardInterrupt as err:
        terminated = isinstance(err, Terminated)
        what = "terminated" if terminated else "interrupted"
        stderr.print(f"{what}; {left}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(128 + (signal.SIGTERM if terminated else signal.SIGINT)) from None
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, before)
