"""bench/fit_once.py, what bench_fit_loop.py runs per checkout: one epoch of a multi-horizon fit,
its figures on one JSON line, the same models from two fits (what the side by side compares)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _fit_once(build: Path) -> dict:
    command = [sys.executable, str(ROOT / "bench" / "fit_once.py"), str(build)]
    command += ["--horizons-s", "1,2", "--batch-size", "8"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_fit_once_prints_the_loops_speed_and_the_same_models_twice(tiny_build: Path) -> None:
    first, again = _fit_once(tiny_build), _fit_once(tiny_build)
    assert first["code"] == str(ROOT)
    assert first["graphs_per_s"] > 0 and again["graphs_per_s"] > 0
    assert len(first["val_loss_m2"]) == 2 and first["val_loss_m2"][0] < first["val_loss_m2"][1]
    assert (first["weights"], first["val_loss_m2"]) == (again["weights"], again["val_loss_m2"])
