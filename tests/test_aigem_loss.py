"""The loss (aigem.model.loss): metres^2 over each model's valid future steps, masked steps counting
nowhere, each member's sums bitwise its model's alone."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from aigem.model.data import Collate, GraphDataset, xy_to_metres
from aigem.model.loss import masked_mse_m2, member_sums


@pytest.fixture(scope="module")
def dataset(tiny_build: Path) -> GraphDataset:
    return GraphDataset(tiny_build, "train")


def test_masked_steps_count_in_no_loss(dataset: GraphDataset) -> None:
    batch = Collate(dataset.scaler)(dataset.__getitems__([0, 1]))
    truth = xy_to_metres(dataset.scaler, torch.zeros(1, 1, 2))  # scaled 0 -> some metres
    scaled = torch.zeros(len(batch.target_node), 3, 2)
    batch.target_xy[:, :3] = truth
    assert float(masked_mse_m2(scaled, batch, dataset.scaler, 3)) == pytest.approx(0.0, abs=1e-6)
    batch.target_xy[:, 0] += 100.0
    batch.target_mask[:, 0] = False
    assert float(masked_mse_m2(scaled, batch, dataset.scaler, 3)) == pytest.approx(0.0, abs=1e-6)


def test_each_member_sums_its_own_steps(dataset: GraphDataset) -> None:
    """Two members of 1 and 3 steps, every target 1 m off in x and 2 m in y at every step (5 m²
    a step), the second step masked for all: 5 m² a target for the first member, 10 m² for the
    second (steps 1 and 3), over 1 and 2 valid steps a target."""
    batch = Collate(dataset.scaler)(dataset.__getitems__([0, 1, 2])).to(dtype=torch.float64)
    targets = len(batch.target_node)
    batch.target_mask[:, :3] = torch.tensor([True, False, True])
    off_m = batch.target_xy[:, :3] + torch.tensor([1.0, 2.0], dtype=torch.float64)  # (A, 3, 2)
    zero = xy_to_metres(dataset.scaler, torch.zeros(2, dtype=torch.float64))  # scaled 0, metres
    scale = xy_to_metres(dataset.scaler, torch.ones(2, dtype=torch.float64)) - zero  # m a unit
    scaled = (off_m - zero) / scale  # the scaled predictions of those positions
    out = torch.stack([scaled, scaled])  # (2, A, 3, 2); member 0 scored on step 1 only
    squared, counts = member_sums(out, batch, dataset.scaler, (1, 3))
    assert counts.tolist() == [targets, 2 * targets]
    assert squared.tolist() == pytest.approx([5.0 * targets, 10.0 * targets], rel=1e-9)


def test_a_members_sums_are_bitwise_its_models_alone(dataset: GraphDataset) -> None:
    batch = Collate(dataset.scaler)(dataset.__getitems__([0, 1, 2, 3]))
    out = torch.randn(3, len(batch.target_node), 25, 2, generator=torch.Generator().manual_seed(1))
    steps = (5, 10, 25)
    squared, counts = member_sums(out, batch, dataset.scaler, steps)
    for member, k in enumerate(steps):
        alone = member_sums(out[member : member + 1, :, :k], batch, dataset.scaler)
        assert torch.equal(squared[member], alone[0][0]) and torch.equal(
            counts[member], alone[1][0]
        )
