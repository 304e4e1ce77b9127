"""Training: the loss falls, checkpoints resume, errors are clear; the CLI end to end; DDP."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig
from aigem.runs import folder, run_log
from aigem.training.epochs import NonFiniteLossError
from aigem.training.fit import fit
from ngsim_cli.aigem import app
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.pipeline import run_build

FAST = TrainConfig(epochs=1, batch_size=8, horizon_s=1.0, seed=3)


def test_fit_then_resume_finishes_like_an_uninterrupted_run(
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    config = TrainConfig(epochs=2, batch_size=8, horizon_s=1.0, seed=3)
    straight = fit(tiny_build, tmp_path / "straight", ModelConfig(), config, "cpu")
    assert straight.epochs_done == 2 and straight.parameters == 74_242
    # "Interrupted" after epoch 1: run one epoch, then resume to two.
    fit(
        tiny_build,
        tmp_path / "resumed",
        ModelConfig(),
        TrainConfig(**{**config.to_dict(), "epochs": 1}),
        "cpu",
    )
    resumed = fit(tiny_build, tmp_path / "resumed", ModelConfig(), config, "cpu", resume=True)
    assert resumed.epochs_done == 2
    a, b = run_log.read_metrics(tmp_path / "straight"), run_log.read_metrics(tmp_path / "resumed")
    assert [r.epoch for r in b] == [1, 2]
    assert b[1].val_loss_m2 == pytest.approx(a[1].val_loss_m2, rel=1e-5)
    for name in (folder.BEST, folder.LAST, folder.METRICS, folder.RUN_INFO, folder.CURVES):
        assert (tmp_path / "resumed" / name).is_file()
    assert not list((tmp_path / "resumed").glob("*.partial*"))


def test_a_fit_on_static_batches_is_the_fit_on_the_loaders_without_dropout(
    tiny_build: Path, tmp_path: Path
) -> None:
    """The splits on the device (here the CPU): the loader's samples in the loader's batches,
    the same steps, so the first epoch's train loss to float rounding (validation's after the
    epoch, whose weights float32's rounding has moved through Adam, to 1 %). With dropout the
    masks, drawn over the padded nodes, are others (docs/aigem.md)."""
    train = FAST  # 1 epoch
    rows = {}
    for resident in (False, True):
        run = tmp_path / f"resident-{resident}"
        fit(tiny_build, run, ModelConfig(dropout=0.0), replace(train, resident=resident), "cpu")
        rows[resident] = run_log.read_metrics(run)[0]
    assert rows[True].train_graphs == rows[False].train_graphs
    assert rows[True].train_loss_m2 == pytest.approx(rows[False].train_loss_m2, rel=1e-4)
    assert rows[True].val_loss_m2 == pytest.approx(rows[False].val_loss_m2, rel=1e-2)


def test_a_second_fit_into_a_run_needs_resume(tiny_build: Path, tmp_path: Path) -> None:
    fit(tiny_build, tmp_path / "run", ModelConfig(), FAST, "cpu")
    with pytest.raises(NgsimInputError, match="already holds a run"):
        fit(tiny_build, tmp_path / "run", ModelConfig(), FAST, "cpu")
    with pytest.raises(NgsimInputError, match="nothing to resume"):
        fit(tiny_build, tmp_path / "other", ModelConfig(), FAST, "cpu", resume=True)


def test_non_finite_loss_stops_with_a_clear_error(tiny_build: Path, tmp_path: Path) -> None:
    with pytest.raises(NonFiniteLossError, match="non-finite training loss"):
        fit(
            tiny_build,
            tmp_path / "run",
            ModelConfig(),
            TrainConfig(**{**FAST.to_dict(), "learning_rate": 1e30}),
            "cpu",
        )


def test_cli_fit_and_evaluate(tiny_build: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    run = tmp_path / "run"
    result = runner.invoke(app, ["fit", str(tiny_build), "--out", str(run), "--epochs", "1",
                                 "--batch-size", "8", "--horizon-s", "2", "--device", "cpu"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "74,242 parameters" in result.stdout
    row = run_log.read_metrics(run)[0]
    assert row.train_seconds > 0 and row.train_graphs_per_s > 0 and row.val_seconds >= 0
    assert (
        f"epoch 1: train MSE {row.train_loss_m2:.3f} m², validation MSE {row.val_loss_m2:.3f} m² (best)"
        in result.stderr
    )
    result = runner.invoke(
        app, ["evaluate", str(run), "--data", str(tiny_build), "--json", "--device", "cpu"]
    )
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["horizon_steps"] == 10 and document["parameters"] == 74_242
    assert set(document["model"]) == {"all", "front", "mid", "rear"}
    assert document["model"]["all"]["n_1s"] == document["constant_velocity"]["all"]["n_1s"] > 0
    assert "rmse_3s_m" not in document["model"]["all"]
    table = runner.invoke(app, ["evaluate", str(run), "--data", str(tiny_build), "--device", "cpu"])
    assert "constant velocity" in table.stdout and "synthetic" in table.stdout
    assert "│       74.2 │" in table.stdout  # the params (K) column of this run's row
    bad = runner.invoke(app, ["evaluate", str(tmp_path / "nope"), "--data", str(tiny_build)])
    assert (
        bad.exit_code == 1 and bad.stderr == f"error: {tmp_path / 'nope'}: no such run directory\n"
    )


@pytest.mark.slow
def test_distributed_training_with_two_cpu_processes(tiny_build: Path, tmp_path: Path) -> None:
    run = tmp_path / "ddp"
    command = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port", "29533",
               "-m", "ngsim_cli.aigem", "fit", str(tiny_build), "--out", str(run), "--epochs", "1",
               "--batch-size", "4", "--horizon-s", "1", "--device", "cpu"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        command, capture_output=True, text=True, timeout=300, env=env, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert [r.epoch for r in run_log.read_metrics(run)] == [1]
    assert (run / folder.BEST).is_file()


EMPTY_VAL = (
    "the validation split (val) is empty: `aigem fit` keeps the best checkpoint and stops early "
    "by validation loss"
)
EMPTY_TRAIN = "the train split (train) is empty: there is nothing to train on (and the scaler is fitted on it)"


@pytest.mark.parametrize(
    ("fractions", "split", "message"),
    [((0.9, 0.0, 0.1), "val", EMPTY_VAL), ((0.0, 0.5, 0.5), "train", EMPTY_TRAIN)],
)
def test_fit_refuses_an_empty_train_or_validation_split(
    tiny_build: Path,
    tmp_path: Path,
    fractions: tuple[float, float, float],
    split: str,
    message: str,
) -> None:
    build, run = tmp_path / "build", tmp_path / "run"
    config = BuildConfig(d_sense_m=12.0, d_min_m=6.0, split_fractions=fractions)
    run_build([tiny_build.parent / "raw"], build, config)
    assert json.loads((build / "manifest.json").read_text())["splits"][split] == 0
    result = CliRunner().invoke(
        app, ["fit", str(build), "--out", str(run), "--epochs", "1", "--device", "cpu"]
    )
    assert result.exit_code == 1
    assert (
        result.stderr
        == f"error: {build}: {message}; rebuild with other split fractions or more data\n"
    )
    assert not run.exists()  # stopped before training: no run directory
