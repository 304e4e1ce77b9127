"""The engine of static batches (aigem.engine): the epoch's batches are the loader's, and the
captured steps compute what the steps called eagerly compute. The capture itself needs CUDA:
those tests run on a GPU machine (bench/gpu_check.sh runs them) and are skipped elsewhere."""

from __future__ import annotations

import gc
import weakref
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from aigem import capacity, engine, ensemble
from aigem.config import ModelConfig
from aigem.data import Collate, GraphDataset
from aigem.epochs import evaluate_losses
from aigem.model import AiGem
from aigem.resident import load_split
from aigem.schedule import set_learning_rate

LAYERS = ModelConfig().layers
cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="captures need CUDA")


def test_an_epochs_order_is_the_loaders_shuffle(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "train", history_steps=LAYERS + 1)
    generator = torch.Generator()
    generator.manual_seed(7)
    loader = DataLoader(range(len(dataset)), batch_size=5, shuffle=True, generator=generator)
    expected = torch.cat(list(loader)).numpy()
    generator.manual_seed(7)
    assert np.array_equal(engine.shuffled(len(dataset), generator), expected)


def test_an_epochs_batches_are_padded_with_the_empty_sample_and_take_a_tier(
    tiny_build: Path,
) -> None:
    dataset = GraphDataset(tiny_build, "train", history_steps=LAYERS + 1)
    split = load_split(dataset, LAYERS)
    order = np.arange(len(dataset))[::-1].copy()
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    small = capacity.Capacity(4, (1,) * len(base.sizes), LAYERS)  # too small for any batch
    batches = engine.epoch_batches(split, order, 4, small, dataset.batch_order, torch.device("cpu"))
    assert len(batches) == -(-len(dataset) // 4) and sum(batches.graphs) == len(dataset)
    for row, graphs in zip(batches.ids.numpy(), batches.graphs, strict=True):
        assert (row[graphs:] == split.empty_id).all()
    first = batches.ids[0, :4].numpy()
    assert np.array_equal(first, dataset.batch_order(order[:4]))  # by recording, as the loader's
    need = split.counts[first].sum(0)
    assert batches.tiers[0] == capacity.tier_of(small, need) > 0


def test_validation_on_static_batches_is_the_loaders(tiny_build: Path) -> None:
    """Each member's validation loss summed over static batches (eager on the CPU) is the one
    `evaluate_losses` takes over the loader's batches, to float rounding."""
    dataset = GraphDataset(tiny_build, "val", history_steps=LAYERS + 1)
    split = load_split(dataset, LAYERS)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    cpu = torch.device("cpu")
    batches = engine.epoch_batches(
        split, np.arange(len(dataset)), 4, base, dataset.batch_order, cpu
    )
    torch.manual_seed(0)
    models = [AiGem(ModelConfig()) for _ in range(2)]
    sums = engine.ValidationSums(ensemble.stack(models, (5, 25)), split, dataset.scaler, cpu)
    loader = DataLoader(dataset, batch_size=4, collate_fn=Collate(dataset.scaler, layers=LAYERS))
    expected = evaluate_losses(list(zip(models, (5, 25), strict=True)), loader, dataset.scaler, cpu)
    assert sums.losses(batches, base) == pytest.approx(expected, rel=1e-5)
    assert sums.ensemble.training  # back to training after it


def _steps(split, dataset: GraphDataset, device: torch.device, base: capacity.Capacity,
           dropout: float = 0.0):  # fmt: skip  # noqa: ANN001, ANN202
    torch.manual_seed(0)
    models = [AiGem(ModelConfig(dropout=dropout)).to(device) for _ in range(2)]
    stacked = ensemble.stack(models, (5, 25))
    optimizers = [torch.optim.Adam(m.parameters(), lr=1e-3, fused=True) for m in models]
    optimizer = ensemble.stack_optimizer(stacked, optimizers, capturable=device.type == "cuda")
    running = torch.zeros(2, dtype=torch.float64, device=device)
    return engine.TrainSteps(stacked, optimizer, split, dataset.scaler, 0.5, running, device)


def captured_against_eager(build: Path, device: torch.device, dropout: float) -> None:
    """Eleven steps over batches of two tiers in an irregular order (each tier warmed up twice,
    captured at its third call, then replayed out of the order of capture), with `dropout`, the
    global generator seeded again half-way (as each epoch is), validation sharing the steps'
    pool and stream called between them: against the same steps and validations called
    eagerly, the same parameters, losses and validation sums (to the rounding of the GPU's
    atomic sums). Each instance runs its whole sequence from one seed, so both draw the same
    dropout masks."""
    dataset = GraphDataset(build, "train", history_steps=LAYERS + 1)
    split = load_split(dataset, LAYERS).to(device)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    order = np.random.default_rng(0).permutation(len(dataset))
    batches = engine.epoch_batches(split, order, 4, base, dataset.batch_order, device)
    tiers = [0, 1, 0, 1, 0, 1, 1, 0, 1, 1, 0]

    def run(steps: engine.TrainSteps, step, validation) -> list[list[float]]:  # noqa: ANN001
        torch.manual_seed(5)
        losses = []
        for row, tier in enumerate(tiers):
            if row == 6:
                torch.manual_seed(6)
            step(steps, row, tier)
            if row >= 5:  # both tiers captured: their replays, then validation's
                losses.append(validation(steps).losses(batches, base))
        return losses

    def replayed(steps: engine.TrainSteps, row: int, tier: int) -> None:
        steps(batches.ids[row], tier, base, 1e-3)

    def called(steps: engine.TrainSteps, row: int, tier: int) -> None:
        set_learning_rate(steps.optimizer, 1e-3)
        steps._step(batches.ids[row], capacity.tier(base, tier))

    captured = _steps(split, dataset, device, base, dropout)
    shared = engine.ValidationSums(
        captured.ensemble, split, dataset.scaler, device, captured.replays
    )
    mine = run(captured, replayed, lambda steps: shared)  # eager twice, then captured
    eager = _steps(split, dataset, device, base, dropout)
    fresh = lambda steps: engine.ValidationSums(steps.ensemble, split, dataset.scaler, device)  # noqa: E731
    theirs = run(eager, called, fresh)  # a first call: eager
    if device.type == "cuda":
        assert len(captured.replays.graphs) == 2
        assert len(shared.replays.graphs) == len(set(batches.tiers))
    torch.testing.assert_close(captured.running, eager.running, rtol=1e-5, atol=1e-6)
    for a, b in zip(captured.ensemble.parameters(), eager.ensemble.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    for ours, others in zip(mine, theirs, strict=True):
        assert ours == pytest.approx(others, rel=1e-5)


@cuda
@pytest.mark.parametrize("dropout", [0.0, 0.1])  # the second alone failing: the masks differ
def test_captured_steps_are_the_eager_steps(tiny_build: Path, dropout: float) -> None:
    captured_against_eager(tiny_build, torch.device("cuda"), dropout)


@cuda
def test_a_dropped_owners_graphs_go_at_once(tiny_build: Path) -> None:
    """Nothing holds a step's owner but its user: its graphs are freed when it is dropped, never
    by the garbage collector in the middle of another capture."""
    device = torch.device("cuda")
    dataset = GraphDataset(tiny_build, "train", history_steps=LAYERS + 1)
    split = load_split(dataset, LAYERS).to(device)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    batches = engine.epoch_batches(
        split, np.arange(len(dataset)), 4, base, dataset.batch_order, device
    )
    gc.disable()
    try:
        steps = _steps(split, dataset, device, base)
        for _ in range(3):
            steps(batches.ids[0], 0, base, 1e-3)
        assert len(steps.replays.graphs) == 1
        gone = weakref.ref(steps)
        del steps
        assert gone() is None
    finally:
        gc.enable()
