"""The training loop's loss: metres^2 over the valid future steps, falling as the model learns."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.utils.data import DataLoader

from aigem.config import ModelConfig
from aigem.data import Collate, GraphDataset, xy_to_metres
from aigem.epochs import masked_mse_m2
from aigem.model import AiGem


def test_loss_falls_in_a_few_steps(tiny_build: Path) -> None:
    torch.manual_seed(0)
    dataset = GraphDataset(tiny_build, "train")
    batch = next(iter(DataLoader(dataset, batch_size=8, collate_fn=Collate(dataset.scaler))))
    model = AiGem(ModelConfig(dropout=0.0))
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    losses = []
    for _ in range(30):
        loss = masked_mse_m2(model(batch, 5), batch, dataset.scaler, 5)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


def test_masked_steps_count_in_no_loss(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "train")
    batch = Collate(dataset.scaler)(dataset.__getitems__([0, 1]))
    truth = xy_to_metres(dataset.scaler, torch.zeros(1, 1, 2))  # scaled 0 -> some metres
    scaled = torch.zeros(len(batch["target_node"]), 3, 2)
    batch["target_xy"][:, :3] = truth
    assert float(masked_mse_m2(scaled, batch, dataset.scaler, 3)) == pytest.approx(0.0, abs=1e-6)
    batch["target_xy"][:, 0] += 100.0
    batch["target_mask"][:, 0] = False
    assert float(masked_mse_m2(scaled, batch, dataset.scaler, 3)) == pytest.approx(0.0, abs=1e-6)
