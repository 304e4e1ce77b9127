"""Metric functions against hand-computed cases and a brute-force reference; the accumulator over
batches against the functions over the whole array; what evaluate reports follows METRICS; the
docs' example scores a build as evaluate does."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from aigem import metrics
from aigem.metrics import (
    ErrorTotals,
    Metric,
    compute_ade_m,
    compute_fde_m,
    compute_rmse_m,
    region_of,
    step_errors,
    summarize_errors,
    table_columns,
)
from ngsim_cli.aigem import app

AIGEM_DOCS = Path(__file__).resolve().parents[1] / "docs" / "aigem.md"


def _two_actors() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """10 steps (2 s at 0.2 s). Actor 0 is off by 3-4-5 at every step; actor 1 is off by 1 m
    in x, and its last 5 steps are masked."""
    truth = np.zeros((2, 10, 2))
    predicted = truth.copy()
    predicted[0] += [3.0, 4.0]
    predicted[1, :, 0] += 1.0
    mask = np.ones((2, 10), bool)
    mask[1, 5:] = False
    return predicted, truth, mask


def test_the_functions_by_hand() -> None:
    predicted, truth, mask = _two_actors()
    assert compute_ade_m(predicted, truth, mask) == pytest.approx(55 / 15)  # (10 * 5 + 5 * 1)
    assert compute_fde_m(predicted, truth, mask) == pytest.approx(5.0)  # actor 0 alone
    assert compute_rmse_m(predicted, truth, mask, 5) == pytest.approx(math.sqrt(13.0))
    assert compute_rmse_m(predicted, truth, mask, 10) == pytest.approx(5.0)
    predicted[1, 5:] = np.nan  # whatever is predicted where the target is not recorded
    assert compute_ade_m(predicted, truth, mask) == pytest.approx(55 / 15)


def _reference(
    predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray
) -> tuple[float, float, list[float]]:
    """ADE, FDE and RMSE at each step by their definitions, one (target, step) at a time."""
    targets, steps = mask.shape
    error = [
        [math.dist(predicted[a, k], truth[a, k]) for k in range(steps)] for a in range(targets)
    ]
    every = [error[a][k] for a in range(targets) for k in range(steps) if mask[a, k]]
    at = [[error[a][k] for a in range(targets) if mask[a, k]] for k in range(steps)]
    rmse = [math.sqrt(sum(e * e for e in errors) / len(errors)) for errors in at]
    return sum(every) / len(every), sum(at[-1]) / len(at[-1]), rmse


def test_the_functions_against_a_brute_force_reference() -> None:
    rng = np.random.default_rng(5)
    for targets, steps in ((1, 1), (7, 10), (30, 25)):
        truth = rng.normal(0.0, 20.0, (targets, steps, 2))
        predicted = truth + rng.normal(0.0, 3.0, (targets, steps, 2))
        mask = rng.random((targets, steps)) < 0.7
        mask[0] = True  # every step has a valid target
        ade, fde, rmse = _reference(predicted, truth, mask)
        assert compute_ade_m(predicted, truth, mask) == pytest.approx(ade, rel=1e-12)
        assert compute_fde_m(predicted, truth, mask) == pytest.approx(fde, rel=1e-12)
        for k in range(1, steps + 1):
            assert compute_rmse_m(predicted, truth, mask, k) == pytest.approx(
                rmse[k - 1], rel=1e-12
            )


def test_nothing_valid_is_nan_and_wrong_shapes_are_refused() -> None:
    predicted, truth, mask = _two_actors()
    assert math.isnan(compute_rmse_m(predicted, truth, mask & False, 3))
    assert math.isnan(compute_ade_m(predicted, truth, mask & False))
    with pytest.raises(ValueError) as wrong:
        compute_ade_m(predicted[:1], truth, mask)  # numpy would broadcast it
    assert str(wrong.value) == (
        "predictions of shape (1, 10, 2) and targets of shape (2, 10, 2): both must be (A, K, 2), "
        "the same"
    )
    with pytest.raises(ValueError) as wrong:
        compute_fde_m(predicted, truth, mask.astype(float))
    assert str(wrong.value) == (
        "mask of dtype float64: must be bool (True where the target's position is recorded)"
    )
    with pytest.raises(ValueError) as wrong:
        compute_fde_m(predicted, truth, mask[:, :9])
    assert (
        str(wrong.value)
        == "mask of shape (2, 9): must be (A, K) = (2, 10), as the targets' (A, K, 2)"
    )
    for step in (0, 11):
        with pytest.raises(ValueError, match=rf"step {step}: .* future steps 1..10"):
            compute_rmse_m(predicted, truth, mask, step)


def test_every_public_function_takes_tensors_as_numpy_arrays() -> None:
    """A tensor (with gradients, of another dtype) gives the numbers of its numpy array; a mask
    of torch.bool is a bool mask, and a wrong one is refused in numpy's words."""
    import torch

    predicted, truth, mask = _two_actors()
    tensors = (
        torch.tensor(predicted, dtype=torch.float32, requires_grad=True),
        torch.tensor(truth, dtype=torch.float32),
        torch.from_numpy(mask),
    )
    assert compute_ade_m(*tensors) == pytest.approx(55 / 15)
    assert compute_fde_m(*tensors) == pytest.approx(5.0)
    assert compute_rmse_m(*tensors, 5) == pytest.approx(math.sqrt(13.0))
    errors = metrics.displacement_errors_m(*tensors)
    assert isinstance(errors, np.ndarray) and errors.shape == (2, 10)
    count = torch.from_numpy(mask.sum(axis=0))
    sums = torch.from_numpy(errors.sum(axis=0))
    squares = torch.from_numpy((errors**2).sum(axis=0))
    assert metrics.ade_of_sums_m(sums, count) == pytest.approx(55 / 15)
    assert metrics.mean_error_of_sums_m(sums, count)[-1] == pytest.approx(5.0)
    assert metrics.rmse_of_sums_m(squares, count)[-1] == pytest.approx(5.0)
    assert region_of(torch.tensor([20.0, 0.0, -20.0])).tolist() == [0, 1, 2]
    totals = ErrorTotals(10)
    totals.add(*tensors, torch.zeros(2))
    assert totals.count[0].tolist() == mask.sum(axis=0).tolist()
    with pytest.raises(ValueError) as wrong:
        compute_ade_m(*tensors[:2], tensors[2].float())
    assert str(wrong.value) == (
        "mask of dtype float32: must be bool (True where the target's position is recorded)"
    )


def test_the_accumulator_over_batches_is_the_functions_over_the_whole_array() -> None:
    """ErrorTotals sums what the functions compute: a split added in uneven batches gives, in
    every region, the functions' numbers over the region's targets all at once."""
    rng = np.random.default_rng(8)
    truth = rng.normal(0.0, 20.0, (50, 10, 2))
    predicted = (truth + rng.normal(0.0, 2.0, truth.shape)).astype(np.float32)  # as a model's
    mask = rng.random((50, 10)) < 0.8
    present_y_m = rng.uniform(-30.0, 30.0, 50)
    totals = ErrorTotals(steps=10)
    for first in range(0, 50, 7):
        batch = slice(first, first + 7)
        totals.add(predicted[batch], truth[batch], mask[batch], present_y_m[batch])
    rows, curves = summarize_errors(totals, 0.2), step_errors(totals)
    chosen = {"all": np.ones(50, bool)} | {
        region: region_of(present_y_m) == index for index, region in enumerate(metrics.REGIONS[1:])
    }
    for region, rows_of in chosen.items():
        arrays = predicted[rows_of], truth[rows_of], mask[rows_of]
        assert rows_of.sum() > 5, region  # every region has targets
        row = rows[region]
        assert row["ade_m"] == pytest.approx(compute_ade_m(*arrays), rel=1e-12)
        assert row["fde_m"] == pytest.approx(compute_fde_m(*arrays), rel=1e-12)
        for second, step in ((1, 5), (2, 10)):
            assert row[f"rmse_{second}s_m"] == pytest.approx(
                compute_rmse_m(*arrays, step), rel=1e-12
            )
        every_step = [compute_rmse_m(*arrays, k) for k in range(1, 11)]
        np.testing.assert_allclose(curves[region]["rmse_m"], every_step, rtol=1e-12)


def test_the_accumulator_and_evaluates_rows_take_the_functions_rules(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """One rule in one place: the errors ErrorTotals sums are displacement_errors_m's, and the
    rows' ratios are the functions' own (a changed rule changes every number)."""
    predicted, truth, mask = _two_actors()
    doubled = metrics.displacement_errors_m
    monkeypatch.setattr(metrics, "displacement_errors_m", lambda *a: 2.0 * doubled(*a))
    totals = ErrorTotals(steps=10)
    totals.add(predicted, truth, mask, present_y_m=np.array([20.0, -20.0]))
    assert summarize_errors(totals, 0.2)["all"]["ade_m"] == pytest.approx(2 * 55 / 15)
    monkeypatch.setattr(metrics, "ade_of_sums_m", lambda error_m, count: 7.0)
    monkeypatch.setattr(metrics, "rmse_of_sums_m", lambda squared, count: np.full(10, 8.0))
    monkeypatch.setattr(metrics, "mean_error_of_sums_m", lambda error_m, count: np.full(10, 9.0))
    row = summarize_errors(totals, 0.2)["mid"]
    assert (row["ade_m"], row["fde_m"], row["rmse_2s_m"]) == (7.0, 9.0, 8.0)


def test_hand_computed_two_actors() -> None:
    # 10 steps (2 s at 0.2 s). Actor 0 (front, y=20) is off by 3-4-5 at every step;
    # actor 1 (rear, y=-20) is off by 1 m in x, and its last 5 steps are masked.
    truth = np.zeros((2, 10, 2))
    predicted = truth.copy()
    predicted[0] += [3.0, 4.0]
    predicted[1, :, 0] += 1.0
    mask = np.ones((2, 10), bool)
    mask[1, 5:] = False
    totals = ErrorTotals(steps=10)
    totals.add(predicted, truth, mask, present_y_m=np.array([20.0, -20.0]))
    out = summarize_errors(totals, 0.2)
    # ADE: (10 * 5 + 5 * 1) / 15; FDE: only actor 0 at step 10.
    assert out["all"]["ade_m"] == pytest.approx(55 / 15)
    assert out["all"]["fde_m"] == pytest.approx(5.0)
    # RMSE at 1 s (step 5): both valid: sqrt((25 + 1) / 2); at 2 s only actor 0.
    assert out["all"]["rmse_1s_m"] == pytest.approx(math.sqrt(13.0))
    assert out["all"]["rmse_2s_m"] == pytest.approx(5.0)
    assert (out["all"]["n_1s"], out["all"]["n_2s"]) == (2, 1)
    assert out["front"]["ade_m"] == pytest.approx(5.0) and out["rear"]["ade_m"] == pytest.approx(
        1.0
    )
    assert out["mid"]["ade_m"] is None and out["rear"]["fde_m"] is None
    assert totals.actors == 2


def test_pooled_rmse_is_not_the_mean_of_per_batch_rmse() -> None:
    totals = ErrorTotals(steps=5)
    for offset in (1.0, 3.0):
        truth = np.zeros((1, 5, 2))
        totals.add(truth + [offset, 0.0], truth, np.ones((1, 5), bool), np.array([0.0]))
    assert summarize_errors(totals, 0.2)["all"]["rmse_1s_m"] == pytest.approx(
        math.sqrt(5.0)
    )  # not 2


def test_regions_by_present_y() -> None:
    assert region_of(np.array([15.1, 15.0, 0.0, -15.0, -15.1])).tolist() == [0, 1, 1, 1, 2]


def test_step_errors_by_hand() -> None:
    """The two actors of the first test: actor 0 (front) off by 5 m at all 10 steps, actor 1
    (rear) off by 1 m at steps 1..5 and masked after."""
    truth = np.zeros((2, 10, 2))
    predicted = truth.copy()
    predicted[0] += [3.0, 4.0]
    predicted[1, :, 0] += 1.0
    mask = np.ones((2, 10), bool)
    mask[1, 5:] = False
    totals = ErrorTotals(steps=10)
    totals.add(predicted, truth, mask, present_y_m=np.array([20.0, -20.0]))
    curves = step_errors(totals)
    both, alone = [math.sqrt(13.0)] * 5, [5.0] * 5  # sqrt((25 + 1) / 2), then actor 0 only
    np.testing.assert_allclose(curves["all"]["rmse_m"], both + alone)
    np.testing.assert_allclose(curves["all"]["mean_error_m"], [3.0] * 5 + [5.0] * 5)
    assert curves["all"]["n"].tolist() == [2] * 5 + [1] * 5
    np.testing.assert_allclose(curves["front"]["rmse_m"], [5.0] * 10)
    np.testing.assert_allclose(curves["rear"]["mean_error_m"], [1.0] * 5 + [np.nan] * 5)
    assert np.isnan(curves["mid"]["rmse_m"]).all() and curves["mid"]["n"].tolist() == [0] * 10
    # The same numbers as the table's: RMSE at 1 s is step 5's, FDE the last step's mean error.
    table = summarize_errors(totals, 0.2)["all"]
    assert curves["all"]["rmse_m"][4] == pytest.approx(table["rmse_1s_m"])
    assert curves["all"]["mean_error_m"][-1] == pytest.approx(table["fde_m"])


def test_the_rows_and_the_tables_columns_follow_metrics() -> None:
    totals = ErrorTotals(steps=10)  # 2 s at 0.2 s
    out = summarize_errors(totals, 0.2)
    assert list(out["all"]) == ["ade_m", "fde_m", "rmse_1s_m", "n_1s", "rmse_2s_m", "n_2s"]
    assert out["all"]["ade_m"] is None and out["all"]["n_2s"] == 0  # nothing counted yet
    assert table_columns(2) == [
        ("ade_m", "ADE"),
        ("fde_m", "FDE"),
        ("rmse_1s_m", "RMSE 1 s"),
        ("rmse_2s_m", "RMSE 2 s"),
    ]


def test_a_new_metric_reaches_evaluates_json_and_table(
    tiny_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A metric added to METRICS alone (here a toy: 1.5 m plus the count at its step, the last
    one: 1.5 plus n_2s in each region) is in every row of --json, its intervals and a column of
    the printed table; the paper's rows have none ("-")."""
    toy = Metric("toy_m", "TOY", "m", lambda error_m, squared_m2, count, k: 1.5 + count[..., k])
    monkeypatch.setattr(metrics, "METRICS", (*metrics.METRICS, toy))
    args = ["evaluate", str(tiny_run), "--device", "cpu"]
    document = json.loads(CliRunner().invoke(app, [*args, "--json"]).stdout)
    rows = document["model"]
    assert [rows[r]["toy_m"] for r in metrics.REGIONS] == [1.5 + rows[r]["n_2s"] for r in rows]
    assert [rows[r]["n_2s"] > 0 for r in metrics.REGIONS] == [True, False, True, False]
    assert document["constant_velocity"]["all"]["toy_m"] == rows["all"]["toy_m"]
    assert document["intervals"]["metrics"]["toy_m"]["difference"]["value"] == 0.0
    assert "toy_m" not in document["paper"]["AiGem (paper)"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    headers = [_cells(line, "┃") for line in result.stdout.splitlines() if "┃ model" in line]
    assert [header[-2:] for header in headers] == [["TOY", "params (K)"]] * 3  # all, mid; the paper
    lines = [_cells(line, "│") for line in result.stdout.splitlines() if line.startswith("│")]
    named = [row for row in lines if row[0]]  # not the intervals' second lines
    toy = {(row[0], index): row[-2] for index, row in enumerate(named)}
    # the tables of all actors and of mid actors (this run has no front or rear targets)
    n = rows["all"]["n_2s"]
    assert [toy[("AiGem (this run)", 0)], toy[("AiGem (this run)", 3)]] == [f"{1.5 + n:.2f}"] * 2
    assert toy[("constant velocity", 1)] == f"{1.5 + n:.2f}"
    assert toy[("AiGem - constant velocity", 2)] == "0.00"
    assert {toy[(name, index)] for name, index in toy if "(paper)" in name} == {"-"}


def _cells(line: str, bar: str) -> list[str]:
    """The cells of one line of a printed table (rich's box drawing)."""
    return [cell.strip() for cell in line.split(bar)[1:-1]]


def _docs_example() -> str:
    """The Python block of docs/aigem.md's section on scoring one's own predictions."""
    section = AIGEM_DOCS.read_text().split("## Scoring your own model's predictions", 1)[1]
    blocks = re.findall(r"^```python\n(.*?)^```", section.split("\n## ", 1)[0], re.M | re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_the_docs_example_scores_as_evaluate_does(
    tiny_build: Path,
    tiny_run: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Run as written where the README's commands leave demo/build: its constant velocity,
    scored with the functions, gets evaluate's numbers for constant velocity (the run's horizon,
    2 s, is the example's first 10 steps)."""
    from aigem.evaluation.evaluate import evaluate

    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "build").symlink_to(tiny_build, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    scope: dict[str, object] = {"__name__": "docs"}
    exec(compile(_docs_example(), str(AIGEM_DOCS), "exec"), scope)  # noqa: S102 (our own docs)
    printed = capsys.readouterr().out
    predicted, truth, mask = (scope[name] for name in ("predicted", "truth", "mask"))
    assert predicted.shape == truth.shape == (len(mask), 25, 2)  # type: ignore[attr-defined]
    baseline = evaluate(tiny_run, device_choice="cpu").constant_velocity["all"]
    first = (predicted[:, :10], truth[:, :10], mask[:, :10])  # type: ignore[index]
    assert compute_ade_m(*first) == pytest.approx(baseline["ade_m"], rel=1e-5)
    assert compute_fde_m(*first) == pytest.approx(baseline["fde_m"], rel=1e-5)
    for second in (1, 2):
        rmse_m = compute_rmse_m(*first, 5 * second)
        assert rmse_m == pytest.approx(baseline[f"rmse_{second}s_m"], rel=1e-5)
        assert f"RMSE {second} s: {rmse_m:.2f} m" in printed
    assert int(mask[:, 9].sum()) == baseline["n_2s"]  # type: ignore[index]
    assert f"{len(mask)} targets: ADE " in printed and "RMSE 5 s: " in printed  # type: ignore[arg-type]
