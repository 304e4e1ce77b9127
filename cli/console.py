"""What both programs share on the terminal: a progress bar and one-line errors on stderr."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import typer
from rich.console import Console
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ngsim_graphs.errors import NgsimError

# Lines are never broken by us: a path or a number stays whole on a narrow terminal and in a
# pipe (the terminal wraps what is too long; a pipe gets the line as it is).
stderr = Console(stderr=True, soft_wrap=True)
stdout = Console(soft_wrap=True)


def print_table(table: Table) -> None:
    """A table on stdout at its natural width where the terminal (or a pipe's 80 columns) is
    narrower: rich would squeeze its columns and cut their values ("52…")."""
    natural = Measurement.get(stdout, stdout.options.update(width=10_000), table).maximum
    if natural <= stdout.width:
        stdout.print(table)
    else:  # print() cannot widen the console
        Console(width=natural, force_terminal=stdout.is_terminal).print(table)


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
