"""bench/short_horizon.py on the tiny run: its constant-velocity errors are evaluate's, its
probes fit what they should, and its scaled constant-velocity step is the scaler's."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from ngsim_cli.aigem import app

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import short_horizon as bench  # noqa: E402


def test_the_report_of_the_tiny_run(tiny_run: Path, tmp_path: Path, capsys) -> None:  # noqa: ANN001
    assert bench.main([str(tiny_run), "--split", "test", "--json", str(tmp_path / "r.json")]) == 0
    (report,) = json.loads((tmp_path / "r.json").read_text())
    scores = json.loads(
        CliRunner().invoke(app, ["evaluate", str(tiny_run), "--device", "cpu", "--json"]).stdout
    )
    at_1s = {
        "model": scores["model"]["all"]["rmse_1s_m"],
        "constant velocity": scores["constant_velocity"]["all"]["rmse_1s_m"],
    }
    for name, value in at_1s.items():
        assert np.isclose(report["rmse_by_step_m"][name][4], value, rtol=1e-4), name
    assert report["targets"] > 10
    # The velocity along the road is nearly the scaled speed: its probe from the features
    # leaves a small part of its spread; an embedding of one epoch, more.
    spread, features = report["velocity_std_mps"][1], report["probe_features_rmse_mps"][1]
    assert features < 0.2 * spread and report["probe_embedding_rmse_mps"][1] > features
    assert report["cv_step_scaled_median"] > 0 and report["cv_error_1s_scaled_median"] > 0
    assert all(0 < share <= 1 for share in report["occupied_share"].values())
    assert "probe: embedding" in capsys.readouterr().out
