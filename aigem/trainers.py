"""The trainers of an epoch of `aigem fit` (aigem.epochs): the models of a fit (`Member`, what
they share: `Loop`), each alone or stacked into ensembles, and their optimiser steps on the
loader's batches or on static ones.

Models that share a ModelConfig, a TrainConfig but for the horizon, their optimisers' step count
and their dropout stream (a multi-horizon fit's, epoch after epoch) train as one ensemble
(aigem.ensemble): stacked when the group first trains, stepped together, and unstacked into each
model and its optimiser at the end of every epoch, before each is validated and checkpointed as
a model trained alone; the next epoch steps the same ensemble again. On the loader's batches a
model alone (or under DDP) steps alone, on its own dropout stream; on static batches
(aigem.engine) a model alone is an ensemble of one.

The loss is the mean squared error in metres^2 over the valid (unmasked) future steps up to the
horizon: predictions are made in scaled coordinates and mapped back to metres before the loss,
so x and y weigh alike.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from aigem import engine, ensemble
from aigem.config import TrainConfig
from aigem.cores import ThreadChooser
from aigem.data import check_covered, xy_to_metres
from aigem.devices import to_device
from aigem.engine import DeviceData, TrainSteps, ValidationSums
from aigem.ensemble import Ensemble
from aigem.model import AiGem
from aigem.records import RunInfo, RunState
from aigem.schedule import clip_gradients, learning_rate_at, set_learning_rate
from ngsim_graphs.scaling import MinMaxScaler

RngState = tuple[torch.Tensor, torch.Tensor | None]  # the CPU generator's state, and CUDA's


def masked_mse_m2(
    model_out: torch.Tensor, batch: dict[str, torch.Tensor], scaler: MinMaxScaler, steps: int
) -> torch.Tensor:
    """Mean squared error in metres^2 over valid steps; (A, steps, 2) scaled predictions."""
    predicted = xy_to_metres(scaler, model_out)
    truth = batch["target_xy"][:, :steps]
    mask = batch["target_mask"][:, :steps].to(predicted.dtype)
    squared = ((predicted - truth) ** 2).sum(dim=-1) * mask
    return squared.sum() / mask.sum().clamp(min=1.0)


def rng_state(device: torch.device) -> RngState:
    cuda = torch.cuda.get_rng_state(device) if device.type == "cuda" else None
    return torch.get_rng_state(), cuda


def _set_rng_state(state: RngState, device: torch.device) -> None:
    torch.set_rng_state(state[0])
    if state[1] is not None:
        torch.cuda.set_rng_state(state[1], device)


@contextmanager
def _own_stream(trainer: Member | Together, device: torch.device) -> Iterator[None]:
    """A step of `trainer` on its own dropout stream: its state set as the global generator's
    before the step (outside any capture: a replay reads it) and kept after it."""
    _set_rng_state(trainer.rng, device)
    yield
    trainer.rng = rng_state(device)


@dataclass(frozen=True)
class Loop:
    """What the models of a fit share: the device, this process's rank, the data."""

    device: torch.device
    rank: int
    world: int
    scaler: MinMaxScaler
    train_loader: DataLoader
    val_loader: DataLoader
    sampler: DistributedSampler | None
    generator: torch.Generator  # the shuffle's
    threads: ThreadChooser
    synthetic: bool  # the build is of synthetic data: the curves say so
    manifest: Path  # the build's, named when its scaler does not cover a train batch
    data: DeviceData | None = None  # the splits on the device: static batches, not the loaders


@dataclass(eq=False)
class Member:
    """One model of a fit and how far it has come: the training loop's state, hence mutable."""

    run_dir: Path
    train: TrainConfig  # its horizon_s is this model's
    steps: int  # future steps predicted and scored
    model: AiGem
    net: nn.Module  # the model, or DistributedDataParallel around it
    optimizer: torch.optim.Optimizer
    info: RunInfo  # what its checkpoints carry
    state: RunState
    who: str  # how errors name it: "" when it trains alone
    stopped: str | None  # why it trains no more: epochs, early stopping, time limit
    rng: RngState | None = None  # its dropout stream, between its steps
    running: torch.Tensor | None = None  # its training loss of the epoch, summed on the device
    shown: float = math.nan  # its mean training loss of the epoch, as last read (NaN: none yet)
    group: Path | None = None  # the multi-horizon run it is a member of
    # when its curves.png was last drawn (time.monotonic; at first, when the fit began: a fit
    # shorter than CURVES_EVERY_S draws it once, at its end)
    drawn_at: float = field(default_factory=time.monotonic)
    drawn: int = -1  # the epochs its curves.png shows (-1: none drawn by this fit)


@dataclass(eq=False)
class Together:
    """Members trained through an epoch as one ensemble, in ascending order of their steps."""

    members: list[Member]
    ensemble: Ensemble
    optimizer: torch.optim.Optimizer
    running: torch.Tensor  # (M,) the members' training losses of the epoch; member.running views
    rng: RngState  # the members' one dropout stream, between their steps
    steps: TrainSteps | None = None  # on static batches (loop.data)
    validation: ValidationSums | None = None

    @property
    def train(self) -> TrainConfig:  # the members' own, but for the horizon
        return self.members[0].train


def _steps_taken(optimizer: torch.optim.Optimizer) -> float:
    state = optimizer.state_dict()["state"]
    return float(next(iter(state.values()))["step"]) if state else 0.0


def _partition(active: list[Member], loop: Loop) -> list[list[Member]]:
    """The active members as they train this epoch: those that share a ModelConfig, a
    TrainConfig but for the horizon, a step count and a dropout stream in one group each,
    ascending in steps; under DDP each alone."""
    if loop.world > 1:
        return [[member] for member in active]
    groups: dict[tuple, list[Member]] = {}
    for member in active:
        key = (
            member.model.config,
            replace(member.train, horizon_s=1.0),
            type(member.optimizer),
            _steps_taken(member.optimizer),
            tuple(bytes(state.numpy()) for state in member.rng if state is not None),
        )
        groups.setdefault(key, []).append(member)
    return [sorted(group, key=lambda member: member.steps) for group in groups.values()]


def group_trainers(
    active: list[Member], loop: Loop, before: list[Member | Together] | None = None
) -> list[Member | Together]:
    """The trainers of this epoch: each group of `_partition` stacked into one ensemble (on
    static batches a member alone too), the others alone. The ensembles of the epoch `before`
    serve again where the groups are the same: their stacked parameters and Adam states are the
    members' own (unstacked at that epoch's end), and a captured step keeps their memory."""
    kept = {
        tuple(map(id, trainer.members)): trainer
        for trainer in before or []
        if isinstance(trainer, Together)
    }
    trainers: list[Member | Together] = []
    for group in _partition(active, loop):
        if len(group) == 1 and (loop.data is None or loop.world > 1):
            trainers.append(group[0])
        elif tuple(map(id, group)) in kept:
            trainers.append(_again(kept[tuple(map(id, group))]))
        else:
            trainers.append(_stack(group, loop))
    return trainers


def _again(together: Together) -> Together:
    """An ensemble of the epoch before for this one: its losses zeroed, its members' stream."""
    together.running.zero_()
    for index, member in enumerate(together.members):
        member.running = together.running[index]
    together.rng = together.members[0].rng
    return together


def _stack(group: list[Member], loop: Loop) -> Together:
    device, data = loop.device, loop.data
    models = [member.model for member in group]
    stacked = ensemble.stack(models, [member.steps for member in group])
    capturable = data is not None and device.type == "cuda"  # its steps are CUDA graphs
    optimizers = [member.optimizer for member in group]
    optimizer = ensemble.stack_optimizer(stacked, optimizers, capturable)
    running = torch.zeros(len(group), dtype=torch.float64, device=device)
    for index, member in enumerate(group):
        member.running = running[index]  # a view: the group's sums are the member's
    together = Together(group, stacked, optimizer, running, group[0].rng)
    if data is not None:
        clip = together.train.clip_grad_norm
        together.steps = TrainSteps(
            stacked, optimizer, data.train, loop.scaler, clip, running, device
        )
        shared = together.steps.replays  # its pool and stream: they never run at once
        together.validation = ValidationSums(stacked, data.val, loop.scaler, device, shared)
    return together


def unstack_together(together: Together) -> None:
    """Each member's parameters, optimiser state and dropout stream back into it."""
    ensemble.unstack(together.ensemble, [member.model for member in together.members])
    rate = together.steps.rate if together.steps is not None else None  # a number, not float32's
    ensemble.unstack_optimizer(together.optimizer, [m.optimizer for m in together.members], rate)
    for member in together.members:
        member.rng = together.rng


def _step(
    member: Member,
    batch: dict[str, Any],
    scaler: MinMaxScaler,
    device: torch.device,
    learning_rate: float,
) -> None:
    """One optimiser step of one model on its own dropout stream; its loss stays on the device."""
    with _own_stream(member, device):
        loss = masked_mse_m2(member.net(batch, member.steps), batch, scaler, member.steps)
        member.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        clip_gradients(member.model.parameters(), member.train.clip_grad_norm)
        set_learning_rate(member.optimizer, learning_rate)
        member.optimizer.step()
        member.running += loss.detach()


def _step_together(
    together: Together,
    batch: dict[str, Any],
    scaler: MinMaxScaler,
    device: torch.device,
    learning_rate: float,
) -> None:
    """One optimiser step of an ensemble: its members' loss summed, each member's gradient its
    own loss's; clipped per member; on the members' one dropout stream."""
    stacked = together.ensemble
    with _own_stream(together, device):
        losses = stacked.member_losses(stacked(batch), batch, scaler)  # (M,)
        together.optimizer.zero_grad(set_to_none=True)
        losses.sum().backward()
        stacked.clip_gradients(together.train.clip_grad_norm)
        set_learning_rate(together.optimizer, learning_rate)
        together.optimizer.step()
        together.running += losses.detach()


def loader_steps(loop: Loop, trainers: list[Member | Together], epoch: int) -> Iterator[int]:
    """Each batch of the train loader (moved to the device once) stepped by every trainer;
    yields its graphs."""
    total = len(loop.train_loader)
    for index, batch in enumerate(loop.train_loader):
        check_covered(batch, loop.scaler, loop.manifest)  # on the CPU: the step never waits
        batch = to_device(batch, loop.device)
        for trainer in trainers:
            rate = learning_rate_at(trainer.train, epoch, index, total)
            if isinstance(trainer, Together):
                _step_together(trainer, batch, loop.scaler, loop.device, rate)
            else:
                _step(trainer, batch, loop.scaler, loop.device, rate)
        yield batch["graphs"]


def static_steps(loop: Loop, trainers: list[Together], epoch: int) -> Iterator[int]:
    """Each static batch of the epoch (the loader's shuffle, aigem.engine) stepped by every
    ensemble; yields its graphs."""
    data = loop.data
    order = engine.shuffled(data.train.samples, loop.generator)
    batches = engine.epoch_batches(
        data.train, order, data.batch_size, data.train_base, data.batch_order, loop.device
    )
    for index in range(len(batches)):
        for together in trainers:  # each on its members' dropout stream, as on the loader's
            rate = learning_rate_at(together.train, epoch, index, len(batches))
            with _own_stream(together, loop.device):
                together.steps(batches.ids[index], batches.tiers[index], data.train_base, rate)
        yield batches.graphs[index]


def batches_per_epoch(loop: Loop) -> int:
    if loop.data is None:
        return len(loop.train_loader)
    return -(-loop.data.train.samples // loop.data.batch_size)
