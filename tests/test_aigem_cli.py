"""`aigem` as a user meets it: help that shows the choices, errors that name the option and come
before PyTorch is loaded, and a warning when fixed threads meet busy cores."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from aigem import cores
from aigem.runs import checkpoints, folder, run_log
from ngsim_cli import console, progress
from ngsim_cli.aigem import app
from ngsim_cli.ngsim import app as ngsim_app
from ngsim_graphs import lock

FIT = ["--epochs", "1", "--batch-size", "8", "--horizon-s", "2", "--seed", "3", "--device", "cpu"]
FIELD = re.compile(r"\b[a-z]+_[a-z_]+\b")  # a config field's name (batch_size, lr_schedule)


def one_error_line(result) -> str:  # noqa: ANN001
    assert result.exit_code != 0 and result.stdout == "", result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    return lines[0]


@pytest.mark.parametrize(
    ("program", "command"),
    [(app, "fit"), (app, "evaluate"), *((ngsim_app, c) for c in ("build", "export-cslstm"))],
)
def test_help_shows_choices_not_python_types(program, command: str) -> None:  # noqa: ANN001
    text = CliRunner(env={"COLUMNS": "100"}).invoke(program, [command, "--help"]).stdout
    assert "list[" not in text, text
    assert program is not app or "<str>" not in text, text  # each aigem option of choices
    assert text.startswith("Usage: ")


def test_the_choices_are_in_the_help() -> None:
    fit = CliRunner(env={"COLUMNS": "100"}).invoke(app, ["fit", "--help"]).stdout
    assert "--device <auto|cpu|cuda>" in fit and "--lr-schedule <constant|cosine>" in fit
    assert "--horizon-s S[,S...]" in fit
    assert "fit warns when it starts on fewer idle cores" in " ".join(fit.split())
    evaluate = CliRunner(env={"COLUMNS": "100"}).invoke(app, ["evaluate", "--help"]).stdout
    assert "--split <train|val|test>" in evaluate and "--device <auto|cpu|cuda>" in evaluate


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--batch-size", "0"], "--batch-size must be >= 1"),
        (["--epochs", "0"], "--epochs must be >= 1"),
        (["--learning-rate", "0"], "--learning-rate must be a finite number > 0, not 0"),
        (["--warmup-epochs", "3"], "--warmup-epochs must be >= 0 and fewer than epochs"),
        (["--clip-grad-norm", "-1"], "--clip-grad-norm must be a finite number > 0, not -1"),
        (["--max-minutes", "0"], "--max-minutes must be a finite number > 0, not 0"),
        (["--patience", "0"], "--patience must be >= 1"),
        (["--workers", "-1"], "--workers must be >= 0"),
        (["--threads", "0"], "--threads must be >= 1"),
        (["--horizon-s", "6"], "--horizon-s 6: 6 s is not a horizon in (0, 5] s"),
    ],
)
def test_an_option_error_names_the_option(
    tiny_build: Path, tmp_path: Path, options: list[str], message: str
) -> None:
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(tmp_path / "run"), *FIT, *options]
    )
    assert result.exit_code == 2
    line = one_error_line(result)
    assert line == f"error: {message}" and not FIELD.search(line)
    assert not (tmp_path / "run").exists()


def test_a_resume_refused_names_the_options(tiny_build: Path, tiny_run: Path) -> None:
    args = ["fit", str(tiny_build), "--out", str(tiny_run), "--resume", *FIT]
    result = CliRunner().invoke(app, [*args, "--batch-size", "16", "--no-concat"])
    line = one_error_line(result)
    assert line == (
        f"error: {tiny_run}: cannot resume: the model config differs from the run's (--no-concat)"
    )
    line = one_error_line(CliRunner().invoke(app, [*args, "--batch-size", "16", "--seed", "4"]))
    assert line == (
        f"error: {tiny_run}: cannot resume with another --batch-size 8 -> 16, --seed 3 -> 4: it "
        "changes what the run learns"
    )


# Each of these is refused from the options, the build's manifest or the run's run.json alone.
REFUSED = [
    ["fit", "{build}", "--out", "{tmp}/a", "--batch-size", "0"],
    ["fit", "{tmp}", "--out", "{tmp}/b"],  # not a build
    ["fit", "{build}", "--out", "{run}"],  # a run there: needs --resume
    ["fit", "{build}", "--out", "{tmp}/c", "--resume"],  # nothing to resume
    ["fit", "{build}", "--out", "{run}", "--resume", "--horizon-s", "2", "--batch-size", "16"],
    ["evaluate", "{build}"],  # not a run
    ["evaluate", "{run}", "--data", "{tmp}"],  # not a build
    ["evaluate", "{run}", "--data", "{other}"],  # another build without --other-build
]
PROBE = """
import json, sys
from typer.testing import CliRunner
from ngsim_cli.aigem import app
results = [CliRunner().invoke(app, args) for args in json.loads(sys.argv[1])]
print(json.dumps({
    "torch": "torch" in sys.modules,
    "results": [[r.exit_code, r.stdout, r.stderr] for r in results],
}))
"""


def test_errors_come_before_pytorch_is_loaded_and_nothing_is_printed_first(
    tiny_build: Path, tiny_run: Path, two_recording_build: Path, tmp_path: Path
) -> None:
    """PyTorch takes seconds to import: a refusal that loads it keeps a user waiting for nothing
    (3.5 to 7 s on a busy 2-core machine), and `fit` printed the parameter count first."""
    values = {"build": tiny_build, "run": tiny_run, "tmp": tmp_path, "other": two_recording_build}
    commands = [[arg.format(**values) for arg in args] for args in REFUSED]
    probe = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(commands)],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    report = json.loads(probe.stdout)
    assert report["torch"] is False
    for args, (code, stdout, stderr) in zip(commands, report["results"], strict=True):
        assert code in (1, 2) and stdout == "", (args, stdout)
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), (args, stderr)


def test_busy_cores_warning_from_the_idle_cores_given() -> None:
    cpus = len(cores.os.sched_getaffinity(0))
    warning = cores.busy_cores_warning(2, idle=1.0)
    assert warning == (
        f"--threads 2 with 1.0 of {cpus} usable cores idle (other processes keep "
        f"{cpus - 1:.1f} busy): every step waits for the threads without a core, which made "
        "training 50 times slower; give --threads 1 or leave --threads out (it follows the idle "
        "cores)"
    )
    assert cores.busy_cores_warning(2, idle=1.8) is None  # a little load: no thread waits
    assert cores.busy_cores_warning(1, idle=0.3) is None  # one thread always has a core


def test_busy_cores_are_read_from_proc_stat(monkeypatch: pytest.MonkeyPatch) -> None:
    samples = iter([(100, 400), (250, 600)])  # 150 of 200 jiffies busy on 2 cores: 0.5 idle
    monkeypatch.setattr(cores, "_busy_and_total", lambda cpus: next(samples))
    assert cores.idle_cores({0, 1}, over_s=0.0) == pytest.approx(0.5)
    monkeypatch.setattr(cores, "_busy_and_total", lambda cpus: None)  # not Linux: silent
    assert cores.idle_cores({0, 1}, over_s=0.0) is None
    assert cores.busy_cores_warning(4) is None


def test_fit_warns_when_fixed_threads_meet_busy_cores(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cores, "idle_cores", lambda cpus, over_s=0.2: 1.0)
    args = ["fit", str(tiny_build), "--out", str(tmp_path / "run"), *FIT, "--workers", "0"]
    busy = CliRunner().invoke(app, [*args, "--threads", "2"])
    assert busy.exit_code == 0, busy.output
    warnings = [line for line in busy.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 1 and warnings[0].startswith("warning: --threads 2 with 1.0 of ")
    assert "1 epoch on cpu (the epochs asked); best epoch 1" in busy.stdout  # not "1 epochs"
    terminal = io.StringIO()  # the progress bar draws on a terminal only
    monkeypatch.setattr(
        console, "stderr", Console(file=terminal, force_terminal=True, width=150, color_system=None)
    )
    one = CliRunner().invoke(app, [*args[:3], str(tmp_path / "one"), *args[4:], "--threads", "1"])
    assert one.exit_code == 0 and "warning" not in one.stderr
    drawn = re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", terminal.getvalue())  # the cursor's moves
    assert re.search(r"epoch 1/1 loss [\d.]+ m² .* ETA \d+:\d\d:\d\d", drawn), drawn


def _start_fit(build: Path, run: Path, batch_size: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "ngsim_cli.aigem", "fit", str(build), "--out", str(run)]
    options = ["--epochs", "50", "--batch-size", str(batch_size), "--workers", "0"]
    return subprocess.Popen(
        [*command, *options, "--device", "cpu", "--threads", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(path: Path, process: subprocess.Popen, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not (path.is_file() and path.stat().st_size) and process.poll() is None:
        assert time.monotonic() < deadline, f"no {path} after {timeout_s} s"
        time.sleep(0.02)


@pytest.mark.slow
def test_ctrl_c_after_an_epoch_says_what_the_run_kept(tiny_build: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    process = _start_fit(tiny_build, run, batch_size=8)
    _wait_for(run / folder.LAST, process)  # the first epoch's checkpoint
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    kept = checkpoints.epochs_kept(run)
    assert kept >= 1 and stderr.splitlines()[-1] == (
        f"interrupted after epoch {kept} (run {run} holds its checkpoint); continue with --resume"
    )
    assert not list(run.glob("*.partial*"))
    assert json.loads((run / "run.json").read_text())["train"]["epochs"] == 50
    assert len(run_log.read_metrics(run)) >= kept  # a row written before its checkpoint is redone


def test_sigterm_before_the_first_epoch_keeps_nothing(tiny_build: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    process = _start_fit(tiny_build, run, batch_size=1)  # an epoch of hundreds of steps
    _wait_for(run / "run.json", process)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert stderr.splitlines()[-1] == "interrupted before the first epoch ended; nothing kept"
    assert not run.exists()


def test_a_second_fit_into_the_same_out_is_refused_while_the_first_runs(
    tiny_build: Path, tmp_path: Path
) -> None:
    """A running fit holds --out's lock (as a build and a paper hold theirs): here this test
    holds it, as the first fit would, and the second fit is one line and touches nothing."""
    run = tmp_path.resolve() / "run"
    held = lock.take_lock(run)
    try:
        result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), *FIT])
        assert result.exit_code == 1
        assert one_error_line(result) == (
            f"error: {run}: another process is writing it (process {os.getpid()}), holding "
            f"{tmp_path.resolve() / '.run.lock'}; wait for it to finish or choose another --out"
        )
        assert not run.exists()
    finally:
        lock.release_lock(held, run)
    assert not (tmp_path / ".run.lock").exists()


@pytest.mark.parametrize(
    "batches", [[], ["--resident", "--workers", "2"]], ids=["loader", "on-the-device"]
)
def test_a_resealed_manifest_whose_scaler_was_edited_is_caught_from_the_data(
    tiny_build: Path, tmp_path: Path, batches: list[str]
) -> None:
    """Anyone can recompute the manifest's unkeyed checksum; the train split's values cannot lie
    outside the scaler fitted on them. Also where the split is loaded onto the device by worker
    processes (the error comes back whole, one line)."""
    build = tmp_path / "build"
    shutil.copytree(tiny_build, build)
    manifest = json.loads((build / "manifest.json").read_text())
    manifest["scaler"]["speed_mps"]["max"] = 3.0
    manifest.pop("manifest_sha256")
    canonical = json.dumps(manifest, sort_keys=True, separators=(",", ":")).encode()
    manifest["manifest_sha256"] = hashlib.sha256(canonical).hexdigest()
    (build / "manifest.json").write_text(json.dumps(manifest, indent=2, sort_keys=True))
    run = tmp_path / "run"
    result = CliRunner().invoke(app, ["fit", str(build), "--out", str(run), *FIT, *batches])
    assert result.exit_code == 1
    line = one_error_line(result)
    assert re.fullmatch(
        rf"error: {re.escape(str(build / 'manifest.json'))}: the scaler does not cover the train "
        r"split: speed \d+\.\d m/s where its range ends at 3\.0 m/s; edited manifest\? build again",
        line,
    ), line
    assert not run.exists()  # no epoch ended: nothing kept


# What the installed `aigem` runs (pyproject.toml), with the program's own name.
PROGRAM = "import sys; from ngsim_cli.entry import aigem; sys.argv[0] = 'aigem'; aigem()"


def test_the_installed_program_is_the_entry_point_tested_here() -> None:
    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert pyproject["project"]["scripts"]["aigem"] == "ngsim_cli.entry:aigem"


def _mapped(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    ("command", "library"),
    [("fit", "polars"), ("fit", "libtorch"), ("evaluate", "libtorch")],
    ids=["fit, loading aigem", "fit, loading PyTorch", "evaluate, loading PyTorch"],
)
def test_ctrl_c_while_aigem_loads_is_one_line(
    tiny_build: Path, tiny_run: Path, tmp_path: Path, command: str, library: str
) -> None:
    run = tmp_path / "run"
    arguments = {
        "fit": ["fit", str(tiny_build), "--out", str(run), *FIT],
        "evaluate": ["evaluate", str(tiny_run), "--device", "cpu"],
    }[command]
    program = subprocess.Popen(
        [sys.executable, "-c", PROGRAM, *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not _mapped(program.pid, library):
        assert program.poll() is None, f"it ended before loading {library}: {program.stderr.read()}"
        assert time.monotonic() < deadline
        time.sleep(0.002)
    program.send_signal(signal.SIGINT)
    stdout, stderr = program.communicate(timeout=120)
    assert (program.returncode, stdout, stderr) == (130, "", "interrupted; nothing written\n")
    assert not run.exists()


@pytest.mark.slow
def test_a_fit_killed_at_any_point_resumes_to_the_uninterrupted_run(
    tiny_build: Path, tmp_path: Path
) -> None:
    """kill -9 before the first checkpoint (a fresh fit takes the folder over) and right after
    it (--resume): the run ends as one that was never stopped, weights to the bit."""

    def fit_process(run: Path, *more: str, batch_size: int = 8) -> subprocess.Popen:
        command = [sys.executable, "-m", "ngsim_cli.aigem", "fit", str(tiny_build), "--out"]
        options = ["--epochs", "2", "--batch-size", str(batch_size), "--horizon-s", "2", "--seed",
                   "3"]  # fmt: skip
        return subprocess.Popen(
            [*command, str(run), *options, "--device", "cpu", "--threads", "1", "--workers", "0",
             *more],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip

    def done(process: subprocess.Popen) -> None:
        _, stderr = process.communicate(timeout=300)
        assert process.returncode == 0, stderr

    straight, killed = tmp_path / "straight", tmp_path / "killed"
    done(fit_process(straight))
    # Batches of one: a long first epoch, killed well before its checkpoint; a fresh fit (of
    # other settings even) takes the folder over, and is killed once its first checkpoint is
    # kept (perhaps before its marker went); --resume ends it.
    process = fit_process(killed, batch_size=1)
    _wait_for(killed / folder.RUN_INFO, process)
    process.kill()
    process.wait(timeout=60)
    assert (killed / folder.STARTED).is_file() and not (killed / folder.LAST).exists()
    process = fit_process(killed)
    _wait_for(killed / folder.LAST, process)
    process.kill()
    process.wait(timeout=60)
    done(fit_process(killed, "--resume"))
    weights = lambda run, name: torch_load(run / name)["model"]
    for name in (folder.BEST, folder.LAST):
        one, other = weights(straight, name), weights(killed, name)
        assert one.keys() == other.keys() and all(one[k].equal(other[k]) for k in one)
    rows = lambda run: [(r.epoch, r.train_loss_m2, r.val_loss_m2)
                        for r in run_log.read_metrics(run)]  # fmt: skip
    assert rows(killed) == rows(straight) and len(rows(straight)) == 2
    assert sorted(p.name for p in killed.iterdir()) == sorted(p.name for p in straight.iterdir())


def torch_load(path: Path) -> dict:
    import torch

    return torch.load(path, map_location="cpu", weights_only=True)


STAMP = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d "  # progress.TIMESTAMP's
MSE = r"\d+\.\d{3} m²"


def test_fit_and_evaluate_into_a_log_print_each_epoch_and_the_end_after_its_time(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """stderr is not a terminal here (a log): each line after its wall-clock time; each epoch's
    train and validation loss, and the run's end (the lines every PLAIN_PROGRESS_INTERVAL_S
    within it set out of reach here), once, with the last epoch's mean loss."""
    monkeypatch.setattr(progress, "PLAIN_PROGRESS_INTERVAL_S", 1e9)
    run = tmp_path / "run"
    args = ["fit", str(tiny_build), "--out", str(run), *FIT, "--epochs", "2"]
    fit = CliRunner().invoke(app, args)
    assert fit.exit_code == 0, fit.output
    lines = fit.stderr.splitlines()
    assert all(re.match(STAMP, line) for line in lines), fit.stderr
    patterns = [
        rf"epoch 1: train MSE {MSE}, validation MSE {MSE} \(best\); .* s validation",
        rf"epoch 2/2: (\d+)/\1 \(100%\), 0:00:\d\d elapsed; loss ({MSE})",
        rf"epoch 2: train MSE ({MSE}), validation MSE {MSE}( \(best\))?; .* s validation",
    ]
    assert len(lines) == len(patterns), lines
    found = [re.fullmatch(p, line[20:]) for p, line in zip(patterns, lines, strict=True)]
    assert all(found), list(zip(patterns, lines, strict=True))
    assert found[1].group(2) == found[2].group(1)  # the epoch's mean, as its line says
    evaluated = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert evaluated.exit_code == 0, evaluated.output
    (line,) = evaluated.stderr.splitlines()
    assert re.fullmatch(
        rf"{STAMP}evaluating the test split: (\d+)/\1 \(100%\), 0:00:\d\d elapsed", line
    )
    assert "\x1b" not in fit.stderr + evaluated.stderr


def test_plain_lines_at_every_batch_repeat_no_count_and_no_earlier_epochs_loss(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the interval 0 a line at every batch, none twice; a line of epoch 2 never shows
    epoch 1's loss (the running loss before epoch 2's first is read shows none)."""
    monkeypatch.setattr(progress, "PLAIN_PROGRESS_INTERVAL_S", 0.0)
    run = tmp_path / "run"
    args = ["fit", str(tiny_build), "--out", str(run), *FIT, "--epochs", "2"]
    fit = CliRunner().invoke(app, args)
    assert fit.exit_code == 0, fit.output
    lines = fit.stderr.splitlines()
    counts = [found.group(1) for line in lines if (found := re.search(r": (\d+/\d+) \(", line))]
    batches = int(counts[-1].split("/")[1])
    assert counts == [f"{done}/{batches}" for done in range(1, batches + 1)]
    first = re.search(rf"epoch 1: train MSE ({MSE})", fit.stderr).group(1)
    later = [line for line in lines if "epoch 2/2:" in line]
    assert later and not any(f"loss {first}" in line for line in later)


def test_the_summary_says_why_a_model_stopped(capsys: pytest.CaptureFixture[str]) -> None:
    from aigem.training.fit import FitResult
    from ngsim_cli.fit_view import print_results

    because = ("epochs", "early stopping", "time limit")
    results = tuple(
        FitResult(Path(f"run/h{h}s"), h, 74_242, 3, 2, 1.5, why, 100.0, "cpu")
        for h, why in enumerate(because, start=1)
    )
    print_results(results, Path("run"))
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(";")[0] for line in lines[1:4]] == [
        "1 s model: 3 epochs on cpu (the epochs asked)",
        "2 s model: 3 epochs on cpu (stopped early: --patience epochs without a better validation "
        "loss)",
        "3 s model: 3 epochs on cpu (--max-minutes ran out)",
    ]


CUDA_PROBE = """
import json, sys
import torch
torch.cuda.is_available = lambda: False  # as on a machine without a GPU
from typer.testing import CliRunner
from ngsim_cli.aigem import app
results = [CliRunner().invoke(app, args) for args in json.loads(sys.argv[1])]
print(json.dumps({
    "loaded": sorted(m for m in ("aigem.training.fit", "aigem.evaluation.evaluate", "aigem.training.epochs",
                                 "aigem.model.network", "torch_geometric") if m in sys.modules),
    "results": [[r.exit_code, r.stdout, r.stderr] for r in results],
}))
"""


def test_no_cuda_is_said_before_the_model_and_the_data_load(
    tiny_build: Path, tiny_run: Path, tmp_path: Path
) -> None:
    """`--device cuda` without CUDA took 22 s to be refused: the model, PyTorch Geometric and
    the data loaded first. Now PyTorch alone."""
    commands = [
        ["fit", str(tiny_build), "--out", str(tmp_path / "run"), "--device", "cuda"],
        ["evaluate", str(tiny_run), "--device", "cuda"],
        [
            "paper",
            str(tiny_build.parent / "raw"),
            "--out",
            str(tmp_path / "paper"),
            "--device",
            "cuda",
        ],
    ]
    probe = subprocess.run(
        [sys.executable, "-c", CUDA_PROBE, json.dumps(commands)],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    report = json.loads(probe.stdout)
    assert report["loaded"] == []
    for code, stdout, stderr in report["results"]:
        assert (code, stdout, stderr) == (
            1,
            "",
            "error: --device cuda: no CUDA device is available\n",
        )
    assert not (tmp_path / "run").exists() and not (tmp_path / "paper").exists()


@pytest.mark.parametrize(
    ("program", "command", "said"),
    [
        (app, "show", "No such command 'show': it is `ngsim-graphs show`."),
        (
            app,
            "export-cslstm",
            "No such command 'export-cslstm': it is `ngsim-graphs export-cslstm`.",
        ),
        (ngsim_app, "fit", "No such command 'fit': it is `aigem fit`."),
        (ngsim_app, "paper", "No such command 'paper': it is `aigem paper`."),
        (app, "nothing", "No such command 'nothing'."),  # of neither program
    ],
)
def test_a_command_of_the_other_program_says_which_program_has_it(
    program,
    command: str,
    said: str,  # noqa: ANN001
) -> None:
    result = CliRunner().invoke(program, [command, "x"])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.splitlines()[-1] == f"Error: {said}"


def test_evaluate_of_a_paper_folder_names_its_runs(tmp_path: Path) -> None:
    paper = tmp_path / "paper"
    (paper / "runs" / "dmin-25m").mkdir(parents=True)
    (paper / "runs" / "dmin-0m").mkdir()
    (paper / "paper.json").write_text(json.dumps({"written_by": "aigem paper"}))
    result = CliRunner().invoke(app, ["evaluate", str(paper)])
    assert one_error_line(result) == (
        f"error: {paper}: is an `aigem paper` folder, not a run: its runs are at {paper}/runs: "
        f"dmin-0m, dmin-25m (the paper's model: {paper}/runs/dmin-25m)"
    )
    (paper / "runs" / "dmin-25m").rmdir()
    (paper / "runs" / "dmin-0m").rmdir()
    result = CliRunner().invoke(app, ["evaluate", str(paper)])
    assert (
        one_error_line(result)
        == f"error: {paper}: is an `aigem paper` folder, not a run: no run yet"
    )


def test_paper_given_a_build_says_it_wants_the_raw_files(tiny_build: Path, tmp_path: Path) -> None:
    made_from = json.loads((tiny_build / "manifest.json").read_text())["inputs"][0]["path"]
    result = CliRunner().invoke(app, ["paper", str(tiny_build), "--out", str(tmp_path / "o")])
    assert one_error_line(result) == (
        f"error: {tiny_build}: is an ngsim-graphs build, not raw trajectory files: aigem paper "
        f"makes its three builds itself from the files a build is made of (this one was made "
        f"from {made_from}); give those files or their folder"
    )
    assert not (tmp_path / "o").exists()


def test_evaluate_says_which_model_each_number_comes_from(tiny_run: Path) -> None:
    result = CliRunner().invoke(
        app, ["evaluate", str(tiny_run), "--device", "cpu", "--bootstrap", "0"]
    )
    assert result.exit_code == 0, result.output
    text = " ".join(result.stdout.split())
    assert (
        "One model, trained for 2 s: every number comes from it (RMSE at 1 and 2 s; ADE and FDE "
        "over 2 s, the paper's over 5 s). Constant velocity on the same targets." in text
    )
    assert "model(s)" not in text and "params (K)" in text
