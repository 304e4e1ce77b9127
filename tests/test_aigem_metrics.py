"""Metric functions against hand-computed cases; what evaluate reports follows METRICS."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from aigem import metrics
from aigem.metrics import (
    ErrorTotals,
    Metric,
    region_of,
    step_errors,
    summarize_errors,
    table_columns,
)
from ngsim_cli.aigem import app


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
    """A metric added to METRICS alone (here a toy: 1.5 m plus its region's index) is in every
    row of --json and a column of the printed table; the paper's rows have none ("-")."""
    toy = Metric("toy_m", "TOY", "m", lambda totals, region, k: 1.5 + region)
    monkeypatch.setattr(metrics, "METRICS", (*metrics.METRICS, toy))
    args = ["evaluate", str(tiny_run), "--device", "cpu"]
    document = json.loads(CliRunner().invoke(app, [*args, "--json"]).stdout)
    assert [document["model"][r]["toy_m"] for r in metrics.REGIONS] == [1.5, 2.5, 3.5, 4.5]
    assert document["constant_velocity"]["all"]["toy_m"] == 1.5
    assert "toy_m" not in document["paper"]["AiGem (paper)"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    headers = [_cells(line, "┃") for line in result.stdout.splitlines() if "┃ model" in line]
    assert [header[-2:] for header in headers] == [["TOY", "params"]] * 3  # all, mid; the paper
    rows = [_cells(line, "│") for line in result.stdout.splitlines() if line.startswith("│")]
    toy = {(row[0], index): row[-2] for index, row in enumerate(rows)}
    # the tables of all actors and of mid actors (this run has no front or rear targets)
    assert [toy[("AiGem (this run)", 0)], toy[("AiGem (this run)", 2)]] == ["1.50", "3.50"]
    assert toy[("constant velocity", 1)] == "1.50"
    assert {toy[(name, index)] for name, index in toy if "(paper)" in name} == {"-"}


def _cells(line: str, bar: str) -> list[str]:
    """The cells of one line of a printed table (rich's box drawing)."""
    return [cell.strip() for cell in line.split(bar)[1:-1]]
