"""Both programs' `--version` and `--help`: every help text fits an 80- and a 100-column terminal,
with each option's help beside its name rather than squeezed into a narrow column."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from functools import cache

import pytest
from typer.main import get_command
from typer.testing import CliRunner

import aigem
import ngsim_graphs
from ngsim_cli.aigem import app as aigem_app
from ngsim_cli.ngsim import app as ngsim_app

APPS = {"ngsim-graphs": ngsim_app, "aigem": aigem_app}
MODULES = {"ngsim-graphs": "ngsim_cli.ngsim", "aigem": "ngsim_cli.aigem"}
COMMANDS = [
    (name, command)
    for name, app in APPS.items()
    for command in ["", *sorted(get_command(app).commands)]  # type: ignore[attr-defined]
]
# click's help: an option's names (and metavar) in a column of at most 30 characters, indented by
# 2, then 2 spaces: help text starts at column 34 at the latest when it shares the line.
OPTION_LINE = re.compile(r"^  (-\S.*?)\s{2,}(\S.*)$")
HELP_COLUMN_MAX = 34
SEPARATOR = "=" * 20

# Prints every command's --help, as a terminal of $COLUMNS shows it (typer's CliRunner would fix
# the width at 80, so each width runs in a process of its own).
PRINT_HELPS = """
import sys
from typer.main import get_command
from {module} import app
command = get_command(app)
for name in ["", *sorted(command.commands)]:
    print({separator!r} + name)
    command.main([*([name] if name else []), "--help"], prog_name={program!r}, standalone_mode=False)
"""


@cache
def helps(program: str, columns: int) -> dict[str, str]:
    """command ("" for the program itself) -> its --help text at `columns`."""
    script = PRINT_HELPS.format(module=MODULES[program], separator=SEPARATOR, program=program)
    result = subprocess.run(
        [sys.executable, "-c", script],
        env={**os.environ, "COLUMNS": str(columns)},
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    parts = result.stdout.split(SEPARATOR)[1:]
    return {part.split("\n", 1)[0]: part.split("\n", 1)[1] for part in parts}


@pytest.mark.parametrize(("program", "app", "version"), [
    ("ngsim-graphs", ngsim_app, ngsim_graphs.__version__),
    ("aigem", aigem_app, aigem.__version__),
])  # fmt: skip
def test_version_prints_the_program_and_its_version(program, app, version) -> None:
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.stdout == f"{program} {version}\n"
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)


@pytest.mark.parametrize("columns", [80, 100])
@pytest.mark.parametrize(("program", "command"), COMMANDS)
def test_help_fits_the_terminal_and_keeps_a_wide_help_column(program, command, columns) -> None:
    text = helps(program, columns)[command]
    lines = text.splitlines()
    assert lines[0].startswith(f"Usage: {program} {command}".rstrip())
    too_long = [line for line in lines if len(line) > columns]
    assert not too_long, too_long
    # Options whose help shares the line start it by column 34, leaving the rest of the width.
    starts = [len(line) - len(m.group(2)) for line in lines if (m := OPTION_LINE.match(line))]
    assert starts, f"no option line in {program} {command} --help"
    assert max(starts) <= HELP_COLUMN_MAX, text
    assert "--help" in text


def test_build_help_wraps_at_the_terminal_width_not_a_narrow_column() -> None:
    """The case of the issue: at 100 columns `build --help` wrapped each help into ~25 characters."""
    lines = helps("ngsim-graphs", 100)["build"].splitlines()
    locations = next(i for i, line in enumerate(lines) if line.startswith("  --locations"))
    assert len(lines[locations]) > 90  # the help runs on to the right margin
    assert "NGSIM: us-101, i-80, lankershim, peachtree; highD: highd-N" in " ".join(
        line.strip() for line in lines[locations : locations + 3]
    )
