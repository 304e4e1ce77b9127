"""`aigem evaluate`: on the run's own build by default; another build only when asked, and then
scaled with the run's scaler; incompatible builds and non-finite predictions are one error line."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from aigem_fixtures import record_checkpoint
from typer.testing import CliRunner

from aigem.config import ModelConfig, TrainConfig
from aigem.evaluation.evaluate import evaluate, target_choice
from aigem.evaluation.results import as_dict
from aigem.evaluation.scoring import score_targets
from aigem.intervals import RESAMPLES, SampleIntervals
from aigem.model.data import GraphDataset
from aigem.runs import checkpoints, folder, records
from aigem.training.ensemble import Ensemble
from aigem.training.fit import fit
from ngsim_cli.aigem import app
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import write_manifest_json
from ngsim_graphs.pipeline import run_build

TINY = {"d_sense_m": 12.0, "d_min_m": 6.0}  # the settings of aigem_fixtures' tiny build


@pytest.fixture(scope="module")
def trained_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("evaluation") / "run"
    fit(
        tiny_build,
        run,
        ModelConfig(),
        TrainConfig(epochs=1, batch_size=8, horizon_s=2.0, seed=3),
        "cpu",
    )
    return run


def _build(tiny_build: Path, out: Path, **settings: object) -> Path:
    """Another build of the tiny build's raw input."""
    run_build([tiny_build.parent / "raw"], out, BuildConfig(**{**TINY, **settings}))
    return out


def _evaluate(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, ["evaluate", *args, "--json", "--device", "cpu"])
    return result.exit_code, result.stdout, result.stderr


def test_data_defaults_to_the_runs_own_build(trained_run: Path, tiny_build: Path) -> None:
    code, out, err = _evaluate(str(trained_run))
    assert code == 0, err
    document = json.loads(out)
    assert document["build_dir"] == str(tiny_build.resolve()) and document["same_build"] is True
    code, named, _ = _evaluate(str(trained_run), "--data", str(tiny_build))
    assert code == 0 and json.loads(named)["model"] == document["model"]


def test_another_build_needs_the_flag(trained_run: Path, tiny_build: Path, tmp_path: Path) -> None:
    # neighbours within 8 m, not 12: the test samples' graphs lose the farther ones (the tiny
    # build's test graphs hold no two actors within 12 m of each other, so d_min changes nothing)
    other = _build(tiny_build, tmp_path / "dsense8", d_sense_m=8.0)
    code, _, err = _evaluate(str(trained_run), "--data", str(other))
    theirs = json.loads((other / "manifest.json").read_text())["config_hash"][:12]
    ours = json.loads((tiny_build / "manifest.json").read_text())["config_hash"][:12]
    assert code == 1 and err == (
        f"error: {other}: not the build that run {trained_run} was trained on (its config hash "
        f"{theirs} is not the run's {ours}: d_sense_m 12.0 -> 8.0); pass --other-build to evaluate "
        "on another build\n"
    )
    code, out, err = _evaluate(str(trained_run), "--data", str(other), "--other-build")
    assert code == 0, err
    document = json.loads(out)
    assert document["same_build"] is False and document["build_dir"] == str(other)
    _, own, _ = _evaluate(str(trained_run))
    assert (
        document["model"]["all"]["ade_m"] != json.loads(own)["model"]["all"]["ade_m"]
    )  # other edges


def test_another_build_is_scaled_with_the_runs_scaler(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    """The same graphs under a manifest with another scaler: with --other-build the numbers are
    the run's own (the run's scaler is used); with the edited build's scaler they would differ."""
    edited = Path(shutil.copytree(tiny_build, tmp_path / "edited"))
    manifest = json.loads((edited / "manifest.json").read_text())
    manifest["scaler"]["x_m"]["max"] += 5.0
    manifest["scaler"]["speed_mps"]["max"] *= 2.0
    write_manifest_json(edited, manifest)  # sealed anew, as a build of other train data would be
    code, _, err = _evaluate(str(trained_run), "--data", str(edited))
    assert code == 1 and "(same config, but its manifest.json differs from the run's build" in err
    own = evaluate(trained_run, None, "test", "cpu")
    other = evaluate(trained_run, edited, "test", "cpu", other_build=True)
    assert other.model == own.model and other.constant_velocity == own.constant_velocity
    assert not other.same_build and own.same_build
    # The override matters: the edited build's own scaler gives other predictions.
    model, _ = checkpoints.load_model(trained_run)
    dataset = GraphDataset(edited, "test", model.config.history_steps_read)
    assert dataset.scaler.to_dict() == manifest["scaler"]
    totals = score_targets(model, dataset, own.horizon_steps, torch.device("cpu")).model
    edited_ade = totals.error_m[0].sum() / totals.count[0].sum()
    assert totals.count[0, 4] == own.model["all"]["n_1s"]  # the same targets
    assert abs(edited_ade - own.model["all"]["ade_m"]) > 0.01


def test_an_incompatible_build_is_refused_even_with_the_flag(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    short = _build(tiny_build, tmp_path / "short", history_steps=4, future_steps=8)
    code, _, err = _evaluate(str(trained_run), "--data", str(short), "--other-build")
    assert code == 1 and err == (
        f"error: {short}: its graphs have 4 history and 8 future steps; the run's model reads 5 and "
        "predicts 10\n"
    )


def test_the_runs_build_gone_is_one_error_line(trained_run: Path, tmp_path: Path) -> None:
    run = Path(shutil.copytree(trained_run, tmp_path / "run"))
    gone = tmp_path / "gone"
    checkpoint = torch.load(run / folder.BEST, map_location="cpu", weights_only=True)
    checkpoint["info"]["build_dir"] = str(gone)
    torch.save(checkpoint, run / folder.BEST)
    record_checkpoint(run / folder.BEST)  # as fit records what it keeps
    code, _, err = _evaluate(str(run))
    assert (
        code == 1
        and err
        == f"error: {gone}: the run's build is gone (or unfinished); pass --data to name it\n"
    )


def test_non_finite_predictions_stop_with_one_line(trained_run: Path, tmp_path: Path) -> None:
    run = Path(shutil.copytree(trained_run, tmp_path / "run"))
    checkpoint = torch.load(run / folder.BEST, map_location="cpu", weights_only=True)
    checkpoint["model"]["output.2.bias"][0] = float("nan")
    torch.save(checkpoint, run / folder.BEST)
    record_checkpoint(run / folder.BEST)  # as fit records what it keeps
    code, out, err = _evaluate(str(run))
    assert code == 1 and out == "" and err.count("\n") == 1
    assert err.startswith(f"error: {run / folder.BEST}: the model's predictions on ")
    assert "are not finite (NaN or infinite); no metrics" in err


def test_an_empty_split_is_one_error_line_not_empty_metrics(
    trained_run: Path,
    tiny_build: Path,
    tmp_path: Path,
) -> None:
    no_val = _build(tiny_build, tmp_path / "no-val", split_fractions=(0.9, 0.0, 0.1))
    code, out, err = _evaluate(
        str(trained_run), "--data", str(no_val), "--other-build", "--split", "val"
    )
    assert (
        code == 1
        and out == ""
        and err == f"error: {no_val}: its val split is empty: nothing to evaluate\n"
    )


def test_target_choice_by_hand() -> None:
    # Targets 0..9 of samples 0, 0, 1, 2, 2, 2, 3, 4, 5, 6 with final errors 1, 3, 9, 3, 4, 5,
    # 1, 6, 3, 5 m. Best first: 0 (1), 6 (1), 1 (3), 3 (3), 8 (3), 4 (4), 5 (5), 9 (5), 7 (6),
    # 2 (9); worst first: 2, 7, 5, 9, 4, 1, 3, 8, 0, 6.
    sample = np.array([0, 0, 1, 2, 2, 2, 3, 4, 5, 6])
    error_m = np.array([1.0, 3.0, 9.0, 3.0, 4.0, 5.0, 1.0, 6.0, 3.0, 5.0])
    chosen = target_choice(sample, error_m, per_group=3)
    assert chosen["best"].tolist() == [0, 6, 3]  # 1 is of sample 0, as 0 is: one per scene
    assert chosen["worst"].tolist() == [2, 7, 5]
    # From the middle on, (10 - 3) // 2 = 3: 3 (sample 2), 8 (5), 4 (2: taken), 5 (2), 9 (6)
    assert chosen["median"].tolist() == [3, 8, 9]
    few = target_choice(np.array([4, 9]), np.array([1.0, 1.0]), per_group=3)  # a tie: lower
    assert few["best"].tolist() == [0, 1] and few["worst"].tolist() == [0, 1]


def test_per_step_curves_and_final_errors_agree_with_the_table(trained_run: Path) -> None:
    result = evaluate(trained_run, None, "test", "cpu")
    table, curves = result.model["all"], result.steps["model"]["all"]
    assert result.horizon_steps == 10 and len(curves["rmse_m"]) == 10  # 2 s at 0.2 s
    assert curves["rmse_m"][4] == pytest.approx(table["rmse_1s_m"])
    assert curves["rmse_m"][9] == pytest.approx(table["rmse_2s_m"])
    assert curves["mean_error_m"][-1] == pytest.approx(table["fde_m"])
    final = result.final
    assert len(final.model_m) == curves["n"][-1] == table["n_2s"]
    assert final.model_m.mean() == pytest.approx(table["fde_m"])
    assert final.constant_velocity_m.mean() == pytest.approx(
        result.constant_velocity["all"]["fde_m"]
    )
    assert set(final.sample.tolist()) <= set(range(result.samples))
    document = json.loads(json.dumps(as_dict(result)))  # JSON-ready: no arrays
    (member,) = document["members"].values()  # a run of one model: a group of one
    assert "final" not in member and member["steps"]["constant_velocity"]["all"]["n"][0] > 0


def test_each_final_error_is_tied_to_its_own_sample(trained_run: Path) -> None:
    """A batch holds its graphs by recording, not in index order: the sample of each final error
    is the same whether the samples come one by one or in batches of any size."""
    model, info = checkpoints.load_model(trained_run)
    dataset = GraphDataset(info.build.build_dir, "test", 5)
    pairs = {}
    for batch_size in (1, 5, 64):
        final = score_targets(model, dataset, 10, torch.device("cpu"), batch_size).final
        order = np.lexsort((final.model_m, final.sample))  # by sample, then error
        pairs[batch_size] = (final.sample[order], final.model_m[order])
    for batch_size in (5, 64):  # the same samples with the same errors, up to float rounding
        assert pairs[batch_size][0].tolist() == pairs[1][0].tolist()
        np.testing.assert_allclose(pairs[batch_size][1], pairs[1][1], atol=1e-3)
    assert len(set(pairs[1][0].tolist())) > 1


# ------------------------------------------------------------------------------------------------
# A multi-horizon run: its models in one pass over the split (aigem.evaluation.scoring.score_members)


def _close_rows(ours: object, theirs: object, key: str = "") -> None:
    """Two evaluations' rows (or per-step curves) alike: counts and None exactly, metres to
    float32 rounding (the stacked models sum in another order)."""
    if isinstance(ours, dict):
        assert isinstance(theirs, dict) and ours.keys() == theirs.keys()
        for name, value in ours.items():
            _close_rows(value, theirs[name], name)
    elif isinstance(ours, list):
        assert isinstance(theirs, list) and len(ours) == len(theirs)
        for value, other in zip(ours, theirs, strict=True):
            _close_rows(value, other, key)
    elif key == "n" or key.startswith("n_") or ours is None:
        assert ours == theirs, key
    else:
        assert ours == pytest.approx(theirs, rel=1e-5, abs=1e-5), key


@pytest.mark.parametrize("together", ["one by one", "stacked"])
def test_a_multi_horizon_run_scores_each_model_as_evaluate_does_in_one_pass(
    tiny_horizons_run: Path, together: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The CPU's way (the models one after the other) and an accelerator's with the loader's
    batches (stacked), both here on the CPU."""
    stacked: list[int] = []  # the members of each stacked pass
    if together == "stacked":

        def run_stacked(ensemble: Ensemble, batch: dict) -> torch.Tensor:
            stacked.append(ensemble.members)
            return ensemble(batch)

        monkeypatch.setattr(Ensemble, "predict_one_by_one", run_stacked)
    calls: list[tuple[int, int]] = []
    several = evaluate(tiny_horizons_run, None, "test", "cpu", 8, lambda *call: calls.append(call))
    assert (2 in stacked) == (together == "stacked")
    batches = -(-several.samples // 8)
    assert batches > 1 and calls == [(done, batches) for done in range(1, batches + 1)]
    assert list(several.members) == ["h1s", "h2s"]
    for name, steps in (("h1s", 5), ("h2s", 10)):
        alone = evaluate(tiny_horizons_run / name, None, "test", "cpu", 8).longest
        joint = several.members[name]
        assert joint.horizon_steps == alone.horizon_steps == steps
        # everything but the model's own numbers exactly: constant velocity, counts, fields
        assert replace(joint, model=alone.model, steps=alone.steps, intervals=None) == replace(
            alone, intervals=None
        )
        _close_intervals(joint.intervals, alone.intervals)
        assert joint.steps["constant_velocity"] == alone.steps["constant_velocity"]
        _close_rows(joint.model, alone.model)
        _close_rows(joint.steps["model"], alone.steps["model"])
        assert joint.final.sample.tolist() == alone.final.sample.tolist()
        np.testing.assert_array_equal(
            joint.final.constant_velocity_m, alone.final.constant_velocity_m
        )
        np.testing.assert_allclose(joint.final.model_m, alone.final.model_m, rtol=1e-5, atol=1e-4)


def test_the_split_on_the_device_scores_as_the_loader(tiny_horizons_run: Path) -> None:
    """Static batches of the split loaded once (CUDA's way, here on the CPU): the same numbers
    as the loader's batches (the counts exactly; constant velocity to float64 rounding, its sums
    over other batches; the model to float32 rounding), each final error tied to the same
    sample."""
    calls: list[tuple[int, int]] = []
    static = evaluate(
        tiny_horizons_run, None, "test", "cpu", 8, lambda *c: calls.append(c), resident=True
    )
    loader = evaluate(tiny_horizons_run, None, "test", "cpu", 8, resident=False)
    assert calls == [(1, 1)]  # the tiny split is one static batch
    _close_rows(static.model, loader.model)
    for region, row in static.constant_velocity.items():
        other = loader.constant_velocity[region]
        assert {k: v is None for k, v in row.items()} == {k: v is None for k, v in other.items()}
        numbers = {k: v for k, v in row.items() if v is not None}
        assert numbers == pytest.approx({k: other[k] for k in numbers}, rel=1e-12), region
    for name, joint in static.members.items():
        alone = loader.members[name]
        np.testing.assert_array_equal(
            joint.final.constant_velocity_m, alone.final.constant_velocity_m
        )
        _close_rows(joint.steps["model"], alone.steps["model"])
        assert joint.final.sample.tolist() == alone.final.sample.tolist()
        np.testing.assert_allclose(joint.final.model_m, alone.final.model_m, rtol=1e-5, atol=1e-4)
    _close_intervals(static.intervals, loader.intervals)
    single = evaluate(tiny_horizons_run / "h2s", None, "test", "cpu", resident=True)
    _close_rows(single.model, loader.members["h2s"].model)


def _close_intervals(ours: SampleIntervals | None, theirs: SampleIntervals | None) -> None:
    """Two evaluations' intervals alike: the same resamples of the same samples, the bounds to
    float32 rounding (the model's sums, in another order)."""
    assert ours is not None and theirs is not None
    assert replace(ours, metrics={}) == replace(theirs, metrics={})
    assert ours.metrics.keys() == theirs.metrics.keys()
    for key, paired in ours.metrics.items():
        for kind in ("model", "constant_velocity", "difference"):
            mine, other = getattr(paired, kind), getattr(theirs.metrics[key], kind)
            assert (mine.value, mine.low, mine.high) == pytest.approx(
                (other.value, other.low, other.high), rel=1e-5, abs=1e-5
            ), (key, kind)


def _edit_member(run: Path, edit: Callable[[dict], None]) -> None:
    """Apply `edit` to the run info that a member's run.json and best.pt record."""
    info = json.loads((run / folder.RUN_INFO).read_text())
    edit(info)
    (run / folder.RUN_INFO).write_text(json.dumps(info))
    checkpoint = torch.load(run / folder.BEST, map_location="cpu", weights_only=True)
    edit(checkpoint["info"])
    torch.save(checkpoint, run / folder.BEST)
    record_checkpoint(run / folder.BEST)  # as fit records what it keeps


@pytest.mark.parametrize(
    ("what", "edit"),
    [
        ("model settings", lambda info: info["model"].update(dropout=0.25)),
        (
            "scalers",
            lambda info: info["scaler"]["x_m"].update(max=info["scaler"]["x_m"]["max"] + 1),
        ),
    ],
)
def test_models_of_other_fits_are_refused_as_one_run(
    tiny_horizons_run: Path, tmp_path: Path, what: str, edit: Callable[[dict], None]
) -> None:
    run = Path(shutil.copytree(tiny_horizons_run, tmp_path / "run"))
    _edit_member(run / "h2s", edit)
    message = (
        f"its models h1s and h2s differ in their {what}: not the models of one multi-horizon "
        "fit; evaluate each on its own"
    )
    code, out, err = _evaluate(str(run))  # refused before any model loads
    assert code == 1 and out == "" and err == f"error: {run}: {message}\n"
    with pytest.raises(NgsimInputError) as raised:
        evaluate(run, None, "test", "cpu")
    assert str(raised.value) == f"{run}: {message}"
    assert evaluate(run / "h2s", None, "test", "cpu").samples > 0  # alone, it is a run


def test_a_multi_horizon_runs_non_finite_model_is_named(
    tiny_horizons_run: Path, tmp_path: Path
) -> None:
    run = Path(shutil.copytree(tiny_horizons_run, tmp_path / "run"))
    checkpoint = torch.load(run / "h2s" / folder.BEST, map_location="cpu", weights_only=True)
    checkpoint["model"]["output.2.bias"][0] = float("nan")
    torch.save(checkpoint, run / "h2s" / folder.BEST)
    record_checkpoint(run / "h2s" / folder.BEST)  # as fit records what it keeps
    code, out, err = _evaluate(str(run))
    build = records.read_record(run / "h2s").info.build.build_dir
    assert code == 1 and out == "" and err.count("\n") == 1
    assert err.startswith(
        f"error: {run / 'h2s' / folder.BEST}: the 2 s model's predictions on {build} (test split, "
        "batch 1 of "
    )
    assert err.endswith(") are not finite (NaN or infinite); no metrics\n")


# ------------------------------------------------------------------------------------------------
# The bootstrap's intervals (aigem.intervals): around the numbers, which they leave as they are


def test_evaluate_gives_intervals_around_its_numbers(tiny_run: Path) -> None:
    """--json's intervals: 1,000 resamples of the split's samples, seed 0, one per metric in
    metres over all actors (not the counts), each holding the row's number as its value; the
    difference is model - constant velocity. --bootstrap 0 gives none and the same rows."""
    code, out, err = _evaluate(str(tiny_run))
    assert code == 0, err
    document = json.loads(out)
    intervals = document["intervals"]
    assert {key: intervals[key] for key in ("level", "resamples", "seed", "samples")} == {
        "level": 0.95,
        "resamples": 1000,
        "seed": 0,
        "samples": document["samples"],
    }
    assert list(intervals["metrics"]) == ["ade_m", "fde_m", "rmse_1s_m", "rmse_2s_m"]
    for key, paired in intervals["metrics"].items():
        ours, theirs = document["model"]["all"][key], document["constant_velocity"]["all"][key]
        assert paired["model"]["value"] == ours and paired["constant_velocity"]["value"] == theirs
        assert paired["difference"]["value"] == ours - theirs
        for kind in ("model", "constant_velocity", "difference"):
            interval = paired[kind]
            assert interval["low"] < interval["value"] < interval["high"], (key, kind)
    ((name, member),) = document["members"].items()
    assert member["intervals"] == intervals  # a run of one model: its model's
    code, out, err = _evaluate(str(tiny_run), "--bootstrap", "0")
    assert code == 0, err
    without = json.loads(out)
    assert without["intervals"] is None and without["members"][name]["intervals"] is None
    assert without["members"][name] == {**member, "intervals": None}  # the same numbers
    assert without == {**document, "intervals": None, "members": without["members"]}


def test_the_per_sample_sums_add_up_to_the_totals(trained_run: Path) -> None:
    """What the bootstrap resamples, summed over the samples, is what the rows come from (to
    float rounding; the counts exactly), and each sample counts its own targets."""
    model, info = checkpoints.load_model(trained_run)
    dataset = GraphDataset(info.build.build_dir, "test", 5)
    scores = score_targets(model, dataset, 10, torch.device("cpu"), batch_size=5)
    pairs = (
        (scores.model_by_sample, scores.model),
        (scores.constant_velocity_by_sample, scores.constant_velocity),
    )
    for by_sample, totals in pairs:
        assert by_sample.error_m.shape == (len(dataset), 10)
        np.testing.assert_allclose(by_sample.error_m.sum(axis=0), totals.error_m[0], rtol=1e-12)
        np.testing.assert_allclose(
            by_sample.squared_m2.sum(axis=0), totals.squared_m2[0], rtol=1e-12
        )
        assert by_sample.count.sum(axis=0).tolist() == totals.count[0].tolist()
    graphs = dataset.build.graphs("test", np.arange(len(dataset)))
    counted = np.zeros((len(dataset), 10), np.int64)  # each sample's targets valid at each step
    np.add.at(counted, graphs.node_sample[graphs.target_node], graphs.target_mask[:, :10])
    assert scores.model_by_sample.count.tolist() == counted.tolist()
    assert (counted.sum(axis=1) > 0).sum() > 1  # more than one sample to resample


def test_a_groups_intervals_come_from_the_models_its_numbers_come_from(
    tiny_horizons_run: Path,
) -> None:
    """RMSE at 1 s and its interval from the 1 s model, the rest from the 2 s model; the table
    of all actors shows each interval under its number and the difference's row."""
    result = CliRunner(env={"COLUMNS": "200"}).invoke(
        app, ["evaluate", str(tiny_horizons_run), "--device", "cpu", "--json"]
    )
    document = json.loads(result.stdout)
    members = {name: m["intervals"]["metrics"] for name, m in document["members"].items()}
    assert list(members["h1s"]) == ["ade_m", "fde_m", "rmse_1s_m"]
    assert document["intervals"]["metrics"] == {
        "ade_m": members["h2s"]["ade_m"],
        "fde_m": members["h2s"]["fde_m"],
        "rmse_1s_m": members["h1s"]["rmse_1s_m"],
        "rmse_2s_m": members["h2s"]["rmse_2s_m"],
    }
    shown = CliRunner(env={"COLUMNS": "200"}).invoke(
        app, ["evaluate", str(tiny_horizons_run), "--device", "cpu"]
    )
    assert shown.exit_code == 0, shown.output
    lines = shown.stdout.splitlines()
    cells = [[c.strip() for c in line.split("│")[1:-1]] for line in lines if line.startswith("│")]
    difference = next(i for i, row in enumerate(cells) if row[0] == "AiGem - constant velocity")
    rmse_1s = document["intervals"]["metrics"]["rmse_1s_m"]["difference"]
    assert cells[difference][3] == f"{rmse_1s['value']:.2f}"
    above, below = rmse_1s["high"] - rmse_1s["value"], rmse_1s["value"] - rmse_1s["low"]
    assert cells[difference + 1][3] in (f"±{above:.2f}", f"+{above:.2f}/-{below:.2f}")
    assert cells[difference + 1][0] == "" and cells[difference + 1][-1] == ""
    assert (
        f"Under each number: its 95 % interval (percentile bootstrap: 1,000 resamples of the "
        f"{document['samples']} samples, each sample's actors drawn together; seed 0)"
        in " ".join(shown.stdout.split())
    )


def test_bootstrap_option(tiny_run: Path) -> None:
    """--bootstrap's default is the library's; a negative number is refused naming it."""
    import inspect

    from ngsim_cli.evaluation import evaluate as command

    assert inspect.signature(command).parameters["bootstrap"].default == RESAMPLES
    code, out, err = _evaluate(str(tiny_run), "--bootstrap", "-1")
    assert code == 2 and out == "" and "--bootstrap" in err
    with pytest.raises(ValueError, match="-1 resamples"):
        evaluate(tiny_run, device_choice="cpu", resamples=-1)
