"""The log files of the long commands (ngsim_cli.logs): `build` into BUILD/build.log once the build
has landed, `fit` into RUN/fit.log once the run folder is fit's (appended by a resume), each of
their stderr lines after its time; a refused or failed call writes no log into a folder it did
not take, and a log is never replaced nor written through a link."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from aigem.runs.records import FIT_LOG, HORIZONS, RUN_INFO
from aigem.runs.unfinished import mark_started, unfinished_group, unfinished_start
from ngsim_cli import console, logs, progress
from ngsim_cli.aigem import app as aigem_app
from ngsim_cli.ngsim import app as ngsim_app
from ngsim_graphs.layout import BUILD_LOG

STAMP = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d "  # logs.TIMESTAMP's
FIT = ["--batch-size", "8", "--horizon-s", "2", "--seed", "3", "--device", "cpu", "--workers", "0"]


def said(path: Path) -> list[str]:
    """The log's lines without their times (each checked to have one) and elapsed times."""
    lines = path.read_text().splitlines()
    assert all(re.match(STAMP, line) for line in lines), lines
    return [re.sub(r", \d:\d\d:\d\d elapsed", "", line[20:]) for line in lines]


@pytest.fixture
def quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    """No progress line within a stage (only at each stage's end): lines a person can list."""
    monkeypatch.setattr(progress, "PLAIN_PROGRESS_INTERVAL_S", 1e9)


def test_a_builds_log_lands_with_it_and_verify_and_overwrite_take_it(
    tiny_build: Path, tmp_path: Path, quiet: None
) -> None:
    raw, out = tiny_build.parent / "raw", tmp_path / "build"
    args = ["build", str(raw), "--out", str(out), "--d-sense-m", "12", "--d-min-m", "6"]
    built = CliRunner().invoke(ngsim_app, [*args, "--jobs", "1"])
    assert built.exit_code == 0, built.output
    stages = [
        "reading trajectories-0750am-0805am.txt: 1/1 (100%)",  # one job: the file by its name
        "cleaning recordings: 1/1 (100%)",
        "building recordings: 1/1 (100%)",
        "writing samples: 1/1 (100%)",
    ]
    assert said(out / BUILD_LOG) == stages
    assert [line[20:] for line in built.stderr.splitlines()] == [
        line[20:] for line in (out / BUILD_LOG).read_text().splitlines()
    ]  # stderr's lines, as it has them off a terminal
    verified = CliRunner().invoke(ngsim_app, ["verify", str(out)])
    assert verified.exit_code == 0 and verified.stderr == "", verified.output
    again = CliRunner().invoke(ngsim_app, [*args, "--jobs", "1", "--overwrite"])
    assert again.exit_code == 0, again.output
    assert said(out / BUILD_LOG) == stages  # the new build's log, not appended to the old one's
    before = (out / BUILD_LOG).read_bytes()
    failed = CliRunner().invoke(ngsim_app, [*args, "--jobs", "1", "--overwrite", "--d-min-m", "-1"])
    refused = CliRunner().invoke(ngsim_app, ["build", str(tmp_path / "none"), "--out", str(out)])
    assert (failed.exit_code, refused.exit_code) == (2, 1)
    assert (out / BUILD_LOG).read_bytes() == before  # nor a line of the calls that failed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["build"]  # and no log elsewhere


def test_a_fits_log_holds_each_epoch_and_a_resume_appends_to_it(
    tiny_build: Path, tmp_path: Path, quiet: None
) -> None:
    run = tmp_path / "run"
    args = ["fit", str(tiny_build), "--out", str(run), *FIT]
    first = CliRunner().invoke(aigem_app, [*args, "--epochs", "1"])
    assert first.exit_code == 0, first.output
    end = r"epoch {0}/{0}: (\d+)/\1 \(100%\); loss [\d.]+ m²"  # the bar's end, in plain words
    epoch = r"epoch {}: train MSE [\d.]+ m², validation MSE [\d.]+ m²( \(best\))?; .* validation"
    first_lines = said(run / FIT_LOG)
    patterns = [end.format(1), epoch.format(1)]
    assert len(first_lines) == 2 and all(map(re.fullmatch, patterns, first_lines)), first_lines
    refused = CliRunner().invoke(aigem_app, [*args, "--epochs", "2", "--resume", "--seed", "4"])
    assert refused.exit_code == 1 and said(run / FIT_LOG) == first_lines  # nothing written
    resumed = CliRunner().invoke(aigem_app, [*args, "--epochs", "2", "--resume"])
    assert resumed.exit_code == 0, resumed.output
    lines = said(run / FIT_LOG)
    assert lines[:2] == first_lines and len(lines) == 4, lines  # appended
    assert all(map(re.fullmatch, [end.format(2), epoch.format(2)], lines[2:])), lines
    evaluated = CliRunner().invoke(aigem_app, ["evaluate", str(run), "--device", "cpu"])
    assert evaluated.exit_code == 0 and len(said(run / FIT_LOG)) == 4  # evaluate has no log


def test_a_fit_that_keeps_no_epoch_takes_its_log_away_with_its_run(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Interrupted in its first epoch, a fit leaves nothing, its log included (the interrupt's
    line is on stderr); a folder that a killed fit left with its log (and its marker) is still
    one a fresh fit takes."""
    import aigem.training.fit

    def set_up_then_interrupted(build_dir: Path, run_dir: Path, *args: Any) -> None:
        *_, show, _on_epoch, _loading, note = args  # fit_horizons' callbacks
        run_dir.mkdir()
        mark_started(run_dir)  # the run folder is fit's
        note("batches from the loader")  # a line on stderr: kept
        assert not (run_dir / FIT_LOG).exists()
        show(1, 1, 10, (float("nan"),))  # training runs: the log opens
        assert said(run_dir / FIT_LOG) == ["batches from the loader"]
        raise KeyboardInterrupt

    monkeypatch.setattr(aigem.training.fit, "fit_horizons", set_up_then_interrupted)
    run = tmp_path / "run"
    stopped = CliRunner().invoke(aigem_app, ["fit", str(tiny_build), "--out", str(run), *FIT])
    assert stopped.exit_code == 130, stopped.output
    assert stopped.stderr.splitlines()[-1].endswith("nothing kept") and not run.exists()
    left = tmp_path / "left"  # a killed fit's: its marker, run.json, its log
    left.mkdir()
    mark_started(left)
    (left / FIT_LOG).write_text("2026-11-28 14:03:07 loading the splits\n")
    assert unfinished_start(left)
    (left / RUN_INFO).write_text("{}")
    assert not unfinished_start(left)  # not an aigem run's run.json: never fit's to take
    group = tmp_path / "group"
    (group / "h1s").mkdir(parents=True)
    mark_started(group)
    (group / HORIZONS).write_text('{"horizons_s": [1.0], "members": ["h1s"]}')
    (group / FIT_LOG).write_text("")
    assert unfinished_group(group, (1.0,))


def test_a_log_is_written_once_its_folder_is_ready_and_appended_to(tmp_path: Path) -> None:
    path = tmp_path / "out" / "x.log"
    ready: list[bool] = []
    with logs.command_log(path, lambda: bool(ready)) as log:
        console.print_line("before the folder is ours")  # kept
        assert not path.parent.exists()
        path.parent.mkdir()
        ready.append(True)
        logs.log_line("a progress line")  # the log alone
        assert isinstance(log, logs.CommandLog)
    assert said(path) == ["before the folder is ours", "a progress line"]
    with logs.command_log(path):
        progress.progress_line("epoch 2: ...")
    assert said(path)[-1] == "epoch 2: ..."  # appended
    with logs.command_log(tmp_path / "never.log", lambda: False):
        console.print_warning("dropped with the folder that never was the command's")
    assert not (tmp_path / "never.log").exists()
    console.print_line("no log is open")
    assert len(said(path)) == 3


def test_a_log_is_never_written_through_a_link(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A link where the log goes: one warning, and the command goes on without a log."""
    target = tmp_path / "theirs.txt"
    target.write_text("a user's file\n")
    (tmp_path / "fit.log").symlink_to(target)
    with logs.command_log(tmp_path / "fit.log"):
        console.print_line("epoch 1: ...")
        console.print_line("epoch 2: ...")
    assert target.read_text() == "a user's file\n"
    first, warning, *rest = capfd.readouterr().err.splitlines()
    assert (first, rest) == ("epoch 1: ...", ["epoch 2: ..."])
    assert re.fullmatch(
        rf"warning: {re.escape(str(tmp_path))}/fit.log: .+; no log is written", warning
    )
