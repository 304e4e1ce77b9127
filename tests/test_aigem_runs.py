"""Run directories: what a run records of its build, checkpoints loaded safely and checked, one
clear error line for anything that is not our run, and no torn file when a write fails."""

from __future__ import annotations

import builtins
import contextlib
import errno
import hashlib
import json
import math
import os
import random
import re
import shutil
import zipfile
from pathlib import Path
from typing import Self

import pytest
import torch
from aigem_fixtures import record_checkpoint
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig
from aigem.evaluation.evaluate import load_run
from aigem.evaluation.scoring import score_members
from aigem.metrics import summarize_errors
from aigem.model.data import GraphDataset
from aigem.model.network import AiGem, count_parameters
from aigem.runs import checkpoints, records, run_log
from aigem.runs import folder as runs
from aigem.runs.baseline import constant_velocity_loss_m2
from aigem.training.fit import fit
from ngsim_cli.aigem import app
from ngsim_graphs import partial_files
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import write_manifest_json
from ngsim_graphs.partial_files import create_exclusive, partial_of
from ngsim_graphs.pipeline import run_build

FAST = TrainConfig(epochs=1, batch_size=8, horizon_s=1.0, seed=3)
FIT = ["--epochs", "1", "--batch-size", "8", "--horizon-s", "1.0", "--seed", "3", "--device", "cpu"]


def _fit_args(epochs: int = 1, horizon_s: float = 1.0) -> list[str]:
    return ["--epochs", str(epochs), "--batch-size", "8", "--horizon-s", str(horizon_s), "--seed",
            "3", "--device", "cpu"]  # fmt: skip


@pytest.fixture(scope="module")
def trained_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("runs") / "run"
    fit(tiny_build, run, ModelConfig(), FAST, "cpu")
    return run


def _copy(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "run"))


def _one_error_line(result, path: Path) -> str:
    """The single stderr line of a failed command, which names `path`."""
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith(f"error: {path}: "), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.output, result.stderr
    return result.stderr


def test_a_run_records_its_builds_identity_and_scaler(trained_run: Path, tiny_build: Path) -> None:
    manifest_bytes = (tiny_build / "manifest.json").read_bytes()
    manifest = json.loads(manifest_bytes)
    info = json.loads((trained_run / runs.RUN_INFO).read_text())
    assert info["build_dir"] == str(tiny_build.resolve())
    assert info["build_config_hash"] == manifest["config_hash"]
    assert info["build_manifest_sha256"] == hashlib.sha256(manifest_bytes).hexdigest()
    assert info["scaler"] == manifest["scaler"]
    # its settings: the config and the limits its source applied, what the config hash covers
    assert info["build_config"] == {**manifest["config"], "limits": manifest["limits"]}
    digests = info.pop(records.DIGESTS)  # and the sha256 of each checkpoint, as it is
    assert digests == {
        name: [hashlib.sha256((trained_run / name).read_bytes()).hexdigest()]
        for name in (runs.BEST, runs.LAST)
    }
    for name in (runs.BEST, runs.LAST):  # loadable without running code, with the same info
        checkpoint = torch.load(trained_run / name, map_location="cpu", weights_only=True)
        assert checkpoint["info"] == info
    last = torch.load(trained_run / runs.LAST, map_location="cpu", weights_only=True)
    assert last["state"]["next_epoch"] == 1 and last["optimizer"]["param_groups"][0]["lr"] == 1e-3


def test_loading_a_model_gives_its_weights_and_draws_nothing(trained_run: Path) -> None:
    saved = torch.load(trained_run / runs.BEST, map_location="cpu", weights_only=True)["model"]
    torch.manual_seed(11)
    model, _ = checkpoints.load_model(trained_run)
    drawn_after_loading = torch.rand(3)
    torch.manual_seed(11)
    assert torch.equal(drawn_after_loading, torch.rand(3))  # the global generator untouched
    weights = model.state_dict()
    assert weights.keys() == saved.keys()
    assert all(torch.equal(weights[name], saved[name]) for name in saved)
    assert not model.training and all(p.device.type == "cpu" for p in model.parameters())


class _Payload:
    """Unpickling this creates `marker`: what a malicious checkpoint would do, harmlessly."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (builtins.open, (self.marker, "w"))


@pytest.mark.parametrize("name", [runs.BEST, runs.LAST])
def test_a_malicious_checkpoint_runs_nothing(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
    name: str,
) -> None:
    run, marker = _copy(trained_run, tmp_path), tmp_path / "pwned"
    good = torch.load(run / name, map_location="cpu", weights_only=True)
    torch.save({**good, "info": _Payload(marker)}, run / name)
    if name == runs.BEST:
        result = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"])
    else:
        result = CliRunner().invoke(
            app, ["fit", str(tiny_build), "--out", str(run), "--resume", *FIT]
        )
    line = _one_error_line(result, run / name)
    assert "refused: loading it would call io.open" in line
    assert not marker.exists()


def _foreign(kind: str, good: dict) -> object:
    """A checkpoint that is not ours, or not whole, as the object (or bytes) to write."""
    if kind == "bare state dict":
        return good["model"]
    if kind == "missing keys":
        return {"model": good["model"]}
    if kind == "unknown model config":
        return {**good, "info": {**good["info"], "model": {**good["info"]["model"], "new_knob": 1}}}
    if kind == "other shapes":
        return {**good, "model": AiGem(ModelConfig(hidden=32)).state_dict()}
    raise ValueError(kind)


DAMAGE = ["empty", "truncated", "random bytes", "bare state dict", "missing keys",
          "unknown model config", "other shapes"]  # fmt: skip


@pytest.mark.parametrize("name", [runs.BEST, runs.LAST])
@pytest.mark.parametrize("kind", DAMAGE)
def test_a_damaged_or_foreign_checkpoint_is_one_error_line(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
    name: str,
    kind: str,
) -> None:
    run = _copy(trained_run, tmp_path)
    path = run / name
    data = path.read_bytes()
    if kind in ("empty", "truncated", "random bytes"):
        damaged = {
            "empty": b"",
            "truncated": data[: len(data) // 2],
            "random bytes": random.Random(0).randbytes(4096),  # seeded: the same bytes every run
        }
        path.write_bytes(damaged[kind])
    else:
        torch.save(_foreign(kind, torch.load(path, map_location="cpu", weights_only=True)), path)
        record_checkpoint(path)  # what a run records: the checks behind the sha256
    if name == runs.BEST:
        result = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"])
    else:
        result = CliRunner().invoke(
            app, ["fit", str(tiny_build), "--out", str(run), "--resume", *FIT]
        )
    line = _one_error_line(result, path)
    expected = {
        "empty": "empty checkpoint (0 bytes)",
        "truncated": "unreadable checkpoint: truncated, damaged or not a torch file",
        "random bytes": "unreadable checkpoint: truncated, damaged or not a torch file",
        "bare state dict": "not an aigem checkpoint: expected info, model",
        "missing keys": "not an aigem checkpoint: expected info, model",
        "unknown model config": "a model config this aigem does not know: unknown new_knob",
        "other shapes": "its weights do not fit its model config: other shape ['encoder.0.spatial.att_src'",
    }
    assert expected[kind] in line


def test_fit_records_constant_velocitys_validation_loss(
    trained_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    expected = constant_velocity_loss_m2(tiny_build, "val", [5])[5]  # 1 s: 5 steps
    assert json.loads((trained_run / runs.BASELINE).read_text()) == {
        "constant_velocity_val_loss_m2": expected,
        "steps": 5,
    }
    assert run_log.read_baseline(trained_run) == expected
    # A run of an older aigem has none (or a damaged one): resuming it records it.
    run = _copy(trained_run, tmp_path)
    (run / runs.BASELINE).write_text("{")
    assert run_log.read_baseline(run) is None
    fit(tiny_build, run, ModelConfig(), TrainConfig(**{**FAST.to_dict(), "epochs": 2}), "cpu", True)
    assert run_log.read_baseline(run) == expected


def test_a_directory_that_is_not_a_run(trained_run: Path, tiny_build: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    missing = runner.invoke(app, ["evaluate", str(tmp_path / "nope"), "--device", "cpu"])
    assert "no such run directory" in _one_error_line(missing, tmp_path / "nope")
    for folder in (tmp_path, tiny_build):  # an empty folder; a build
        result = runner.invoke(app, ["evaluate", str(folder), "--device", "cpu"])
        assert "not a run directory: no run.json" in _one_error_line(result, folder)
    run = _copy(trained_run, tmp_path)
    (run / runs.BEST).unlink()
    unfinished = runner.invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert "not a finished run: no best.pt" in _one_error_line(unfinished, run)
    (run / runs.RUN_INFO).write_text("[1, 2]")
    foreign = runner.invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert "not an aigem run description" in _one_error_line(foreign, run / runs.RUN_INFO)
    (run / runs.RUN_INFO).unlink()
    resume = runner.invoke(app, ["fit", str(tiny_build), "--out", str(run), "--resume", *FIT])
    assert "not a run directory: no run.json" in _one_error_line(resume, run)


def test_a_checkpoint_of_another_run_is_refused(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    run = _copy(trained_run, tmp_path)
    other = tmp_path / "other"
    fit(tiny_build, other, ModelConfig(concat_position=False), FAST, "cpu")
    shutil.copy(other / runs.BEST, run / runs.BEST)
    record_checkpoint(run / runs.BEST)  # its run.json taken along too
    result = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert "belongs to another run: its model differs from run.json's" in _one_error_line(
        result, run / runs.BEST
    )


class _FullDisk:
    """An open file on a disk that fills up after `room` bytes."""

    def __init__(self, file, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data: bytes) -> int:
        self.file.write(data[: self.room])
        self.file.flush()
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str):
        return getattr(self.file, name)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.file.close()


@pytest.mark.parametrize("name", [runs.RUN_INFO, runs.BASELINE, runs.BEST, runs.LAST])
def test_a_full_disk_is_one_error_line_and_leaves_no_torn_file(
    tiny_build: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    name: str,
) -> None:
    def full_disk_create(path: Path):  # noqa: ANN202
        file = create_exclusive(path)
        return _FullDisk(file, 100) if partial_of(path.name) == name else file

    monkeypatch.setattr(partial_files, "create_exclusive", full_disk_create)
    run = tmp_path / "run"
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), *FIT])
    line = _one_error_line(result, run / name)
    assert line == f"error: {run / name}: cannot write: No space left on device\n"
    assert not list(tmp_path.rglob("*.partial*"))
    assert not (run / name).exists() and not (run / runs.LAST).exists()
    if name == runs.RUN_INFO:
        assert not run.exists()  # the run folder it had just made is gone again
    monkeypatch.undo()  # space again: no epoch got its checkpoint, so the run starts over
    again = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), *FIT])
    assert again.exit_code == 0, again.output
    assert [r.epoch for r in run_log.read_metrics(run)] == [1]


def test_resume_refuses_another_build_and_accepts_an_identical_rebuild(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    run = _copy(trained_run, tmp_path)
    copy = Path(shutil.copytree(tiny_build, tmp_path / "copy"))  # byte-identical: the same build
    edited = Path(shutil.copytree(tiny_build, tmp_path / "edited"))
    manifest = json.loads((edited / "manifest.json").read_text())
    manifest["scaler"]["x_m"]["max"] += 1.0  # same config hash, another manifest
    write_manifest_json(edited, manifest)  # sealed anew, as a build of other train data would be
    runner = CliRunner()
    refused = runner.invoke(app, ["fit", str(edited), "--out", str(run), "--resume", *_fit_args(2)])
    assert _one_error_line(refused, edited) == (
        f"error: {edited}: not the build that run {run} was trained on (same config, but its "
        "manifest.json differs from the run's build (other inputs, or edited)); a run resumes on "
        "its own build only\n"
    )
    horizon = runner.invoke(
        app, ["fit", str(copy), "--out", str(run), "--resume", *_fit_args(2, 2.0)]
    )
    assert "cannot resume with other horizons (1 -> 2 s)" in _one_error_line(horizon, run)
    assert [r.epoch for r in run_log.read_metrics(run)] == [1]
    resumed = runner.invoke(app, ["fit", str(copy), "--out", str(run), "--resume", *_fit_args(2)])
    assert resumed.exit_code == 0, resumed.output
    assert [r.epoch for r in run_log.read_metrics(run)] == [1, 2]
    assert json.loads((run / runs.RUN_INFO).read_text())["train"]["epochs"] == 2


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        ("optimizer", "its optimizer state is not this run's optimizer's (Adam)"),
        (
            "state",
            "its progress record is not aigem's (expected next_epoch, best_epoch, best_val_loss)",
        ),
    ],
)
def test_resume_refuses_a_foreign_optimizer_or_progress(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
    kind: str,
    message: str,
) -> None:
    run = _copy(trained_run, tmp_path)
    checkpoint = torch.load(run / runs.LAST, map_location="cpu", weights_only=True)
    model = AiGem(ModelConfig())
    foreign = {
        "optimizer": torch.optim.SGD(model.parameters(), lr=0.1).state_dict(),
        "state": {"next_epoch": "1", "best_epoch": 0, "best_val_loss": 1.0},
    }
    torch.save({**checkpoint, kind: foreign[kind]}, run / runs.LAST)
    record_checkpoint(run / runs.LAST)
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), "--resume", *FIT])
    assert _one_error_line(result, run / runs.LAST) == f"error: {run / runs.LAST}: {message}\n"


def test_fit_never_writes_into_another_programs_folder(tiny_build: Path, tmp_path: Path) -> None:
    folder = tmp_path / "models"
    folder.mkdir()
    (folder / "best.pt").write_bytes(b"someone else's model")
    (folder / "notes.txt").write_text("mine\n")
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(folder), *FIT])
    line = _one_error_line(result, folder)
    assert "not empty and is not an aigem run: it holds best.pt, notes.txt" in line
    assert sorted(p.name for p in folder.iterdir()) == ["best.pt", "notes.txt"]
    assert (folder / "best.pt").read_bytes() == b"someone else's model"


def test_a_damaged_metrics_log_is_one_line(
    trained_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    run = _copy(trained_run, tmp_path)
    with (run / runs.METRICS).open("a") as log:
        log.write('{"epoch": 1, "train_lo\n')  # a torn line
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(run), "--resume", *_fit_args(2)]
    )
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert (
        result.stderr
        == f"error: {run / runs.METRICS}, line 2: not a row of aigem's metrics log (damaged?)\n"
    )


def _contents(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.mark.parametrize(
    "kept",
    [
        (runs.RUN_INFO, runs.BEST),  # a run kept without its last.pt: what evaluate needs
        (runs.RUN_INFO, runs.BEST, runs.BASELINE, runs.METRICS, runs.CURVES),
    ],
    ids=["run.json and best.pt", "all but last.pt"],
)
def test_fit_never_empties_a_folder_that_only_looks_like_a_run(
    trained_run: Path, tiny_build: Path, tmp_path: Path, kept: tuple[str, ...]
) -> None:
    folder = tmp_path / "final-model"
    folder.mkdir()
    for name in kept:
        shutil.copy(trained_run / name, folder / name)
    before = _contents(folder)
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(folder), *FIT])
    assert _one_error_line(result, folder) == (
        f"error: {folder}: holds an aigem run with no last.pt to resume, which no fit left "
        "unfinished here (a run kept without its checkpoint, or a copy): its files are not fit's "
        "to replace; choose a new or empty --out\n"
    )
    assert _contents(folder) == before


def test_a_multi_horizon_fit_never_empties_a_folder_that_only_looks_like_one(
    trained_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    """horizons.json of the same horizons is not enough: every member is looked at too."""
    folder = tmp_path / "models"
    for member in ("h1s", "h2s"):
        (folder / member).mkdir(parents=True)
        for name in (runs.RUN_INFO, runs.BEST):
            shutil.copy(trained_run / name, folder / member / name)
    horizons = {"horizons_s": [1.0, 2.0], "members": ["h1s", "h2s"]}
    (folder / runs.HORIZONS).write_text(json.dumps(horizons))
    (folder / "notes.txt").write_text("mine\n")
    before = _contents(folder)
    result = CliRunner().invoke(
        app,
        ["fit", str(tiny_build), "--out", str(folder), *FIT[:4], "--horizon-s", "1,2", *FIT[6:]],
    )
    assert _one_error_line(result, folder) == (
        f"error: {folder}: directory is not empty and is not a multi-horizon aigem run: it holds "
        "h1s, h2s, horizons.json and 1 more; choose a new or empty --out\n"
    )
    assert _contents(folder) == before


def test_a_fit_stopped_before_its_first_checkpoint_is_started_over(
    tiny_build: Path, tmp_path: Path
) -> None:
    """What a fit leaves before its first last.pt carries its marker: the next fit takes the
    folder (its leftovers go); the marker goes once a checkpoint is kept."""
    run = tmp_path / "run"
    run.mkdir()
    (run / runs.STARTED).write_bytes(runs.STARTED_LINE)
    leftover = run / ".best.pt.partial-0123456789abcdef"  # a write killed halfway
    leftover.write_bytes(b"half a checkpoint")
    (run / runs.METRICS).write_text('{"epoch": 1, "train_loss_m2": 1.0}\n')
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), *FIT])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in run.iterdir()) == sorted(
        [
            runs.RUN_INFO,
            runs.METRICS,
            runs.LAST,
            runs.BEST,
            runs.BASELINE,
            runs.CURVES,
            runs.FIT_LOG,
        ]
    )
    assert [r.epoch for r in run_log.read_metrics(run)] == [1]
    # The same with a file fit did not write beside the marker: refused, nothing removed.
    other = tmp_path / "other"
    other.mkdir()
    (other / runs.STARTED).write_bytes(runs.STARTED_LINE)
    (other / runs.BEST).write_bytes(b"someone else's model")
    (other / "notes.txt").write_text("mine\n")
    before = _contents(other)
    refused = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(other), *FIT])
    assert _one_error_line(refused, other) == (
        f"error: {other}: directory is not empty and is not an aigem run: it holds notes.txt, "
        "which fit did not write; choose a new or empty --out\n"
    )
    assert _contents(other) == before


def test_a_run_is_never_written_through_a_link(
    trained_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    """Links put at the partial names of a run's files, and at its log, lead outside the run:
    a resumed fit writes its files beside them, never into what they lead to."""
    run = _copy(trained_run, tmp_path)
    victims = tmp_path / "victims"
    victims.mkdir()
    for name in (runs.RUN_INFO, runs.LAST, runs.BEST, runs.CURVES, runs.METRICS):
        (victims / name).write_text(f"mine: {name}\n")
        os.symlink(victims / name, run / f"{name}.partial")
    metrics = (run / runs.METRICS).read_bytes()
    (victims / "log").write_bytes(metrics)
    (run / runs.METRICS).unlink()
    os.symlink(victims / "log", run / runs.METRICS)
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(run), "--resume", *_fit_args(2)]
    )
    assert result.exit_code == 0, result.output
    assert {p.name: p.read_bytes() for p in victims.iterdir()} == {
        **{name: f"mine: {name}\n".encode() for name in (runs.RUN_INFO, runs.LAST, runs.BEST,
                                                         runs.CURVES, runs.METRICS)},
        "log": metrics,
    }  # fmt: skip
    assert not (run / runs.METRICS).is_symlink()
    assert [r.epoch for r in run_log.read_metrics(run)] == [1, 2]
    assert checkpoints.epochs_kept(run) == 2


def test_a_run_from_before_cv_residual_reads_as_without_it(
    trained_run: Path, tmp_path: Path
) -> None:
    run = _copy(trained_run, tmp_path)
    evaluate = ["evaluate", str(run), "--device", "cpu", "--json"]
    before = json.loads(CliRunner().invoke(app, evaluate).stdout)
    for name in (runs.BEST, runs.LAST):
        checkpoint = torch.load(run / name, map_location="cpu", weights_only=True)
        info = checkpoint["info"]
        model = {k: v for k, v in info["model"].items() if k != "cv_residual"}
        assert len(model) == len(info["model"]) - 1
        torch.save({**checkpoint, "info": {**info, "model": model}}, run / name)
    document = json.loads((run / "run.json").read_text())
    del document["model"]["cv_residual"]
    (run / "run.json").write_text(json.dumps(document))
    record_checkpoint(run / runs.BEST)  # as that older aigem's fit kept them
    record_checkpoint(run / runs.LAST)
    result = CliRunner().invoke(app, evaluate)
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["model"] == before["model"]


def test_fit_with_cv_residual_records_it_and_predicts_constant_velocity_plus_the_mlp(
    tiny_build: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(run), "--cv-residual", *FIT]
    )
    assert result.exit_code == 0, result.output
    checkpoint = torch.load(run / runs.BEST, map_location="cpu", weights_only=True)
    assert checkpoint["info"]["model"]["cv_residual"] is True
    # The fitted model as evaluation loads it, its MLP's output set to 0: each step adds constant
    # velocity's displacement alone, so it scores as constant velocity does, to float precision.
    loaded = load_run(run, None, torch.device("cpu"), other_build=False)
    assert loaded.model.config.cv_residual
    with torch.no_grad():
        loaded.model.output[-1].weight.zero_()
        loaded.model.output[-1].bias.zero_()
    dataset = GraphDataset(
        tiny_build, "test", loaded.model.config.history_steps_read, loaded.scaler
    )
    (scores,) = score_members([loaded.model], dataset, [loaded.steps(dataset)], torch.device("cpu"))
    ours = summarize_errors(scores.model, dataset.config.time_step_s)["all"]
    baseline = summarize_errors(scores.constant_velocity, dataset.config.time_step_s)["all"]
    assert ours["n_1s"] == baseline["n_1s"] > 0
    for key in ("ade_m", "fde_m", "rmse_1s_m"):
        assert ours[key] == pytest.approx(baseline[key], rel=1e-4, abs=1e-4), key


# A run that aigem 0.1.0 wrote (`aigem fit BUILD --out RUN --epochs 1` on the build below; its
# last.pt and curves.png left out): every later aigem loads and evaluates it.
RUN_0_1_0 = Path(__file__).parent / "fixtures" / "run-0.1.0"
# Its raw input: the files `synth --recordings 1 --minutes 0.5 --seed 3` wrote in aigem 0.1.0
# (the generator has changed since, so they are kept, not made again).
RAW_0_1_0 = Path(__file__).parent / "fixtures" / "raw-0.1.0.zip"


@pytest.fixture(scope="module")
def build_of_run_0_1_0(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The build RUN_0_1_0 was trained on, made again from its raw input: the same config hash;
    its manifest names other paths, so evaluating takes --other-build."""
    root = tmp_path_factory.mktemp("build-0.1.0")
    with zipfile.ZipFile(RAW_0_1_0) as archive:
        archive.extractall(root / "raw")
    run_build([root / "raw"], root / "build", BuildConfig(), jobs=1)
    return root / "build"


def _evaluate_json(run: Path, build: Path) -> dict:
    args = ["evaluate", str(run), "--data", str(build), "--other-build", "--device", "cpu"]
    result = CliRunner().invoke(app, [*args, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_a_run_of_aigem_0_1_0_loads_and_evaluates(build_of_run_0_1_0: Path, tmp_path: Path) -> None:
    run = _copy(RUN_0_1_0, tmp_path)
    model, info = checkpoints.load_model(run)
    assert count_parameters(model) == 74_242 and model.config == ModelConfig() == info.model
    assert info.train.horizon_s == 5.0 and info.train.epochs == 1
    assert info.build.time_step_s == 0.2 and info.build.settings["history_steps"] == 16
    manifest = json.loads((build_of_run_0_1_0 / "manifest.json").read_text())
    assert info.build.identity.config_hash == manifest["config_hash"]
    # Its build's config held the limits; today's build records NGSIM's beside it, the same ones.
    assert info.build.settings == {**manifest["config"], "limits": manifest["limits"]}
    args = ["evaluate", str(run), "--data", str(build_of_run_0_1_0), "--other-build"]
    result = CliRunner().invoke(app, [*args, "--device", "cpu", "--json"])
    assert result.exit_code == 0, result.output
    # Its run.json records no sha256 of best.pt: used as it is, and said so.
    warning, *progress = result.stderr.splitlines()
    assert warning == (
        f"warning: {run / runs.BEST}: its run.json records no sha256 of its checkpoints (a run of "
        "an aigem before they were recorded): used as it is, unchecked"
    )  # and, off a terminal, timestamped progress lines only
    assert all(re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d ", line) for line in progress)
    scores = json.loads(result.stdout)
    assert (scores["samples"], scores["parameters"], scores["horizon_steps"]) == (22, 74_242, 25)
    assert scores["same_build"] is False and scores["synthetic"] is True
    ours, baseline = scores["model"]["all"], scores["constant_velocity"]["all"]
    assert ours["n_5s"] == baseline["n_5s"] == 302
    # As measured when the run was written (one epoch: far from constant velocity yet).
    assert ours["ade_m"] == pytest.approx(35.2097, rel=1e-3)
    assert ours["rmse_1s_m"] == pytest.approx(5.5169, rel=1e-3)
    assert baseline["ade_m"] == pytest.approx(2.53975, rel=1e-4)
    assert baseline["rmse_5s_m"] == pytest.approx(7.37091, rel=1e-4)


def _edit_info(run: Path, edit) -> None:
    """Apply `edit` to the run info of run.json and of best.pt alike."""
    document = json.loads((run / runs.RUN_INFO).read_text())
    edit(document)
    (run / runs.RUN_INFO).write_text(json.dumps(document))
    checkpoint = torch.load(run / runs.BEST, map_location="cpu", weights_only=True)
    edit(checkpoint["info"])
    torch.save(checkpoint, run / runs.BEST)


def test_settings_a_run_lacks_take_their_defaults(build_of_run_0_1_0: Path, tmp_path: Path) -> None:
    run = _copy(RUN_0_1_0, tmp_path)
    before = _evaluate_json(run, build_of_run_0_1_0)

    def older(info: dict) -> None:  # as an aigem before these settings wrote it
        del info["model"]["cv_residual"], info["model"]["concat_position"]
        del info["train"]["compile"], info["train"]["clip_grad_norm"]

    _edit_info(run, older)
    assert "cv_residual" not in json.loads((run / runs.RUN_INFO).read_text())["model"]
    model, _ = checkpoints.load_model(run)
    assert model.config == ModelConfig()  # cv_residual False, concat_position True
    after = _evaluate_json(run, build_of_run_0_1_0)
    assert after["model"] == before["model"]


def test_a_setting_of_a_newer_aigem_is_one_error_line(
    build_of_run_0_1_0: Path, tmp_path: Path
) -> None:
    for key in ("model", "train"):
        run = _copy(RUN_0_1_0, tmp_path / key)
        _edit_info(run, lambda info: info[key].update(new_knob=1))  # noqa: B023
        args = ["--data", str(build_of_run_0_1_0), "--other-build", "--device", "cpu"]
        result = CliRunner().invoke(app, ["evaluate", str(run), *args])
        line = _one_error_line(result, run / runs.RUN_INFO)
        assert f"a {key} config this aigem does not know: unknown new_knob" in line


def test_a_run_recording_a_horizon_off_the_grid_is_one_error_line(tmp_path: Path) -> None:
    """A run that an aigem before the check trained for 0.3 s (1 step, 0.2 s) is refused, not
    scored and reported as 0.3 s."""
    run = _copy(RUN_0_1_0, tmp_path)
    _edit_info(run, lambda info: info["train"].update(horizon_s=0.3))
    result = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert _one_error_line(result, run / runs.RUN_INFO) == (
        f"error: {run / runs.RUN_INFO}: a train config this aigem cannot use: horizon_s must be "
        "a multiple of the 0.2 s time step\n"
    )


def test_an_unlimited_max_minutes_of_an_older_aigem_reads_as_none(tmp_path: Path) -> None:
    """An aigem before the settings were checked finite took --max-minutes inf (no limit), and
    run.json holds Infinity: the run still loads, with no limit."""
    run = _copy(RUN_0_1_0, tmp_path)
    _edit_info(run, lambda info: info["train"].update(max_minutes=math.inf))
    assert "Infinity" in (run / runs.RUN_INFO).read_text()
    assert records.read_record(run).info.train.max_minutes is None
    assert checkpoints.load_model(run)[1].train.max_minutes is None  # best.pt's too


def test_a_best_model_kept_before_a_resume_of_an_older_run_still_loads(tmp_path: Path) -> None:
    """Resuming an older run rewrites run.json with every setting; its best.pt, kept before,
    lacks the settings added since: the same model config, read with their defaults."""
    run = _copy(RUN_0_1_0, tmp_path)
    checkpoint = torch.load(run / runs.BEST, map_location="cpu", weights_only=True)
    del checkpoint["info"]["model"]["cv_residual"]
    torch.save(checkpoint, run / runs.BEST)
    model, info = checkpoints.load_model(run)
    assert model.config == ModelConfig() == info.model  # cv_residual read at its default
    checkpoint["info"]["model"]["hidden"] = 32  # another model: still refused
    torch.save(checkpoint, run / runs.BEST)
    with pytest.raises(NgsimInputError, match="belongs to another run: its model differs"):
        checkpoints.load_model(run)


# ------------------------------------------------------------------------------------------------
# Each checkpoint's sha256, recorded in run.json and checked before anything is computed.


def _flip_a_weight_bit(path: Path) -> None:
    """Flip one bit inside the largest weight tensor of a checkpoint (the same size, and
    loadable: only the numbers change, as in the reproduction d5)."""
    weights = torch.load(path, map_location="cpu", weights_only=True)["model"]
    raw = max(weights.values(), key=lambda tensor: tensor.numel()).numpy().tobytes()
    data = bytearray(path.read_bytes())
    at = data.find(raw) + len(raw) // 2
    assert at > len(raw) // 2
    data[at] ^= 0x20
    path.write_bytes(bytes(data))
    assert torch.load(path, map_location="cpu", weights_only=True)["model"].keys() == weights.keys()


def test_a_flipped_bit_in_best_pt_is_refused_before_any_number(
    trained_run: Path, tmp_path: Path
) -> None:
    run = _copy(trained_run, tmp_path)
    _flip_a_weight_bit(run / runs.BEST)
    result = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu", "--json"])
    assert _one_error_line(result, run / runs.BEST) == (
        f"error: {run / runs.BEST}: its bytes do not match the sha256 that run.json records for "
        "it: damaged or edited since fit kept it\n"
    )
    assert result.stdout == ""


@pytest.mark.parametrize("name", [runs.LAST, runs.BEST])
def test_a_resume_refuses_a_flipped_bit_in_either_checkpoint(
    trained_run: Path, tiny_build: Path, tmp_path: Path, name: str
) -> None:
    """last.pt is what a resume loads; best.pt what it would keep as the run's model."""
    run = _copy(trained_run, tmp_path)
    _flip_a_weight_bit(run / name)
    result = CliRunner().invoke(app, ["fit", str(tiny_build), "--out", str(run), "--resume", *FIT])
    assert "its bytes do not match the sha256 that run.json" in _one_error_line(result, run / name)
    assert [r.epoch for r in run_log.read_metrics(run)] == [1]


def test_a_checkpoint_that_run_json_does_not_record_is_refused(
    trained_run: Path, tmp_path: Path
) -> None:
    run = _copy(trained_run, tmp_path)
    document = json.loads((run / runs.RUN_INFO).read_text())
    del document[records.DIGESTS][runs.BEST]
    (run / runs.RUN_INFO).write_text(json.dumps(document))
    with pytest.raises(NgsimInputError, match="records no sha256 of it: not a checkpoint this run"):
        checkpoints.load_model(run)


class _Killed(BaseException):
    """A kill -9 in the middle of end_epoch's writes (nothing after it runs)."""


@pytest.mark.parametrize("killed_before", [0, 1, 2, 3, None])
def test_a_fit_killed_while_it_keeps_its_checkpoints_leaves_them_loadable(
    trained_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, killed_before: int | None
) -> None:
    """end_epoch's writes: run.json (both digests accepted), best.pt, last.pt, run.json (the new
    ones alone). Killed before any of them, the run's checkpoints still load, each one's bytes
    one that run.json accepts."""
    run = _copy(trained_run, tmp_path)
    kept = torch.load(run / runs.LAST, map_location="cpu", weights_only=True)
    model = AiGem(ModelConfig())
    optimizer = torch.optim.Adam(model.parameters())
    info = records.info_of(kept["info"], run / runs.LAST)
    writes, write_atomic = [], runs.write_atomic

    def write_or_die(path: Path, data: bytes) -> None:
        if len(writes) == killed_before:
            raise _Killed
        writes.append(path.name)
        write_atomic(path, data)

    monkeypatch.setattr(runs, "write_atomic", write_or_die)  # the checkpoints
    monkeypatch.setattr(records, "write_atomic", write_or_die)  # run.json
    state = records.RunState(1, 0, 1e9)  # the next epoch is the best yet: both checkpoints kept
    with pytest.raises(_Killed) if killed_before is not None else contextlib.nullcontext():
        runs.end_epoch(run, state, info, 1, 1.0, 2.0, model, optimizer, True)
    assert writes == [runs.RUN_INFO, runs.BEST, runs.LAST, runs.RUN_INFO][:killed_before]
    monkeypatch.undo()
    checkpoints.load_model(run)
    epochs = checkpoints.epochs_kept(run)
    assert epochs == (2 if killed_before in (3, None) else 1)
    accepted = json.loads((run / runs.RUN_INFO).read_text())[records.DIGESTS]
    assert len(accepted[runs.LAST]) == (2 if killed_before in (1, 2, 3) else 1)
    # A resume settles the record on what it finds.
    runs.start_run(run, info.build.build_dir, ModelConfig(), FAST, True, model, optimizer, True)
    settled = json.loads((run / runs.RUN_INFO).read_text())[records.DIGESTS]
    assert settled == {
        name: [hashlib.sha256((run / name).read_bytes()).hexdigest()]
        for name in (runs.BEST, runs.LAST)
    }
