"""bench/gpu_check.sh runs its stages end to end on the CPU on a tiny input and prints the table
of the target figures last (on a GPU machine it measures them)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "gpu_check.sh"
FIGURES = (
    "fit loop, 5 horizons, batch 8 (graphs/s)",
    "fit loop, 1 model, batch 8 (graphs/s)",
    "GPU busy while the 5-horizon fit trains (%)",
    "evaluate (test samples/s per model)",
    "aigem paper, full protocol, six 15-min recordings (min, extrapolated)",
    "longest end of a command after its last line (s, bench_exit.py)",
)


# Slow (some 80 CPU seconds: synth, a build, bench_train, a fit, an evaluation, `aigem paper`
# and bench_exit run one after the other by the script): each of its stages has fast tests of its own.
@pytest.mark.slow
def test_gpu_check_measures_every_stage_on_the_cpu(tmp_path: Path) -> None:
    python = Path(sys.executable)
    env = {
        **os.environ,
        "PYTHON": str(python),
        "PATH": f"{python.parent}{os.pathsep}{os.environ['PATH']}",  # the venv's commands
        "OMP_NUM_THREADS": "1",
    }
    command = [str(SCRIPT), "--device", "cpu", "--out", str(tmp_path / "check"),
               "--recordings", "1", "--minutes", "0.4", "--epochs", "1", "--batch-size", "8",
               "--bench-sizes", "8", "--steps", "1", "--fast"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    table = result.stdout[result.stdout.index("== gpu_check on the CPU") :].splitlines()
    assert not any(line.startswith("FAILED") for line in table), table
    assert "synth" in table[1] and "exit" in table[1]  # every stage timed
    cells = [[cell.strip() for cell in line.split("|")[1:-1]] for line in table if line[:1] == "|"]
    rows = {figure: value for figure, _, value in cells[2:]}
    for figure in FIGURES:
        assert figure in rows, figure
    for figure in FIGURES[:2] + FIGURES[3:]:
        assert float(rows[figure].replace(",", "")) > 0, (figure, rows[figure])
    assert rows[FIGURES[2]] == "-"  # no GPU, no utilisation
    assert rows["captured steps equal eager ones (tests/test_aigem_engine.py)"] == "passed"


def test_gpu_check_build_runs_the_build_benchmark_on_every_core(tmp_path: Path) -> None:
    """`gpu_check.sh build`: bench_build.py of this tree alone, its figures printed (the venv's
    commands on PATH: nothing to install)."""
    python = Path(sys.executable)
    env = {
        **os.environ,
        "PYTHON": str(python),
        "PATH": f"{python.parent}{os.pathsep}{os.environ['PATH']}",
    }
    command = [str(SCRIPT), "build", "--recordings", "1", "--minutes", "0.2",
               "--work-dir", str(tmp_path / "out")]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    assert any(line.startswith("input              txt-r1-m0.2") for line in lines), lines
    wall = next(line for line in lines if line.startswith("wall "))
    assert float(wall.split()[1]) > 0
    assert not any(line.startswith("side by side") for line in lines)  # --against none
