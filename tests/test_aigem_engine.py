"""The engine of static batches (aigem.training.engine): the epoch's batches are the loader's, validation
over them is the loader's, and the captured steps compute what the one step function called
eagerly computes. The capture itself needs CUDA: those tests run on a GPU machine
(bench/gpu_check.sh runs them) and are skipped elsewhere; their harness runs on the CPU too."""

from __future__ import annotations

import gc
import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from aigem.config import ModelConfig
from aigem.model.data import Collate, GraphDataset
from aigem.model.loss import masked_mse_m2
from aigem.model.network import AiGem
from aigem.training import capacity, engine, trainers
from aigem.training.loading import load_split
from aigem.training.resident import ResidentSplit
from aigem.training.schedule import set_learning_rate
from ngsim_graphs.scaling import MinMaxScaler

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


def _trainer(device: torch.device, scaler: MinMaxScaler, dropout: float = 0.0) -> trainers.Trainer:
    """A trainer of two models (1 and 5 s) on `device`, clipping at 0.5; its Adam capturable
    on CUDA, as a fit's on static batches."""
    torch.manual_seed(0)
    models = [AiGem(ModelConfig(dropout=dropout)).to(device) for _ in range(2)]
    optimizers = [torch.optim.Adam(m.parameters(), lr=1e-3, fused=True) for m in models]
    return trainers.stack_trainer(
        models, optimizers, (5, 25), scaler, 0.5, device, capturable=device.type == "cuda"
    )


def _split(build: Path, split: str, device: torch.device) -> tuple[GraphDataset, ResidentSplit]:
    dataset = GraphDataset(build, split, history_steps=LAYERS + 1)
    return dataset, load_split(dataset, LAYERS).to(device)


def _losses(trainer: trainers.Trainer, batches: object, run) -> list[float]:  # noqa: ANN001
    """Each member's validation loss over `batches`, each batch added by `run`."""
    trainer.start_validation()
    for batch in batches:
        run(trainer, batch)
    return trainer.end_validation()


def test_validation_on_static_batches_is_the_loaders(tiny_build: Path) -> None:
    """The one validation, over static batches (eager on the CPU) and over the loader's: each
    member's loss to float rounding, and each the mean of its model's loss over the split."""
    cpu = torch.device("cpu")
    dataset, split = _split(tiny_build, "val", cpu)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    batches = engine.epoch_batches(
        split, np.arange(len(dataset)), 4, base, dataset.batch_order, cpu
    )
    trainer = _trainer(cpu, dataset.scaler)
    loader = DataLoader(dataset, batch_size=4, collate_fn=Collate(dataset.scaler, layers=LAYERS))
    static = _losses(trainer, batches, trainers.Trainer.add_validation)
    loaded = _losses(trainer, loader, trainers.Trainer.add_validation)
    assert static == pytest.approx(loaded, rel=1e-5)
    assert trainer.ensemble.training  # back to training after it
    everything = Collate(dataset.scaler)(dataset.__getitems__(np.arange(len(dataset))))
    models = [AiGem(ModelConfig()).eval() for _ in range(2)]
    for model, member in zip(models, range(2), strict=True):
        model.load_state_dict({n: p[member] for n, p in trainer.ensemble.params.items()})
    with torch.no_grad():
        whole = [masked_mse_m2(m(everything, k), everything, dataset.scaler, k) for m, k in
                 zip(models, (5, 25), strict=True)]  # fmt: skip
    assert loaded == pytest.approx([float(loss) for loss in whole], rel=1e-5)


def captured_against_eager(
    build: Path, device: torch.device, dropout: float, validated: int | None = None
) -> None:
    """Eleven steps over batches of two tiers in an irregular order (each tier warmed up twice,
    captured at its third call, then replayed out of the order of capture), with `dropout`, the
    members' stream seeded again half-way (as each epoch is), validation sharing the steps'
    pool and stream called between them: against the same step and validation functions called
    eagerly on the assembled batches, the same parameters, losses and validation sums (to the
    rounding of the GPU's atomic sums). Each trainer runs its whole sequence from one seed, so
    both draw the same dropout masks. On the CPU both are eager (the same path as a fit's).
    `validated`: the validation's first batches (None: all)."""
    dataset, split = _split(build, "train", device)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    order = np.random.default_rng(0).permutation(len(dataset))
    batches = engine.epoch_batches(split, order, 4, base, dataset.batch_order, device)
    tiers = [0, 1, 0, 1, 0, 1, 1, 0, 1, 1, 0]
    val = [batches[row] for row in range(len(batches))][:validated]

    def run(trainer: trainers.Trainer, step, add) -> list[list[float]]:  # noqa: ANN001
        torch.manual_seed(5)
        trainer.rng = trainers.rng_state(device)
        losses = []
        for row, tier in enumerate(tiers):
            if row == 6:
                torch.manual_seed(6)
                trainer.rng = trainers.rng_state(device)
            static = batches[row]
            step(trainer, replace(static, tier=tier, capacity=capacity.tier(base, tier)))
            if row >= 5:  # both tiers captured: their replays, then validation's
                losses.append(_losses(trainer, val, add))
        return losses

    def called(trainer: trainers.Trainer, static: engine.StaticBatch) -> None:
        with trainer._own_stream(device):
            set_learning_rate(trainer.optimizer, 1e-3)
            trainer._step(static.assembled())

    def added(trainer: trainers.Trainer, static: engine.StaticBatch) -> None:
        trainer._add_validation(static.assembled())

    captured = _trainer(device, dataset.scaler, dropout)
    replayed = lambda trainer, static: trainer.step(static, 1e-3)  # noqa: E731
    mine = run(captured, replayed, trainers.Trainer.add_validation)  # eager twice, then captured
    eager = _trainer(device, dataset.scaler, dropout)
    theirs = run(eager, called, added)
    if device.type == "cuda":
        assert len(captured.replays.graphs) == 2
        assert len(captured.validation.graphs) == len({static.tier for static in val})
    torch.testing.assert_close(captured.running, eager.running, rtol=1e-5, atol=1e-6)
    for a, b in zip(captured.ensemble.parameters(), eager.ensemble.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    for ours, others in zip(mine, theirs, strict=True):
        assert ours == pytest.approx(others, rel=1e-5)
    assert float(captured.running.sum()) > 0 and captured.rate == 1e-3


def test_the_cpus_static_steps_are_the_step_called_on_assembled_batches(tiny_build: Path) -> None:
    """The harness of the captured steps' test, on the CPU: a trainer's step of a static batch
    is its one step function of the batch assembled (no capture here; the same path as a fit's
    `--resident` on the CPU)."""
    captured_against_eager(tiny_build, torch.device("cpu"), dropout=0.1, validated=2)


@cuda
@pytest.mark.parametrize("dropout", [0.0, 0.1])  # the second alone failing: the masks differ
def test_captured_steps_are_the_eager_steps(tiny_build: Path, dropout: float) -> None:
    captured_against_eager(tiny_build, torch.device("cuda"), dropout)


@cuda
def test_a_dropped_owners_graphs_go_at_once(tiny_build: Path) -> None:
    """Nothing holds a step's owner but its user: its graphs are freed when it is dropped, never
    by the garbage collector in the middle of another capture."""
    device = torch.device("cuda")
    dataset, split = _split(tiny_build, "train", device)
    base = capacity.base_capacity(split.counts, 4, LAYERS)
    batches = engine.epoch_batches(
        split, np.arange(len(dataset)), 4, base, dataset.batch_order, device
    )
    gc.disable()
    try:
        trainer = _trainer(device, dataset.scaler)
        for _ in range(3):
            trainer.step(batches[0], 1e-3)
        assert len(trainer.replays.graphs) == 1
        gone = weakref.ref(trainer)
        del trainer
        assert gone() is None
    finally:
        gc.enable()
