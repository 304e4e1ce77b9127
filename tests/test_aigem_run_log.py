"""A run's log: metrics.jsonl's rows as EpochRow (written, read back, older rows, damaged ones)
and baseline.json."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from aigem.runs.records import BASELINE, METRICS
from aigem.runs.run_log import (
    EpochRow,
    append_row,
    drop_rows_after,
    read_baseline,
    read_metrics,
    write_baseline,
)
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError

ROW = EpochRow(1, 9.5, 4.25, 1, 312, 0.8, 385.8, 0.0, 0.001)


def test_a_row_is_written_as_fit_logs_it_and_read_back(tmp_path: Path) -> None:
    append_row(tmp_path, ROW)
    append_row(tmp_path, EpochRow(2, 3.0, 5.0, 1, train_graphs=100))  # a time limit cut it
    assert (tmp_path / METRICS).read_text().splitlines() == [
        '{"epoch": 1, "train_loss_m2": 9.5, "val_loss_m2": 4.25, "best_epoch": 1, '
        '"train_graphs": 312, "train_seconds": 0.8, "train_graphs_per_s": 385.8, '
        '"val_seconds": 0.0, "learning_rate": 0.001}',
        '{"epoch": 2, "train_loss_m2": 3.0, "val_loss_m2": 5.0, "best_epoch": 1, '
        '"train_graphs": 100}',
    ]
    assert read_metrics(tmp_path) == [ROW, EpochRow(2, 3.0, 5.0, 1, train_graphs=100)]
    assert read_metrics(tmp_path / "nowhere") == []


def test_a_row_of_an_older_aigem_lacks_what_was_logged_since(tmp_path: Path) -> None:
    """aigem 0.1.0's first rows had the losses and the best epoch alone; a key this aigem does
    not know (a newer aigem's) is left aside."""
    (tmp_path / METRICS).write_text(
        '{"epoch": 1, "train_loss_m2": 2, "val_loss_m2": 1.5, "best_epoch": 1}\n\n'
        '{"epoch": 2, "train_loss_m2": 1.0, "val_loss_m2": 2.5, "best_epoch": 1, "new": 7}\n'
    )
    first, second = read_metrics(tmp_path)
    assert first == EpochRow(1, 2, 1.5, 1) and first.learning_rate is None
    assert second.epoch == 2 and second.train_seconds is None


@pytest.mark.parametrize(
    "line",
    [
        '{"epoch": 1, "train_lo',  # torn
        '{"epoch": 1, "train_loss_m2": 1.0, "val_loss_m2": 1.0}',  # no best epoch
        '{"epoch": 1.0, "train_loss_m2": 1.0, "val_loss_m2": 1.0, "best_epoch": 1}',
        '{"epoch": 1, "train_loss_m2": "1", "val_loss_m2": 1.0, "best_epoch": 1}',
        "[1, 2]",
    ],
)
def test_a_damaged_row_is_one_line_naming_it(tmp_path: Path, line: str) -> None:
    (tmp_path / METRICS).write_text(json.dumps(ROW.to_json()) + "\n" + line + "\n")
    with pytest.raises(NgsimInputError) as error:
        read_metrics(tmp_path)
    assert str(error.value) == (
        f"{tmp_path / METRICS}, line 2: not a row of aigem's metrics log (damaged?)"
    )


def test_rows_after_the_last_checkpoint_are_dropped_the_rest_kept_as_written(
    tmp_path: Path,
) -> None:
    lines = [
        '{"epoch": 1, "train_loss_m2": 2, "val_loss_m2": 1.5, "best_epoch": 1, "new": 7}',
        '{"epoch": 2, "train_loss_m2": 1.0, "val_loss_m2": 2.5, "best_epoch": 1}',
    ]
    (tmp_path / METRICS).write_text("".join(line + "\n" for line in lines))
    drop_rows_after(tmp_path, 2)
    assert (tmp_path / METRICS).read_text() == "".join(line + "\n" for line in lines)
    drop_rows_after(tmp_path, 1)
    assert (tmp_path / METRICS).read_text() == lines[0] + "\n"


def test_a_log_that_is_a_link_is_replaced_not_followed(tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere.jsonl"
    written = json.dumps(ROW.to_json()) + "\n"
    elsewhere.write_text(written)
    run = tmp_path / "run"
    run.mkdir()
    os.symlink(elsewhere, run / METRICS)
    with pytest.raises(NgsimOutputError, match="is a symbolic link: not written through"):
        append_row(run, ROW)
    drop_rows_after(run, 1)  # as a resume does: the link replaced by the rows it leads to
    assert not (run / METRICS).is_symlink() and read_metrics(run) == [ROW]
    append_row(run, ROW)
    assert elsewhere.read_text() == written and len(read_metrics(run)) == 2


def test_baseline_round_trip(tmp_path: Path) -> None:
    assert read_baseline(tmp_path) is None  # a run without one (an older aigem's)
    write_baseline(tmp_path, 12.5, 25)
    assert json.loads((tmp_path / BASELINE).read_text()) == {
        "constant_velocity_val_loss_m2": 12.5,
        "steps": 25,
    }
    assert read_baseline(tmp_path) == 12.5
    (tmp_path / BASELINE).write_text('{"constant_velocity_val_loss_m2": true}')
    assert read_baseline(tmp_path) is None  # damaged: only the line is missing
