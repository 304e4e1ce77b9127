"""The learning rate of each step (hand-computed), gradient clipping, and fit with a schedule:
the rates logged, a resume that matches an uninterrupted run, and what a resume may not change."""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from aigem_fixtures import record_checkpoint
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig
from aigem.model.network import AiGem
from aigem.runs import folder, run_log
from aigem.training.fit import fit
from aigem.training.schedule import clip_gradients, learning_rate_at
from ngsim_cli.aigem import app
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimInputError


def _rates(train: TrainConfig, batches: int) -> list[float]:
    return [
        learning_rate_at(train, epoch, batch, batches)
        for epoch in range(train.epochs)
        for batch in range(batches)
    ]


def test_constant_is_the_paper_rate_at_every_step() -> None:
    assert _rates(TrainConfig(epochs=3, learning_rate=2e-3), 4) == [2e-3] * 12


def test_warmup_rises_linearly_then_holds() -> None:
    rates = _rates(TrainConfig(epochs=3, learning_rate=1.0, warmup_epochs=1.5), 2)
    assert rates == [1 / 3, 2 / 3, 1.0, 1.0, 1.0, 1.0]


def test_a_warmup_ending_within_a_step_never_passes_the_rate() -> None:
    rates = _rates(TrainConfig(epochs=2, learning_rate=1.0, warmup_epochs=0.5), 3)  # 1.5 steps
    assert rates == pytest.approx([2 / 3, 1.0, 1.0, 1.0, 1.0, 1.0])
    tiny = _rates(TrainConfig(epochs=2, learning_rate=1.0, warmup_epochs=0.01), 50)  # 0.5 steps
    assert max(tiny) == 1.0


def test_cosine_falls_along_half_a_cosine_to_zero() -> None:
    rates = _rates(TrainConfig(epochs=2, learning_rate=1.0, lr_schedule="cosine"), 2)
    # 0.5 (1 + cos(pi s / 4)) for steps s = 0..3: the last step's rate is the last above 0
    assert rates == pytest.approx([1.0, 0.8535534, 0.5, 0.1464466])


def test_cosine_starts_after_the_warmup() -> None:
    train = TrainConfig(epochs=3, learning_rate=1.0, lr_schedule="cosine", warmup_epochs=1)
    assert _rates(train, 2) == pytest.approx([0.5, 1.0, 1.0, 0.8535534, 0.5, 0.1464466])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("learning_rate", 0.0, "learning_rate must be a finite number > 0, not 0"),
        ("learning_rate", math.nan, "learning_rate must be a finite number > 0, not nan"),
        ("lr_schedule", "linear", "lr_schedule must be one of constant, cosine"),
        ("warmup_epochs", 2.0, "warmup_epochs must be >= 0 and fewer than epochs"),
        ("warmup_epochs", -0.5, "warmup_epochs must be a finite number >= 0, not -0.5"),
        ("warmup_epochs", math.nan, "warmup_epochs must be a finite number >= 0, not nan"),
        ("clip_grad_norm", 0.0, "clip_grad_norm must be a finite number > 0, not 0"),
        ("clip_grad_norm", math.inf, "clip_grad_norm must be a finite number > 0, not inf"),
        ("max_minutes", math.inf, "max_minutes must be a finite number > 0, not inf"),
        (
            "seed",
            2**32,
            "seed must be a whole number from 0 to 4294967295 (2**32 - 1), not 4294967296",
        ),
        ("horizon_s", 0.3, "horizon_s must be a multiple of the 0.2 s time step"),
    ],
)
def test_bad_settings_are_refused(field: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        TrainConfig(epochs=2, **{field: value})


def test_clipping_scales_a_long_gradient_down_and_leaves_a_short_one() -> None:
    """Each member's gradients (stacked, (M, ...)) clipped on their own total norm (to 1e-6:
    clip_grad_norm_'s own epsilon)."""
    long, short = torch.zeros(2, 2, requires_grad=True), torch.zeros(2, 1, requires_grad=True)
    long.grad = torch.tensor([[3.0, 0.0], [0.3, 0.0]])  # member 0: total norm 5; member 1: 0.5
    short.grad = torch.tensor([[4.0], [0.4]])

    def close(*values: list[float]) -> list:
        return [pytest.approx(value, abs=1e-5) for value in values]

    clip_gradients([long, short], 1.0)
    assert long.grad.tolist() == close([0.6, 0.0], [0.3, 0.0])
    assert short.grad.tolist() == close([0.8], [0.4])
    clip_gradients([long, short], 0.8)  # norms 1 and 0.5 now: the first only
    assert long.grad.tolist() == close([0.48, 0.0], [0.3, 0.0])
    clip_gradients([long, short], None)
    assert short.grad.tolist() == close([0.64], [0.4])
    assert short.grad[1].tolist() == [pytest.approx(0.4, rel=1e-7)]  # never scaled


class _Stop(Exception):
    """Ends a fit after its first epoch's checkpoint, as a kill would."""


def _stop_after_first_epoch(horizon_s: float, row: dict[str, float]) -> None:
    raise _Stop


SCHEDULED = TrainConfig(
    epochs=2,
    batch_size=8,
    horizon_s=1.0,
    seed=3,
    learning_rate=2e-3,
    lr_schedule="cosine",
    warmup_epochs=0.5,
    clip_grad_norm=5.0,
)


@pytest.mark.slow
def test_a_scheduled_run_logs_its_rates_and_resumes_like_an_uninterrupted_one(
    tiny_build: Path, tmp_path: Path
) -> None:
    straight = fit(tiny_build, tmp_path / "straight", ModelConfig(), SCHEDULED, "cpu")
    rows = run_log.read_metrics(tmp_path / "straight")
    train_graphs = int(open_build(tiny_build).manifest.splits["train"])
    assert [r.train_graphs for r in rows] == [train_graphs, train_graphs]
    batches = math.ceil(train_graphs / SCHEDULED.batch_size)
    assert [r.learning_rate for r in rows] == pytest.approx(
        [learning_rate_at(SCHEDULED, e, batches - 1, batches) for e in (0, 1)]
    )
    assert rows[1].learning_rate < rows[0].learning_rate < SCHEDULED.learning_rate
    with pytest.raises(_Stop):
        fit(
            tiny_build,
            tmp_path / "resumed",
            ModelConfig(),
            SCHEDULED,
            "cpu",
            on_epoch=_stop_after_first_epoch,
        )
    with pytest.raises(
        NgsimInputError,
        match="another epochs 2 -> 3: the cosine schedule decays over the run's epochs; resume with --epochs 2",
    ):
        longer = TrainConfig(**{**SCHEDULED.to_dict(), "epochs": 3})
        fit(tiny_build, tmp_path / "resumed", ModelConfig(), longer, "cpu", resume=True)
    unclipped = TrainConfig(**{**SCHEDULED.to_dict(), "clip_grad_norm": None})
    with pytest.raises(NgsimInputError, match="another clip_grad_norm 5.0 -> None"):
        fit(tiny_build, tmp_path / "resumed", ModelConfig(), unclipped, "cpu", resume=True)
    resumed = fit(tiny_build, tmp_path / "resumed", ModelConfig(), SCHEDULED, "cpu", resume=True)
    assert resumed.epochs_done == straight.epochs_done == 2
    again = run_log.read_metrics(tmp_path / "resumed")
    assert [r.val_loss_m2 for r in again] == pytest.approx([r.val_loss_m2 for r in rows], rel=1e-5)


def test_each_step_runs_at_its_scheduled_rate(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = []  # Adam's rate when it steps
    adam_step = torch.optim.Adam.step

    def step(self, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        seen.append(self.param_groups[0]["lr"])
        return adam_step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", step)
    fit(tiny_build, tmp_path / "run", ModelConfig(), SCHEDULED, "cpu")
    batches = math.ceil(int(open_build(tiny_build).manifest.splits["train"]) / 8)
    assert seen == _rates(SCHEDULED, batches)


def test_clipping_reaches_the_optimizer(tiny_build: Path, tmp_path: Path) -> None:
    """Gradients clipped to a norm of 1e-12 are far below Adam's eps: the weights stay put."""
    torch.manual_seed(SCHEDULED.seed)  # fit initialises the model from the same seed
    start = AiGem(ModelConfig()).state_dict()
    moved = {}
    for clip in (None, 1e-12):
        train = replace(SCHEDULED, clip_grad_norm=clip, epochs=1, warmup_epochs=0.0)
        fit(tiny_build, tmp_path / str(clip), ModelConfig(), train, "cpu")
        end = torch.load(tmp_path / str(clip) / folder.LAST, weights_only=True)["model"]
        moved[clip] = max(float((end[k] - start[k]).abs().max()) for k in start)
    assert moved[None] > 1e-3 and moved[1e-12] < 1e-5


def test_the_cli_passes_the_settings_and_refuses_bad_ones(tiny_build: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    args = ["fit", str(tiny_build), "--epochs", "2", "--batch-size", "8", "--horizon-s", "1",
            "--device", "cpu"]  # fmt: skip
    bad = runner.invoke(app, [*args, "--out", str(tmp_path / "bad"), "--lr-schedule", "linear"])
    assert bad.exit_code == 2 and "Invalid value for '--lr-schedule'" in bad.stderr
    assert not (tmp_path / "bad").exists()
    settings = ["--learning-rate", "2e-3", "--lr-schedule", "cosine", "--warmup-epochs", "0.5",
                "--clip-grad-norm", "5"]  # fmt: skip
    good = runner.invoke(app, [*args, "--out", str(tmp_path / "run"), *settings])
    assert good.exit_code == 0, good.output
    train = json.loads((tmp_path / "run" / folder.RUN_INFO).read_text())["train"]
    assert (train["learning_rate"], train["lr_schedule"]) == (2e-3, "cosine")
    assert (train["warmup_epochs"], train["clip_grad_norm"]) == (0.5, 5.0)


def test_a_run_of_an_older_aigem_resumes_as_the_constant_rate_it_trained_with(
    tiny_build: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    config = TrainConfig(epochs=1, batch_size=8, horizon_s=1.0, seed=3)
    fit(tiny_build, run, ModelConfig(), config, "cpu")
    checkpoint = torch.load(run / folder.LAST, weights_only=True)
    for key in (
        "lr_schedule",
        "warmup_epochs",
        "clip_grad_norm",
    ):  # as an aigem without schedules wrote it
        del checkpoint["info"]["train"][key]
    torch.save(checkpoint, run / folder.LAST)
    record_checkpoint(run / folder.LAST)  # as that aigem's fit kept it
    longer = TrainConfig(**{**config.to_dict(), "epochs": 2})
    assert fit(tiny_build, run, ModelConfig(), longer, "cpu", resume=True).epochs_done == 2
    warmed = TrainConfig(**{**longer.to_dict(), "warmup_epochs": 1.0})
    with pytest.raises(NgsimInputError, match="another warmup_epochs 0.0 -> 1.0"):
        fit(tiny_build, run, ModelConfig(), warmed, "cpu", resume=True)
