"""bench/bench_train.py runs end to end on the tiny build and prints its table."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "bench_train.py"


@pytest.mark.slow
def test_bench_train_prints_every_measurement(tiny_build: Path) -> None:
    command = [sys.executable, str(SCRIPT), str(tiny_build), "--batch-sizes", "4",
               "--device", "cpu", "--steps", "2", "--warmup", "1", "--profile-steps", "1",
               "--models", "1,2", "--paths", "both"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # quick on a busy machine too
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=300, check=True, env=env
    )
    rows = [re.split(r"\s{2,}", line) for line in result.stdout.splitlines()]
    rows = [row for row in rows if row[0] in ("host", "cpu")]
    assert [row[:3] for row in rows] == [["cpu", "-", "to device"]] + [
        [device, size, what]
        for size in ("4",)
        for device, what in (
            ("host", "loader"),
            ("cpu", "model step"),
            ("cpu", "gpu path"),
            ("cpu", "2 models"),  # as one ensemble
            ("cpu", "2 apart"),  # one after the other
            ("cpu", "static 1"),  # aigem.training.engine's step on static batches
            ("cpu", "static 2"),
            ("cpu", "fit loop"),
            ("cpu", "fit 2 h"),  # fit_horizons of 1 and 2 s
            ("cpu", "fit loop st"),  # on static batches
            ("cpu", "fit 2 h st"),
        )
    ]
    for row in rows:  # graphs/s and ms/batch measured; ops and syncs counted for the steps
        assert float(row[3].replace(",", "")) > 0 and float(row[4].replace(",", "")) > 0
        if row[0] == "cpu" and row[2] != "to device":
            assert float(row[5].replace(",", "")) > 0 and float(row[6].replace(",", "")) >= 0
            assert row[7:10] == ["-", "-", "-"]  # the CUDA columns
        if row[2].startswith("static"):
            assert row[11].endswith("%") and row[12] == "-"  # the padding; no GPU memory
