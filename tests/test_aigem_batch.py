"""The typed batch (aigem.model.batch): moved to a device and to another float type whole, pinned for
a DataLoader (its workers hand it over: tests/test_aigem_data.py)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest
import torch
from torch.utils.data._utils.pin_memory import pin_memory

from aigem.model.batch import Batch, Edges
from aigem.model.data import Collate, GraphDataset


def same(a: object, b: object) -> bool:
    """Equal batch values: tensors element for element, edges and anything else by ==."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, Edges):
        return same(a.index, b.index) and same(a.attr, b.attr)
    return torch.equal(a, b) if isinstance(a, torch.Tensor) else a == b


def same_batches(a: Batch, b: Batch, but: tuple[str, ...] = ()) -> None:
    """Every field of two batches equal (`same`), but the fields `but`."""
    for name in (f.name for f in fields(Batch) if f.name not in but):
        assert same(getattr(a, name), getattr(b, name)), name


@pytest.fixture(scope="module")
def batch(tiny_build: Path) -> Batch:
    dataset = GraphDataset(tiny_build, "train", history_steps=3)
    return Collate(dataset.scaler, layers=2)(dataset.__getitems__([0, 1, 2]))


def _tensors(batch: Batch) -> list[torch.Tensor]:
    """Every tensor of a batch: its fields', its edges' and its plan's."""
    tensors = [getattr(batch, f.name) for f in fields(Batch)]
    tensors = [t for t in tensors if isinstance(t, torch.Tensor)]
    tensors += [t for edges in batch.edges.values() for t in (edges.index, edges.attr)]
    plan = batch.plan
    tensors += [plan.order, plan.outputs]
    return tensors + [t for a in plan.adjacency for t in (a.crow, a.col, a.row, a.attr)]


def test_a_batch_moves_whole_and_casts_its_floats_only(batch: Batch) -> None:
    cpu = batch.to(torch.device("cpu"), non_blocking=True)
    assert cpu.graphs == batch.graphs == 3 and cpu.edge_types == batch.edge_types
    assert all(a is b for a, b in zip(_tensors(cpu), _tensors(batch), strict=True))  # no copy
    double = batch.to(dtype=torch.float64)
    for before, after in zip(_tensors(batch), _tensors(double), strict=True):
        assert after.dtype == (torch.float64 if before.is_floating_point() else before.dtype)
        assert torch.equal(after, before.to(after.dtype))
    assert batch.x.dtype == torch.float32  # the batch itself unchanged: a new one


def test_pinning_pins_every_tensor(batch: Batch, monkeypatch: pytest.MonkeyPatch) -> None:
    """What a DataLoader's pin_memory=True does to each batch: every tensor pinned (without an
    accelerator, pinning is recorded instead: PyTorch pins for one)."""
    pinned: list[int] = []
    if not torch.cuda.is_available():
        monkeypatch.setattr(torch.Tensor, "pin_memory", lambda t: pinned.append(id(t)) or t)
    out = pin_memory(batch)
    assert isinstance(out, Batch)
    if torch.cuda.is_available():
        assert all(t.is_pinned() for t in _tensors(out))
    else:
        assert sorted(pinned) == sorted(id(t) for t in _tensors(batch))
