"""bench/bench_accuracy.py trains each setting, reports its time to the target, and does not train
a finished setting again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from aigem.runs import folder, run_log
from ngsim_graphs.build import open_build

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "bench_accuracy.py"


def _bench(build: Path, out: Path, *args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, str(SCRIPT), str(build), "--out", str(out), "--epochs", "2",
               "--horizon-s", "1", "--device", "cpu", "--workers", "0", "--threads", "1", *args]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)


@pytest.mark.slow
def test_bench_accuracy_reports_time_to_target_and_resumes(
    tiny_build: Path, tmp_path: Path
) -> None:
    settings = ["--setting", "batch=8", "--setting", "batch=16,lr=2e-3,schedule=cosine,warmup=1"]
    result = _bench(tiny_build, tmp_path, "--target-m2", "1e9", *settings)
    assert result.returncode == 0, result.stderr
    table = json.loads((tmp_path / "accuracy.json").read_text())
    train_graphs = open_build(tiny_build).manifest.splits["train"]
    first, second = table["settings"]
    assert [first["setting"], second["setting"]] == ["batch=8", settings[3]]
    names = ("batch8", "batch16_lr2e-3_schedulecosine_warmup1")
    for item, run in zip((first, second), names, strict=True):
        rows = run_log.read_metrics(tmp_path / run)
        assert item["val_m2"] == [row.val_loss_m2 for row in rows] and item["epochs"] == 2
        assert item["target_epoch"] == 1 and item["graphs_to_target"] == train_graphs
        assert item["seconds_to_target"] == round(rows[0].train_seconds + rows[0].val_seconds, 1)
    info = json.loads(
        (tmp_path / "batch16_lr2e-3_schedulecosine_warmup1" / folder.RUN_INFO).read_text()
    )
    assert info["train"]["lr_schedule"] == "cosine" and info["train"]["warmup_epochs"] == 1.0
    assert (tmp_path / "accuracy.png").read_bytes().startswith(b"\x89PNG")
    assert "not reached" not in result.stdout and "epoch 1," in result.stdout

    before = (tmp_path / "batch8" / folder.LAST).stat().st_mtime_ns
    again = _bench(tiny_build, tmp_path, "--target-m2", "1e-9", "--setting", "batch=8")
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "batch8" / folder.LAST).stat().st_mtime_ns == before  # not trained again
    assert "target: not reached" in again.stdout


def test_bench_accuracy_refuses_a_bad_setting_before_training(
    tiny_build: Path, tmp_path: Path
) -> None:
    result = _bench(tiny_build, tmp_path, "--setting", "batch=8", "--setting", "speed=3")
    assert result.returncode != 0
    expected = "--setting speed=3: 'speed=3' is not KEY=VALUE, KEY one of batch, lr, schedule"
    assert expected in result.stderr
    assert not (tmp_path / "batch8").exists()
