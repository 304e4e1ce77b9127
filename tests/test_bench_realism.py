"""bench/realism.py: constant velocity's errors against a reference taken sample by sample, the
report through its command line, and the generator's calibration (synthetic traffic no more
predictable than NGSIM's)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_cli_ngsim import invoke

from aigem.runs.baseline import constant_velocity
from ngsim_graphs.build import open_build
from ngsim_graphs.splits import SPLIT_ORDER

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import realism as bench  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "realism.py"


@pytest.fixture(scope="module")
def calibration_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two recordings of three minutes, synth's default seed."""
    root = tmp_path_factory.mktemp("calibration")
    synth = invoke("synth", root / "raw", "--format", "txt", "--recordings", 2, "--minutes", 3)
    assert synth.exit_code == 0, synth.output
    build = invoke("build", root / "raw", "--out", root / "build", "--jobs", 1)
    assert build.exit_code == 0, build.output
    return root / "build"


def _reference(build_dir: Path, location: str) -> tuple[dict[int, float], float, float]:
    """RMSE at 1..5 s, ADE and FDE of constant velocity, one sample at a time."""
    build = open_build(build_dir)
    errors, masks = [], []
    for split in SPLIT_ORDER:
        arrays = build.sample_arrays(split)
        for sample in range(build.manifest.splits[split.value]):
            entry = build.entries[int(arrays["recording_index"][sample])]
            if location != bench.ALL and entry.location != location:
                continue
            graphs = build.graphs(split, np.array([sample]))
            present = graphs.node_features[graphs.target_node]
            predicted = constant_velocity(present, 25, build.config.time_step_s)
            errors.append(np.linalg.norm(predicted - graphs.target_xy, axis=-1))
            masks.append(graphs.target_mask)
    error, mask = np.concatenate(errors), np.concatenate(masks)
    rmse = {
        h: float(np.sqrt((error[:, 5 * h - 1] ** 2)[mask[:, 5 * h - 1]].mean()))
        for h in range(1, 6)
    }
    return rmse, float(error[mask].mean()), float(error[:, -1][mask[:, -1]].mean())


def test_constant_velocity_errors_against_each_sample_alone(tiny_build: Path) -> None:
    found = bench.constant_velocity_errors(open_build(tiny_build))
    for location in found:
        rmse, ade, fde = _reference(tiny_build, location)
        assert found[location].rmse_m == pytest.approx(rmse)
        assert (found[location].ade_m, found[location].fde_m) == pytest.approx((ade, fde))


@pytest.mark.slow
def test_synthetic_traffic_is_no_more_predictable_than_ngsims(calibration_build: Path) -> None:
    # The generator before its calibration: constant velocity's RMSE 0.30 m at 1 s and 4.8 m at
    # 5 s on NGSIM's 0.73 and 6.68 m (Deo and Trivedi 2018).
    errors = bench.constant_velocity_errors(open_build(calibration_build))[bench.ALL]
    assert errors.rmse_m[1] > 0.5
    assert errors.rmse_m[5] > 5.0


@pytest.mark.slow
def test_the_report_prints_ours_beside_ngsims(calibration_build: Path, tmp_path: Path) -> None:
    plot, report = tmp_path / "realism.png", tmp_path / "realism.json"
    command = [sys.executable, str(SCRIPT), str(calibration_build), str(calibration_build),
               "--plot", str(plot), "--json", str(report)]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    [row] = [line.split() for line in result.stdout.splitlines() if line.startswith("cv_rmse_1s_m")]
    assert row[-1] == "0.73" and len(row) == 1 + 2 * 3 + 1  # two builds' locations and all
    assert "Deo and Trivedi 2018" in result.stdout
    # The second-order measures, once per build: the real sample's figure, then value (ratio) for
    # each of the two recordings and all.
    rows = [line.split() for line in result.stdout.splitlines() if line.startswith("jerk_std")]
    assert len(rows) == 2 and rows[0] == rows[1] and len(rows[0]) == 2 + 2 * 3
    value, ratio = float(rows[0][-2]), float(rows[0][-1].strip("()"))
    assert rows[0][1] == "8.1" and ratio == pytest.approx(value / 8.1, abs=0.006)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and report.is_file()
