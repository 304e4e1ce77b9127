"""Constant velocity: its positions by hand, and its validation loss against a brute-force loop
over every target and step of the tiny build in fit's definition (masked MSE, metres^2)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from aigem.runs import baseline
from aigem.runs.baseline import constant_velocity, constant_velocity_loss_m2
from ngsim_graphs.build import open_build


def test_constant_velocity_by_hand() -> None:
    # [x, y, heading, speed]: heading 0 drives along +y, pi/2 along +x
    state = np.array([[1.0, 2.0, 0.0, 10.0], [0.0, 0.0, math.pi / 2, 5.0]])
    positions = constant_velocity(state, steps=2, time_step_s=0.2)
    np.testing.assert_allclose(positions[0], [[1.0, 4.0], [1.0, 6.0]], atol=1e-12)
    np.testing.assert_allclose(positions[1], [[1.0, 0.0], [2.0, 0.0]], atol=1e-12)


def _brute_force_loss_m2(build_dir: Path, steps: int) -> float:
    """Squared errors summed over every valid (target, step <= steps) of the val split, one
    sample and one target at a time, divided by their number."""
    build = open_build(build_dir)
    time_step_s = build.config.time_step_s
    squared, valid = 0.0, 0
    for sample in range(build.manifest.splits["val"]):
        graph = build.graphs("val", np.array([sample]))
        for target, node in enumerate(graph.target_node):
            x, y, heading, speed = graph.node_features[node]
            for k in range(steps):
                if graph.target_mask[target, k]:
                    t = (k + 1) * time_step_s
                    dx = x + speed * math.sin(heading) * t - graph.target_xy[target, k, 0]
                    dy = y + speed * math.cos(heading) * t - graph.target_xy[target, k, 1]
                    squared, valid = squared + dx * dx + dy * dy, valid + 1
    assert valid > 0
    return squared / valid


def test_the_validation_loss_is_fits_masked_mse_brute_force(
    tiny_build: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(baseline, "CHUNK_SAMPLES", 7)  # several chunks, the last one short
    losses = constant_velocity_loss_m2(tiny_build, "val", [5, 10])
    assert losses[5] == pytest.approx(_brute_force_loss_m2(tiny_build, 5), rel=1e-9)
    assert losses[10] == pytest.approx(_brute_force_loss_m2(tiny_build, 10), rel=1e-9)
    assert losses[5] < losses[10]  # constant velocity drifts further the longer it runs
