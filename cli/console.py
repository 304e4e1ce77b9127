"""How both programs write on the terminal: the two consoles (lines never broken by us), one line
on stderr (a warning, an error, a note; also into the command's log where one is open:
`logs`), a table on stdout at its natural width, a count in words. What a line says of progress
is `progress`'s; how a command ends on an error, `exits`'."""

from __future__ import annotations

from collections.abc import Callable

from rich.console import Console
from rich.measure import Measurement
from rich.table import Table

# Lines are never broken by us: a path or a number stays whole on a narrow terminal and in a
# pipe (the terminal wraps what is too long; a pipe gets the line as it is).
stderr = Console(stderr=True, soft_wrap=True)
stdout = Console(soft_wrap=True)


# Where each line of print_line also goes: the open log of the command (logs.command_log).
line_sinks: list[Callable[[str], None]] = []


def write_stderr(line: str) -> None:
    """One line on stderr alone, never wrapped or marked up (a progress line: a log has its own)."""
    stderr.print(line, markup=False, highlight=False, soft_wrap=True)


def print_line(line: str) -> None:
    """One line on stderr, never wrapped or marked up; also into the command's log (line_sinks)."""
    write_stderr(line)
    for sink in line_sinks:
        sink(line)


def print_warning(message: str) -> None:
    """One line `warning: ...` on stderr, never wrapped or marked up."""
    print_line(f"warning: {message}")


def print_error(message: str) -> None:
    """One line `error: ...` on stderr, never wrapped or marked up."""
    print_line(f"error: {message}")


def print_table(table: Table) -> None:
    """A table on stdout at its natural width where the terminal (or a pipe's 80 columns) is
    narrower: rich would squeeze its columns and cut their values ("52…")."""
    natural = Measurement.get(stdout, stdout.options.update(width=10_000), table).maximum
    if natural <= stdout.width:
        stdout.print(table)
    else:  # print() cannot widen the console
        Console(width=natural, force_terminal=stdout.is_terminal).print(table)


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """'1 epoch', '2 epochs', '1,024 rows': a count and its noun, singular for one."""
    return f"{count:,} {noun if count == 1 else plural or noun + 's'}"
