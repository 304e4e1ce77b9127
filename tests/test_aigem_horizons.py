"""One model per horizon in one fit (the paper's protocol): each member is the single-horizon fit
of its horizon (in float64 to 1e-9; in float32 to float tolerance, see `_close_run`: the members
train as one ensemble, whose products sum in another order; a fit repeated is the same bit for
bit); members stop and resume on their own; `aigem evaluate RUN` takes RMSE at h s from the h s
model and ADE/FDE from the longest."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
from collections.abc import Iterator
from dataclasses import replace
from itertools import count
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig, check_horizons_s
from aigem.evaluation.evaluate import evaluate
from aigem.model.batch import Batch
from aigem.runs import checkpoints, folder, run_log
from aigem.runs.records import planned_group
from aigem.training import epochs, trainers
from aigem.training import fit as training
from aigem.training.ensemble import Ensemble
from aigem.training.fit import fit, fit_horizons
from ngsim_cli.aigem import app

# threads=1: bit-reproducible, so that a run can be compared with a run of the same models
TRAIN = TrainConfig(epochs=2, batch_size=8, seed=3, threads=1)
ARGS = ["--epochs", "2", "--batch-size", "8", "--seed", "3", "--threads", "1", "--device", "cpu"]
TIMING = ("train_seconds", "train_graphs_per_s", "val_seconds")


@pytest.fixture(scope="module")
def fitted(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A 1 s + 2 s run of two epochs, fitted through the CLI; (its directory, its stdout)."""
    run = tmp_path_factory.mktemp("horizons") / "run"
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(run), "--horizon-s", "2,1", *ARGS]
    )
    assert result.exit_code == 0, result.output
    return run, result.stdout


def _rows(run_dir: Path) -> list[dict[str, float]]:
    """metrics.jsonl without the timings."""
    rows = run_log.read_metrics(run_dir)
    return [{k: v for k, v in r.to_json().items() if k not in TIMING} for r in rows]


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["model"]


def _same_weights(a: Path, b: Path) -> bool:
    one, other = _weights(a), _weights(b)
    return one.keys() == other.keys() and all(torch.equal(one[k], other[k]) for k in one)


def _distance(a: Path, b: Path) -> float:
    """The L2 distance of two checkpoints' weights (all tensors as one vector), relative to b's."""
    one, other = _weights(a), _weights(b)
    assert one.keys() == other.keys()
    flat = [torch.cat([w[k].flatten() for k in one]) for w in (one, other)]
    return float((flat[0] - flat[1]).norm() / flat[1].norm())


def _close_weights(a: Path, b: Path, other: Path) -> bool:
    """a is nearer b than a quarter of its distance to `other`, the other horizon's model. A
    member trained in an ensemble is some 0.5% away from the model trained alone: float32 rounding
    (the ensemble sums in another order) grows through Adam, whose step divides each gradient by
    its own size, over the fit's 66 steps; the other horizon's model is some 6% away. A smoke
    test: `test_a_member_is_the_single_horizon_fit_in_float64` compares to 1e-9."""
    return _distance(a, b) < _distance(a, other) / 4


def _close_run(a: Path, b: Path, other: Path) -> bool:
    """The same run as `_same_run` says, to float tolerance: best and last weights close
    (`_close_weights`, `other` the other horizon's run), the same log but for the losses, which
    agree to 5% (the horizons' differ several-fold)."""
    rows, others = _rows(a), _rows(b)
    losses = ("train_loss_m2", "val_loss_m2")
    return (
        _close_weights(a / folder.BEST, b / folder.BEST, other / folder.BEST)
        and _close_weights(a / folder.LAST, b / folder.LAST, other / folder.LAST)
        and [{k: v for k, v in r.items() if k not in losses} for r in rows]
        == [{k: v for k, v in r.items() if k not in losses} for r in others]
        and all(
            r[k] == pytest.approx(o[k], rel=0.05)
            for r, o in zip(rows, others, strict=True)
            for k in losses
        )
    )


def _same_run(a: Path, b: Path) -> bool:
    """The same best and last weights and the same log (timings aside)."""
    return (
        _same_weights(a / folder.BEST, b / folder.BEST)
        and _same_weights(a / folder.LAST, b / folder.LAST)
        and _rows(a) == _rows(b)
    )


def test_the_layout_and_the_summary(fitted: tuple[Path, str]) -> None:
    run, out = fitted
    assert sorted(p.name for p in run.iterdir()) == [folder.FIT_LOG, "h1s", "h2s", folder.HORIZONS]
    assert json.loads((run / folder.HORIZONS).read_text()) == {
        "horizons_s": [1.0, 2.0],
        "members": ["h1s", "h2s"],
    }
    for name in ("h1s", "h2s"):
        files = sorted(p.name for p in (run / name).iterdir())
        owned = [
            folder.BASELINE,
            folder.BEST,
            folder.CURVES,
            folder.LAST,
            folder.METRICS,
            folder.RUN_INFO,
        ]
        assert files == sorted(owned)
    assert "1 s model: 2 epochs on cpu (the epochs asked); best epoch" in out
    assert f"Run: {run / 'h2s'}" in out.replace("\n", "")
    assert "2 models trained together" in out


def test_a_member_is_the_single_horizon_fit(
    fitted: tuple[Path, str], tiny_build: Path, tmp_path: Path
) -> None:
    run, _ = fitted
    alone = tmp_path / "alone"
    result = fit(
        tiny_build,
        alone,
        ModelConfig(),
        TrainConfig(**{**TRAIN.to_dict(), "horizon_s": 1.0}),
        "cpu",
    )
    assert _close_run(run / "h1s", alone, run / "h2s")
    assert not _close_run(run / "h2s", alone, run / "h1s")  # the test tells the horizons apart
    assert (run / "h1s" / folder.RUN_INFO).read_text() == (alone / folder.RUN_INFO).read_text()
    best = min(r.val_loss_m2 for r in run_log.read_metrics(run / "h1s"))
    assert result.best_val_loss_m2 == pytest.approx(best, rel=0.05)


# A fit in float64, where the ensemble's other order of summation is ~1e-16: with a cosine
# schedule after a warm-up, clipping and dropout, each member is the model trained alone to 1e-9.
F64_MODEL = ModelConfig(dropout=0.2)
F64_TRAIN = replace(TRAIN, lr_schedule="cosine", warmup_epochs=0.5, clip_grad_norm=0.3)


@pytest.fixture
def float64(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Models in float64 (the default dtype while the test runs) and batches too: their floating
    tensors cast as the training loop moves them to the device (`Batch.to`)."""

    real = Batch.to

    def to_in_float64(batch: Batch, device: torch.device, *args: object, **kwargs: object) -> Batch:
        return real(batch, device, torch.float64, kwargs.get("non_blocking", False))

    monkeypatch.setattr(Batch, "to", to_in_float64)  # the steps' and validation's
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        yield
    finally:
        torch.set_default_dtype(before)


def _assert_the_fit_alone(member: Path, alone: Path) -> None:
    """The same weights to 1e-9 and the same log, the losses and learning rates to 1e-9."""
    assert _weights(member / folder.LAST)["decoder.weight_ih"].dtype == torch.float64
    for name in (folder.BEST, folder.LAST):
        assert _distance(member / name, alone / name) < 1e-9
    rows, alone_rows = _rows(member), _rows(alone)
    assert [r.keys() for r in rows] == [r.keys() for r in alone_rows]
    for row, alone_row in zip(rows, alone_rows, strict=True):
        for key, value in row.items():
            assert value == pytest.approx(alone_row[key], rel=1e-9, abs=0.0), key


@pytest.mark.slow
def test_a_member_is_the_single_horizon_fit_in_float64(
    float64: None, tiny_build: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    fit_horizons(tiny_build, run, (1.0, 2.0), F64_MODEL, F64_TRAIN, "cpu")
    for horizon_s in (1.0, 2.0):
        alone = tmp_path / f"alone{horizon_s:g}"
        fit(tiny_build, alone, F64_MODEL, replace(F64_TRAIN, horizon_s=horizon_s), "cpu")
        _assert_the_fit_alone(run / f"h{horizon_s:g}s", alone)
    assert _distance(run / "h1s" / folder.LAST, run / "h2s" / folder.LAST) > 0.01  # they differ
    rates = [r.learning_rate for r in run_log.read_metrics(run / "h1s")]
    assert rates[0] > 10 * rates[1] > 0  # the cosine ran to near 0 by the end


@pytest.mark.slow
def test_a_time_limit_cuts_the_ensembles_epoch_as_a_models_alone(
    float64: None, tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A clock that advances 1 s each time the loop reads it (some 3 reads a batch, ~77 an
    epoch of the tiny build), so that 2 minutes run out in the second epoch, after the same batch
    in both fits: the models are unstacked and checkpointed after the batch the limit cut."""
    ticks = count()
    monkeypatch.setattr(epochs, "time", SimpleNamespace(monotonic=lambda: float(next(ticks))))
    train = replace(F64_TRAIN, epochs=3, max_minutes=2.0)
    run = tmp_path / "run"
    results = fit_horizons(tiny_build, run, (1.0, 2.0), F64_MODEL, train, "cpu")
    assert [(r.stopped_because, r.epochs_done) for r in results] == [("time limit", 2)] * 2
    first, cut = run_log.read_metrics(run / "h2s")
    assert 0 < cut.train_graphs < first.train_graphs
    alone = tmp_path / "alone"
    fit(tiny_build, alone, F64_MODEL, replace(train, horizon_s=2.0), "cpu")
    _assert_the_fit_alone(run / "h2s", alone)


def test_a_non_finite_loss_names_its_model(
    tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The 2 s model, the second member of the ensemble, gets NaN losses: the error names it."""
    real = Ensemble.member_losses

    def nan_for_the_2s_model(stacked: Ensemble, *args: object) -> torch.Tensor:
        losses = real(stacked, *args)
        return torch.where(torch.tensor(stacked.steps) == 10, torch.nan, losses)

    monkeypatch.setattr(Ensemble, "member_losses", nan_for_the_2s_model)
    with pytest.raises(epochs.NonFiniteLossError) as error:
        fit_horizons(tiny_build, tmp_path / "run", (1.0, 2.0), ModelConfig(), TRAIN, "cpu")
    assert str(error.value).startswith(
        "the 2 s model: non-finite training loss (nan) at epoch 1, batch"
    )


def test_each_member_keeps_its_own_best_model(fitted: tuple[Path, str]) -> None:
    run, _ = fitted
    for name, horizon_s in (("h1s", 1.0), ("h2s", 2.0)):
        best = torch.load(run / name / folder.BEST, map_location="cpu", weights_only=True)
        assert best["info"]["train"]["horizon_s"] == horizon_s
    assert not _same_weights(run / "h1s" / folder.BEST, run / "h2s" / folder.BEST)
    assert _rows(run / "h1s") != _rows(run / "h2s")


def test_one_member_stopping_early_leaves_the_others_training(
    fitted: tuple[Path, str], tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The 1 s model's validation loss rises (1, 2, ...): with patience 1 it stops after epoch 2;
    the 2 s model trains on, exactly as it would have."""
    real, rising = epochs.validation_losses, (float(i) for i in count(1))

    def rising_for_1s(*args: object) -> list[tuple[trainers.Member, float]]:
        return [
            (member, next(rising) if member.steps == 5 else loss) for member, loss in real(*args)
        ]

    monkeypatch.setattr(epochs, "validation_losses", rising_for_1s)
    run = tmp_path / "run"
    train = TrainConfig(**{**TRAIN.to_dict(), "epochs": 3, "patience_epochs": 1})
    short, long = fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), train, "cpu")
    assert (short.stopped_because, short.epochs_done, short.best_epoch) == ("early stopping", 2, 1)
    assert (long.stopped_because, long.epochs_done) == ("epochs", 3)
    assert [r.epoch for r in run_log.read_metrics(run / "h1s")] == [1, 2]
    assert _rows(run / "h2s")[:2] == _rows(fitted[0] / "h2s")  # unaffected by the other's stop
    again = fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), train, "cpu", resume=True)
    assert [r.stopped_because for r in again] == ["early stopping", "epochs"]  # nothing to train
    assert [r.epoch for r in run_log.read_metrics(run / "h1s")] == [1, 2]


@pytest.mark.slow
def test_a_resumed_run_ends_as_an_uninterrupted_one(
    fitted: tuple[Path, str], tiny_build: Path, tmp_path: Path
) -> None:
    straight, _ = fitted
    run = tmp_path / "run"
    one_epoch = TrainConfig(**{**TRAIN.to_dict(), "epochs": 1})
    fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), one_epoch, "cpu")
    after_one = (run / "h2s" / folder.LAST).read_bytes()
    fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), TRAIN, "cpu", resume=True)
    assert _same_run(run / "h1s", straight / "h1s") and _same_run(run / "h2s", straight / "h2s")
    # Killed in epoch 2 between the members' checkpoints: the 2 s model's row of epoch 2 is
    # logged, its last.pt is still epoch 1's. Only the 2 s model trains again, alone.
    (run / "h2s" / folder.LAST).write_bytes(after_one)
    document = json.loads((run / "h2s" / folder.RUN_INFO).read_text())  # as run.json then is:
    accepted = document[folder.DIGESTS][folder.LAST]  # accepting last.pt's old bytes and new ones
    accepted.insert(0, hashlib.sha256(after_one).hexdigest())
    (run / "h2s" / folder.RUN_INFO).write_text(json.dumps(document))
    h1s_last = (run / "h1s" / folder.LAST).read_bytes()
    short, long = fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), TRAIN, "cpu", resume=True)  # fmt: skip
    assert (short.epochs_done, short.stopped_because, long.epochs_done) == (2, "epochs", 2)
    assert (run / "h1s" / folder.LAST).read_bytes() == h1s_last
    assert _close_run(run / "h2s", straight / "h2s", straight / "h1s")
    # A member without any checkpoint (killed before its first: its marker is there) starts over.
    for name in (folder.LAST, folder.BEST, folder.METRICS):
        (run / "h1s" / name).unlink()
    (run / "h1s" / folder.STARTED).write_bytes(folder.STARTED_LINE)
    fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), TRAIN, "cpu", resume=True)
    assert _close_run(run / "h1s", straight / "h1s", straight / "h2s")  # trained alone


def test_a_ctrl_c_at_an_epochs_end_comes_once_every_model_kept_that_epoch(
    tiny_build: Path, tmp_path: Path
) -> None:
    """The models of a fit keep the same epoch, so that a resumed fit stacks them as an
    uninterrupted one does: a Ctrl-C while the first model's epoch is written waits for all."""
    run = tmp_path / "run"

    def ctrl_c_at_the_first(horizon_s: float, row: dict[str, float]) -> None:
        if horizon_s == 1.0:
            os.kill(os.getpid(), signal.SIGINT)

    train = TrainConfig(**{**TRAIN.to_dict(), "epochs": 1})
    with pytest.raises(KeyboardInterrupt):
        fit_horizons(
            tiny_build,
            run,
            (1.0, 2.0, 3.0),
            ModelConfig(),
            train,
            "cpu",
            on_epoch=ctrl_c_at_the_first,
        )
    assert [checkpoints.epochs_kept(run / f"h{h}s") for h in (1, 2, 3)] == [1, 1, 1]


def _alike(ours: float | None, theirs: float | None, kind: str) -> bool:
    """A metric of the one-pass evaluation against evaluate's of one model: constant velocity's
    exactly, the model's to float rounding (the models run stacked)."""
    if kind == "constant_velocity" or theirs is None:
        return ours == theirs
    return ours == pytest.approx(theirs, rel=1e-6)


def test_evaluate_takes_each_metric_from_its_model(fitted: tuple[Path, str]) -> None:
    run, _ = fitted
    result = CliRunner().invoke(app, ["evaluate", str(run), "--json", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    one, two = (evaluate(run / name, None, "test", "cpu") for name in ("h1s", "h2s"))
    for kind in ("model", "constant_velocity"):
        for region in ("all", "front", "mid", "rear"):
            ours, one_s, two_s = (
                document[kind][region],
                getattr(one, kind)[region],
                getattr(two, kind)[region],
            )
            assert _alike(ours["rmse_1s_m"], one_s["rmse_1s_m"], kind)
            assert ours["n_1s"] == one_s["n_1s"] and ours["n_2s"] == two_s["n_2s"]
            for key in ("rmse_2s_m", "ade_m", "fde_m"):
                assert _alike(ours[key], two_s[key], kind)
    assert document["model"]["all"]["rmse_1s_m"] != two.model["all"]["rmse_1s_m"]  # another model
    assert document["sources"]["rmse_1s_m"] == "h1s" and document["sources"]["fde_m"] == "h2s"
    assert document["horizons_s"] == [1.0, 2.0] and set(document["members"]) == {"h1s", "h2s"}
    assert document["parameters"] == 74_242 and "AiGem (paper)" in document["paper"]
    table = CliRunner().invoke(app, ["evaluate", str(run), "--device", "cpu"]).stdout
    assert (
        "2 models, one per horizon (1 and 2 s): RMSE at h s from the model trained for h s; ADE "
        "and FDE over 2 s from the 2 s model, the paper's over 5 s. Constant velocity likewise, on "
        "the same targets." in " ".join(table.split())
    )
    assert "RMSE 2 s" in table and "RMSE 3 s" not in table.split("the paper's table")[0]
    assert "synthetic" in table and "AiGem (this run)" in table


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("0", "0 s is not a horizon in (0, 5] s"),
        ("6", "6 s is not a horizon in (0, 5] s"),
        ("a", "'a' is not a number of seconds"),
        ("1,2,1", "1 s given more than once"),
        ("0.1,1", "0.1 s is shorter than one time step (0.2 s)"),
    ],
)
def test_bad_horizons_are_one_line_and_exit_2(
    tiny_build: Path, tmp_path: Path, value: str, message: str
) -> None:
    run = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["fit", str(tiny_build), "--out", str(run), "--horizon-s", value, *ARGS]
    )
    assert result.exit_code == 2 and result.stderr == f"error: --horizon-s {value}: {message}\n"
    assert not run.exists()


def test_a_multi_horizon_run_is_started_and_resumed_as_such_only(
    fitted: tuple[Path, str], tiny_build: Path, tmp_path: Path
) -> None:
    run = Path(shutil.copytree(fitted[0], tmp_path / "run"))
    runner = CliRunner()

    def error(horizons: str, *more: str, out: Path = run) -> str:
        result = runner.invoke(
            app, ["fit", str(tiny_build), "--out", str(out), "--horizon-s", horizons, *ARGS, *more]
        )
        assert result.exit_code == 1 and result.stderr.count("\n") == 1, result.output
        return result.stderr

    assert (
        error("1,2")
        == f"error: {run}: already holds a run; pass --resume to continue it, or choose another --out\n"
    )
    assert error("1,3", "--resume") == (
        f"error: {run}: cannot resume with other horizons (1,2 -> 1,3 s): it changes what the run learns\n"
    )  # fmt: skip
    # a run is a group: one horizon into a run of two is refused as any other horizons are
    assert error("2") == (
        f"error: {run}: already holds a run; pass --resume to continue it, or choose another --out\n"
    )  # fmt: skip
    assert error("2", "--resume") == (
        f"error: {run}: cannot resume with other horizons (1,2 -> 2 s): it changes what the run learns\n"
    )  # fmt: skip
    assert "nothing to resume: no last.pt" in error("1,2", "--resume", out=tmp_path / "new")
    single = tmp_path / "single"
    fit(tiny_build, single, ModelConfig(), TrainConfig(**{**TRAIN.to_dict(), "epochs": 1}), "cpu")
    assert error("1,2", out=single) == (
        f"error: {single}: already holds a run; pass --resume to continue it, or choose another --out\n"
    )  # fmt: skip
    assert error("1,2", "--resume", out=single) == (
        f"error: {single}: cannot resume with other horizons (5 -> 1,2 s): it changes what the run learns\n"
    )  # fmt: skip
    assert _rows(run / "h1s") == _rows(fitted[0] / "h1s")  # nothing was changed


def test_a_horizon_is_at_least_one_time_step() -> None:
    """A horizon of 0 steps would train a model that predicts nothing (and AiGem reads 0 steps
    as its future_steps)."""
    with pytest.raises(ValueError, match=r"^horizon_s must be at least one time step \(0.2 s\)$"):
        TrainConfig(horizon_s=0.1)
    with pytest.raises(ValueError, match=r"^0.19 s is shorter than one time step \(0.2 s\)$"):
        check_horizons_s((1.0, 0.19))
    assert check_horizons_s((1.0, 0.2)) == (0.2, 1.0)
    assert TrainConfig(horizon_s=0.2).horizon_steps(0.2) == 1
    assert TrainConfig(horizon_s=1.0).horizon_steps(0.2) == 5
    with pytest.raises(ValueError, match=r"^a 0.2 s horizon is less than one time step \(0.5 s\)$"):
        TrainConfig(horizon_s=0.2).horizon_steps(0.5)  # a build on a coarser grid


def test_a_horizon_shorter_than_the_builds_time_step_is_refused_before_any_directory(
    tiny_build: Path, tmp_path: Path
) -> None:
    """On a build of 0.5 s steps 0.2 s rounds to 0 steps: refused, and no run directory made."""
    run = tmp_path / "run"
    with pytest.raises(ValueError, match=r"^a 0.2 s horizon is less than one time step"):
        arguments = (tiny_build, planned_group(run, (0.2, 1.0)), ModelConfig(), TRAIN)
        training._start_members(*arguments, resume=False, time_step_s=0.5, loop=None)
    assert not run.exists()
