"""bench/bench_evaluate.py runs end to end on the tiny two-horizon run, the evaluate call and the
whole command, with this checkout as both the old and the new code."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "bench" / "bench_evaluate.py"


def _bench(run: Path, old: Path, *more: str) -> subprocess.CompletedProcess:
    command = [sys.executable, str(SCRIPT), str(run), "--old", str(old), "--new", str(ROOT),
               "--rounds", "1", *more]  # fmt: skip
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_bench_evaluate_times_the_call_and_the_forward_passes(tiny_horizons_run: Path) -> None:
    done = _bench(tiny_horizons_run, ROOT, "--forward")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    for name in ("old", "new"):
        assert any(re.fullmatch(rf"round 1 {name}: \d+ samples x 2 models in [0-9.]+ s, [0-9.]+ "
                                r"samples/s", line) for line in lines), lines  # fmt: skip
    assert re.search(
        r"^median samples/s: old [0-9.]+, new [0-9.]+; ratio [0-9.]+$", done.stdout, re.M
    )
    # the same code scores the same run alike, to the bit
    assert "largest difference between the two results' metrics: 0\n" in done.stdout
    assert re.search(r"^loading the test split once \(\d+ batches\): [0-9.]+ s$", done.stdout, re.M)
    assert re.search(r"^forward, round 1: stacked [0-9.]+ s, apart [0-9.]+ s$", done.stdout, re.M)


@pytest.mark.slow
def test_bench_evaluate_times_the_whole_command(tiny_horizons_run: Path, tmp_path: Path) -> None:
    done = _bench(tiny_horizons_run, ROOT, "--command")
    assert done.returncode == 0, done.stderr
    seconds = re.findall(r"^round 1 (old|new): aigem evaluate in ([0-9.]+) s$", done.stdout, re.M)
    assert sorted(name for name, _ in seconds) == ["new", "old"]
    assert all(float(value) > 0 for _, value in seconds)
    assert re.search(
        r"^median seconds: old [0-9.]+, new [0-9.]+; old / new [0-9.]+$", done.stdout, re.M
    )
    # a folder that is not a checkout: its command fails, and the script says which
    failed = _bench(tiny_horizons_run, tmp_path, "--command")
    assert failed.returncode == 1
    assert f"{tmp_path}: aigem evaluate failed" in failed.stderr
