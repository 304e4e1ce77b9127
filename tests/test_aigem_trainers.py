"""The trainers of an epoch: the one step trains (a model alone, an ensemble of one), and which
models train as one ensemble."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch
from torch.utils.data import DataLoader

from aigem.config import ModelConfig, TrainConfig
from aigem.model.data import Collate, GraphDataset
from aigem.model.loss import masked_mse_m2
from aigem.model.network import AiGem
from aigem.runs.records import RunState
from aigem.training import trainers
from aigem.training.epochs import Loop, Member
from aigem.training.fit import device_data, make_optimizer
from aigem.training.trainers import Trainer


def test_the_step_trains_a_model_alone(tiny_build: Path) -> None:
    """fit's one step of an ensemble of one: its loss falls in a few steps on one batch, and
    it is the model's masked loss (aigem.model.loss) before each step."""
    torch.manual_seed(0)
    dataset = GraphDataset(tiny_build, "train")
    batch = next(iter(DataLoader(dataset, batch_size=8, collate_fn=Collate(dataset.scaler))))
    model, cpu = AiGem(ModelConfig(dropout=0.0)), torch.device("cpu")
    optimizer = make_optimizer(model, TrainConfig(), cpu)
    with torch.no_grad():
        first = float(masked_mse_m2(model(batch, 5), batch, dataset.scaler, 5))
    trainer = trainers.stack_trainer([model], [optimizer], [5], dataset.scaler, None, cpu)
    losses = []
    for _ in range(30):
        before = float(trainer.running[0])
        trainer.step(batch, 1e-3)
        losses.append(float(trainer.running[0]) - before)
    assert losses[0] == pytest.approx(first, rel=1e-6)
    assert losses[-1] < 0.5 * losses[0] and trainer.rate == 1e-3


def _member(steps: int, config: ModelConfig, seed: int) -> Member:
    """A model of a fit with `steps` future steps, new (no optimiser step taken)."""
    torch.manual_seed(seed)
    model = AiGem(config)
    train = TrainConfig(horizon_s=steps / 5)
    optimizer = make_optimizer(model, train, torch.device("cpu"))
    return Member(
        Path(f"h{steps}"),
        train,
        steps,
        model,
        optimizer,
        info={},
        state=RunState(),
        who="",
        stopped=None,
        rng=(torch.Generator().manual_seed(0).get_state(), None),  # every epoch starts one seed
    )


def _loop(world: int) -> Loop:
    """A Loop of `world` processes; `_group` reads its device and world size only."""
    return Loop(
        torch.device("cpu"),
        rank=0,
        world=world,
        scaler=None,
        train_loader=None,
        val_loader=None,
        sampler=None,
        generator=torch.Generator(),
        threads=None,
        synthetic=True,
        manifest=Path("manifest.json"),
    )


def test_members_that_share_their_settings_train_as_one_ensemble_in_one_process_only() -> None:
    paper, two_heads = ModelConfig(), ModelConfig(heads=2)
    middle, short, other, long = (
        _member(10, paper, seed=1),
        _member(5, paper, seed=2),
        _member(5, two_heads, seed=3),
        _member(25, paper, seed=4),
    )
    members = [middle, short, other, long]
    together, alone = trainers.group_trainers(members, _loop(world=1))
    assert isinstance(together, Trainer) and alone.members == [other]  # an ensemble of one
    assert together.members == [short, middle, long]  # ascending steps
    assert alone.net is alone.ensemble and alone.ensemble.steps == (5,)
    assert together.ensemble.steps == (5, 10, 25)
    stacked = together.ensemble.params["decoder.weight_ih"]
    for index, member in enumerate(together.members):
        assert torch.equal(stacked[index], member.model.decoder.weight_ih)
    # A member on another dropout stream steps alone (none is, in a fit: one seed an epoch)
    long.rng = (torch.Generator().manual_seed(1).get_state(), None)
    together, *alone = trainers.group_trainers(members, _loop(world=1))
    assert together.members == [short, middle]
    assert [trainer.members for trainer in alone] == [[other], [long]]
    # Under DDP each model steps alone, through its DistributedDataParallel: nothing stacked
    # (the wrapper needs a process group: tests/test_aigem_training.py trains under torchrun).
    assert trainers.partition(members, _loop(world=2)) == [[member] for member in members]


def _static_epoch(build: Path, groups: list[list[Member]]) -> list[Trainer]:
    """One epoch of static batches (the splits on the CPU) stepped by an ensemble of each group."""
    cpu = torch.device("cpu")
    config = ModelConfig()
    data = device_data(build, config, TrainConfig(batch_size=16), cpu, workers=0)
    scaler = GraphDataset(build, "train").scaler
    loop = replace(_loop(world=1), scaler=scaler, data=data)
    loop.generator.manual_seed(0)
    together = [trainers._stack(group, loop) for group in groups]
    torch.manual_seed(99)  # what the global stream holds before: no member's
    for _ in trainers.train_steps(loop, together, epoch=0):
        pass
    return together


def test_each_ensemble_on_static_batches_draws_its_own_dropout_stream(tiny_build: Path) -> None:
    """Two ensembles step each static batch in turn; the first ends as it ends stepping alone,
    its dropout masks drawn from its members' stream, not after the other's draws."""
    paper, two_heads = ModelConfig(), ModelConfig(heads=2)
    both = _static_epoch(
        tiny_build, [[_member(5, paper, 1), _member(10, paper, 2)], [_member(5, two_heads, 3)]]
    )
    alone = _static_epoch(tiny_build, [[_member(5, paper, 1), _member(10, paper, 2)]])
    ours, theirs = both[0].ensemble.params, alone[0].ensemble.params
    assert all(torch.equal(ours[name], theirs[name]) for name in theirs)
    assert torch.equal(both[0].rng[0], alone[0].rng[0])  # where the stream ended
    start = _member(5, paper, 1).rng[0]
    assert not torch.equal(both[0].rng[0], start) and not torch.equal(both[1].rng[0], start)
