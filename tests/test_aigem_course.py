"""What a run says of its training: 'trained N of M epochs' in every table, the JSON and the
figures of `aigem evaluate`, and where the run is unfinished the command that continues it (and
that command does continue it)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from dataclasses import fields, replace
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig, fit_option, option_words
from aigem.evaluation.evaluate import evaluate
from aigem.figures.plots import error_by_horizon, error_by_region, final_error_distribution
from aigem.runs import checkpoints, curves
from aigem.runs import folder as runs
from aigem.runs.course import (
    EARLY_STOPPING,
    EPOCHS,
    UNFINISHED,
    Course,
    course_of,
    resume_command,
    stop_reason,
    training_record,
)
from aigem.runs.records import read_group
from aigem.runs.run_log import EpochRow
from ngsim_cli.aigem import app
from ngsim_graphs.errors import NgsimInputError

ROW = EpochRow(epoch=1, train_loss_m2=1.0, val_loss_m2=1.0, best_epoch=1)


def test_why_a_model_stopped_by_hand() -> None:
    rows = [ROW, replace(ROW, epoch=2)]
    assert stop_reason(3, 3, rows, None) == EPOCHS
    assert stop_reason(2, 5, rows, 1) == EARLY_STOPPING  # one epoch without a better loss
    assert stop_reason(2, 5, rows, 2) == UNFINISHED
    assert stop_reason(2, 5, rows, None) == UNFINISHED
    assert stop_reason(0, 5, [], 1) == UNFINISHED


def test_a_record_of_models_alike_and_of_models_apart(tiny_horizons_run: Path) -> None:
    done, cut = Course(3, 3, 2, EPOCHS), Course(1, 3, 1, UNFINISHED)
    alike = training_record({"h1s": done, "h2s": done}, read_group(tiny_horizons_run))
    assert alike["finished"] and alike["summary"] == "trained 3 of 3 epochs"
    assert alike["resume_command"] is None
    apart = training_record({"h1s": done, "h2s": cut}, read_group(tiny_horizons_run))
    assert not apart["finished"]
    assert apart["summary"] == "h1s trained 3 of 3 epochs; h2s trained 1 of 3 epochs"
    assert apart["models"]["h2s"] == {
        "epochs_done": 1,
        "epochs": 3,
        "best_epoch": 1,
        "stopped": UNFINISHED,
    }
    early = Course(2, 9, 1, EARLY_STOPPING)
    assert early.finished and early.words().startswith("trained 2 of 9 epochs, stopped early")


def test_the_resume_command_repeats_the_settings_a_resume_needs(
    tiny_horizons_run: Path, tiny_build: Path
) -> None:
    # the fixture: TrainConfig(epochs=1, batch_size=8, seed=3), horizons 1 and 2 s
    assert resume_command(read_group(tiny_horizons_run)) == (
        f"aigem fit {tiny_build.resolve()} --out {tiny_horizons_run.resolve()} --horizon-s 1,2 "
        "--batch-size 8 --seed 3 --epochs 1 --resume"
    )
    assert course_of(tiny_horizons_run / "h2s") == Course(1, 1, 1, EPOCHS)


def test_every_option_of_the_configs_mapping_is_one_of_fit() -> None:
    """config.fit_option, the one mapping of the configs' fields to `aigem fit`'s options, names
    only options fit has, for a value of each field's type; the CLI's messages name the same."""
    command = typer.main.get_command(app).commands["fit"]
    options = {name for p in command.params for name in (*p.opts, *p.secondary_opts)}
    said = set(option_words().values())
    for config in (TrainConfig, ModelConfig):
        for field in fields(config):
            values = (True, False) if "bool" in str(field.type) else (2,)
            said |= {w for v in values for w in fit_option(field.name, v) if w.startswith("--")}
    assert said and said <= options, said - options
    assert fit_option("hidden", 32) == [] and fit_option("concat_position", True) == []


def test_the_resume_command_says_every_setting_a_resume_must_repeat(
    tiny_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    """Each setting of the model and of RESUME_FIXED that is not its default, by its option
    (config.fit_option); the command parses as fit's options."""
    run = Path(shutil.copytree(tiny_run, tmp_path / "run"))
    document = json.loads((run / "run.json").read_text())
    document["train"] |= {"learning_rate": 0.002, "lr_schedule": "cosine", "warmup_epochs": 0.5,
                          "clip_grad_norm": 5.0, "patience_epochs": 4, "threads": 1}  # fmt: skip
    document["model"] |= {"concat_position": False, "cv_residual": True, "hidden": 32}
    (run / "run.json").write_text(json.dumps(document))
    command = resume_command(read_group(run))
    assert command == (
        f"aigem fit {tiny_build.resolve()} --out {run.resolve()} --horizon-s 2 --batch-size 8 "
        "--learning-rate 0.002 --lr-schedule cosine --warmup-epochs 0.5 --clip-grad-norm 5 "
        "--seed 3 --no-concat --cv-residual --epochs 1 --resume"
    )  # the patience and threads may change, the width no option sets
    fit = typer.main.get_command(app).commands["fit"]
    parsed = fit.make_context("fit", shlex.split(command)[2:]).params
    assert parsed["cv_residual"] and parsed["no_concat"] and parsed["clip_grad_norm"] == 5.0


def _invoke(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def cut_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`aigem fit --epochs 3` that stopped after its first epoch (its time limit ran out at the
    first batch: the epoch it cut is checkpointed, the two after it are not trained)."""
    run = tmp_path_factory.mktemp("course") / "run"
    code, _, err = _invoke(
        "fit", str(tiny_build), "--out", str(run), "--epochs", "3", "--batch-size", "8",
        "--max-minutes", "0.000001", "--device", "cpu", "--threads", "1",
    )  # fmt: skip
    assert code == 0, err
    return run


def test_an_unfinished_run_says_so_in_every_table_the_json_and_the_figures(
    cut_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    command = (
        f"aigem fit {tiny_build.resolve()} --out {cut_run.resolve()} --batch-size 8 "
        "--epochs 3 --resume"
    )
    code, out, err = _invoke("evaluate", str(cut_run), "--device", "cpu")
    assert code == 0, err
    titles = [line.strip() for line in out.splitlines() if "split," in line]
    assert titles and all(t.endswith("AiGem trained 1 of 3 epochs (UNFINISHED)") for t in titles)
    said = f"AiGem trained 1 of 3 epochs (UNFINISHED); continue with `{command}`"
    assert f"{said}." in out.replace("\n", " ")
    assert f"warning: these scores are of an unfinished run: {said}" in err.replace("\n", " ")

    code, out, err = _invoke("evaluate", str(cut_run), "--device", "cpu", "--json")
    assert code == 0 and "unfinished run" in err
    assert json.loads(out)["training"] == {
        "finished": False,
        "summary": "trained 1 of 3 epochs",
        "resume_command": command,
        "models": {"run": {"epochs_done": 1, "epochs": 3, "best_epoch": 1, "stopped": UNFINISHED}},
    }

    result = evaluate(cut_run, device_choice="cpu")
    for draw in (error_by_horizon, error_by_region, final_error_distribution):
        figure = draw(result, "a build")
        assert figure.get_suptitle().endswith("AiGem trained 1 of 3 epochs (UNFINISHED)")
        footer = " ".join(text.get_text() for text in figure.texts).replace("\n", " ")
        assert f"continue with `{command}`" in footer


def test_curves_png_says_how_many_epochs_and_how_to_continue(
    cut_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    drawn = []
    monkeypatch.setattr(curves, "curves_png", lambda *args: drawn.append(args) or b"png")
    runs.plot_curves(cut_run)
    assert drawn[0][-1] == "trained 1 of 3 epochs (UNFINISHED: continue with --resume)"
    title = curves.curves_figure(*drawn[0][:-1], trained=drawn[0][-1]).axes[0].get_title()
    assert (
        title
        == "AiGem training, 5 s horizon\ntrained 1 of 3 epochs (UNFINISHED: continue with --resume)"
    )


def test_the_command_said_continues_the_run(cut_run: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(cut_run, run)
    command = evaluate(run, device_choice="cpu").training["resume_command"]
    words = shlex.split(command)
    assert words[:2] == ["aigem", "fit"]
    code, _, err = _invoke(*words[1:], "--device", "cpu", "--threads", "1")
    assert code == 0, err
    code, out, _ = _invoke("evaluate", str(run), "--device", "cpu")
    assert code == 0 and "AiGem trained 3 of 3 epochs." in out
    assert "UNFINISHED" not in out and "continue with" not in out


# ------------------------------------------------------------------------------------------------
# The log and last.pt agree, or the run is refused: a course is never told from a damaged log.


@pytest.fixture(scope="module")
def two_epoch_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`aigem fit --epochs 2`, finished: metrics.jsonl logs epochs 1 and 2, last.pt holds 2."""
    run = tmp_path_factory.mktemp("two_epochs") / "run"
    code, _, err = _invoke(
        "fit", str(tiny_build), "--out", str(run), "--epochs", "2", "--batch-size", "8",
        "--horizon-s", "1", "--device", "cpu", "--threads", "1",
    )  # fmt: skip
    assert code == 0, err
    return run


def _log_edited(run: Path, tmp_path: Path, epochs: list[int]) -> Path:
    """A copy of `run` whose metrics.jsonl keeps (or renumbers) its rows as `epochs` say."""
    copy = Path(shutil.copytree(run, tmp_path / "run"))
    rows = [json.loads(line) for line in (copy / runs.METRICS).read_text().splitlines()]
    edited = [rows[min(epoch, len(rows)) - 1] | {"epoch": epoch} for epoch in epochs]
    (copy / runs.METRICS).write_text("".join(json.dumps(row) + "\n" for row in edited))
    return copy


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_a_log_that_lost_its_last_line_is_refused_by_evaluate_and_resume(
    two_epoch_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    """evaluate called such a run unfinished (1 of 2 epochs) while scoring epoch 2's model, and
    `fit --resume` left a log of epochs 1 and 3: both refuse it, naming the run and both
    epochs, and nothing is written."""
    run = _log_edited(two_epoch_run, tmp_path, [1])
    before = _files(run)
    expected = (
        f"error: {run}: its metrics.jsonl ends at epoch 1 but its last.pt holds epoch 2: the log "
        "lost lines or was edited; put back the metrics.jsonl this run wrote, or fit a new run "
        "into another --out\n"
    )
    code, out, err = _invoke("evaluate", str(run), "--device", "cpu", "--bootstrap", "0")
    assert (code, out, err) == (1, "", expected)
    code, out, err = _invoke(
        "fit", str(tiny_build), "--out", str(run), "--resume", "--epochs", "3", "--batch-size",
        "8", "--horizon-s", "1", "--device", "cpu", "--threads", "1",
    )  # fmt: skip
    assert (code, out, err) == (1, "", expected)
    assert _files(run) == before


def test_a_log_with_a_hole_is_refused_and_one_ahead_is_not(
    two_epoch_run: Path, tmp_path: Path
) -> None:
    """A hole (epoch 2 logged as 3) is refused; a row one epoch beyond last.pt is what a fit
    killed between logging an epoch and keeping its last.pt leaves (a resume redoes it)."""
    from aigem.paper.folder import PaperConfig, _member_progress

    run = _log_edited(two_epoch_run, tmp_path / "hole", [1, 3])
    message = (
        f"{run}: its metrics.jsonl logs epochs 1, 3, not 1 to 3 in order, but its last.pt holds "
        "epoch 2: the log lost lines or was edited"
    )
    with pytest.raises(NgsimInputError, match=f"^{re.escape(message)}"):
        checkpoints.load_model(run)  # evaluate, show --run, a user's load_model
    with pytest.raises(NgsimInputError, match=f"^{re.escape(message)}"):
        _member_progress(run, PaperConfig(epochs=2))  # aigem paper, on a model it reuses
    checkpoints.check_log(_log_edited(two_epoch_run, tmp_path / "ahead", [1, 2, 3]), 2)
    checkpoints.check_log(two_epoch_run, 2)
