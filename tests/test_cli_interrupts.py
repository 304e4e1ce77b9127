"""Ctrl-C, SIGTERM and kill -9 of `ngsim-graphs`, as a user's terminal sends them, through the
installed entry point in a process of its own: one line saying what was left, exit status 130
(143), no traceback from any process, no worker left running, and the output as it was."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ngsim_cli import entry
from ngsim_cli.ngsim import app
from ngsim_graphs import lock
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.synth.formats import write_synthetic

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

# What the installed script runs (pyproject.toml), with the program's own name.
PROGRAM = "import sys; from ngsim_cli.entry import ngsim_graphs; sys.argv[0] = 'ngsim-graphs'; ngsim_graphs()"
Moment = Callable[[int, Path], bool]  # (the program's pid, its --out) -> whether it is there


def test_the_installed_program_is_the_entry_point_tested_here() -> None:
    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert pyproject["project"]["scripts"]["ngsim-graphs"] == "ngsim_cli.entry:ngsim_graphs"


def files(root: Path) -> dict[str, bytes]:
    if not root.exists():
        return {}
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def children(pid: int) -> list[int]:
    """The processes whose parent is `pid` (workers, multiprocessing's resource tracker)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def gone_within(pids: list[int], seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.02)
    return not any(alive(pid) for pid in pids)


def loading(pid: int, _out: Path) -> bool:
    """Importing its modules: Polars' library is mapped, the command has not started."""
    return "polars" in Path(f"/proc/{pid}/maps").read_text()


def started(_pid: int, out: Path) -> bool:
    return lock.lock_path(out).exists()


def found(folder: Path, pattern: str) -> bool:
    """Whether a path under `folder` matches `pattern` (glob; `**` for any depth) now, while the
    program writes: a folder it removes while it is looked into is not there."""
    try:
        return any(folder.glob(pattern))
    except FileNotFoundError:
        return False


def staged(pattern: str) -> Moment:
    def there(_pid: int, out: Path) -> bool:
        return found(out.parent, f".{out.name}.partial-*/_staging/{pattern}")

    return there


READING = staged("_read-*/*")  # a file's rows parsed into scratch files
CLEANING = staged("*/tracks-*.arrow")  # a part of a recording's tracks made


def run_until(arguments: list[str], moment: Moment, out: Path) -> tuple[subprocess.Popen, list]:
    """`ngsim-graphs ARGUMENTS` in a process group of its own, stopped at `moment`; with the
    processes it has started by then."""
    program = subprocess.Popen(
        [sys.executable, "-c", PROGRAM, *arguments],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.monotonic() + 120
    try:
        while not moment(program.pid, out):
            assert program.poll() is None, f"it ended before the moment: {program.stderr.read()}"
            assert time.monotonic() < deadline, "the moment never came"
            time.sleep(0.002)
    except BaseException:
        program.kill()
        program.communicate()
        raise
    return program, children(program.pid)


def finish(program: subprocess.Popen) -> list[str]:
    """The lines of its stderr once it has ended (within a minute, or it is killed)."""
    try:
        _, stderr = program.communicate(timeout=60)
    finally:
        if program.poll() is None:
            os.killpg(program.pid, signal.SIGKILL)
    return stderr.splitlines()


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two recordings of two minutes: a build of a few seconds with two jobs."""
    folder = tmp_path_factory.mktemp("interrupts") / "raw"
    write_synthetic(folder, SynthConfig(raw_format=RawFormat.TXT, recordings=2, minutes=2, seed=5))
    return folder


@pytest.fixture(scope="module")
def earlier(raw: Path) -> Path:
    """A finished build of `raw`, which each test's --out starts as."""
    out = raw.parent / "earlier"
    result = CliRunner().invoke(app, ["build", str(raw), "--out", str(out), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture
def out(earlier: Path, tmp_path: Path) -> Path:
    shutil.copytree(earlier, tmp_path / "out")
    return tmp_path / "out"


def build(raw: Path, out: Path) -> list[str]:
    return ["build", str(raw), "--out", str(out), "--overwrite", "--jobs", "2"]


@pytest.mark.parametrize(
    ("moment", "left"),
    [
        (loading, "nothing written"),
        (started, "nothing written ({out} is as it was)"),
        (READING, "nothing written ({out} is as it was)"),
        (CLEANING, "nothing written ({out} is as it was)"),
    ],
    ids=["loading", "started", "reading", "cleaning"],
)
def test_ctrl_c_is_one_line_and_leaves_out_as_it_was(
    raw: Path, out: Path, moment: Moment, left: str
) -> None:
    before = files(out)
    program, started_processes = run_until(build(raw, out), moment, out)
    os.killpg(program.pid, signal.SIGINT)  # as a terminal sends it: workers included
    lines = finish(program)
    assert (program.returncode, lines) == (130, [f"interrupted; {left.format(out=out)}"])
    assert gone_within(started_processes, 2), "a worker outlived the interrupt"
    assert files(out) == before
    assert siblings(out) == []


def test_sigterm_is_handled_as_ctrl_c(raw: Path, out: Path) -> None:
    before = files(out)
    program, started_processes = run_until(build(raw, out), READING, out)
    os.kill(program.pid, signal.SIGTERM)  # the main process only, as `kill PID` does
    lines = finish(program)
    assert (program.returncode, lines) == (
        143,
        [f"terminated; nothing written ({out} is as it was)"],
    )
    assert gone_within(started_processes, 2)
    assert files(out) == before
    assert siblings(out) == []


@pytest.mark.slow
def test_workers_end_with_a_killed_build_whose_leftovers_the_next_removes(
    raw: Path, out: Path
) -> None:
    program, started_processes = run_until(build(raw, out), CLEANING, out)
    os.kill(program.pid, signal.SIGKILL)
    finish(program)
    assert started_processes and gone_within(started_processes, 5), "workers outlived the build"
    assert len(siblings(out)) == 2  # its lock file and partial directory
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, *build(raw, out)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert siblings(out) == []


@pytest.mark.parametrize("command", ["synth", "export-cslstm"])
def test_sigterm_of_a_command_that_writes_a_folder_leaves_no_file(
    command: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    folder = tmp_path / "new"
    if command == "synth":
        arguments = ["synth", str(folder), "--recordings", "2", "--minutes", "2"]
        moment: Moment = lambda _pid, out: found(out.parent, f".{out.name}.partial-*/*/*.txt")
    else:
        raw = request.getfixturevalue("raw")
        arguments = ["export-cslstm", str(raw), "--out", str(folder), "--allow-partial"]
        moment = WRITING_MAT
    program, _ = run_until(arguments, moment, folder)
    os.kill(program.pid, signal.SIGTERM)
    lines = finish(program)
    assert (program.returncode, lines) == (
        143,
        [f"terminated; nothing written ({folder} is as it was)"],
    )
    assert not folder.exists() and siblings(folder) == []


def WRITING_MAT(_pid: int, out: Path) -> bool:  # noqa: N802 - a moment, as READING is
    """export-cslstm is writing its first file, wherever it writes it."""
    return found(out.parent, "**/*TrainSet.mat*")


@pytest.mark.slow
def test_a_killed_export_cslstm_leaves_nothing_the_next_does_not_remove(
    raw: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "cs"
    arguments = ["export-cslstm", str(raw), "--out", str(folder), "--allow-partial"]
    program, _ = run_until(arguments, WRITING_MAT, folder)
    os.kill(program.pid, signal.SIGKILL)
    finish(program)
    assert not folder.exists()  # nothing that looks like an export, not even half of one
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, *arguments], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert siblings(folder) == [] and len(list(folder.iterdir())) == 4


def test_a_ctrl_c_while_the_program_loads_is_answered_once_it_has_loaded(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Polars' native start-up panics on an interrupt that reaches it: the entry point holds
    Ctrl-C off while it imports, then answers it with its one line."""
    imported = []

    def import_module(name: str) -> object:
        signal.raise_signal(signal.SIGINT)  # Ctrl-C in the middle of the imports
        imported.append(name)  # the import ran to its end
        return type("Module", (), {"main": staticmethod(lambda: None)})

    monkeypatch.setattr(entry.importlib, "import_module", import_module)
    with pytest.raises(SystemExit) as exited:
        entry.ngsim_graphs()
    assert exited.value.code == 130 and imported == ["ngsim_cli.ngsim"]
    assert capsys.readouterr().err == "interrupted; nothing written\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
