"""The trainers of `aigem fit` (aigem.training.epochs): a fit's models (`Member`; what they share: `Loop`)
stacked into ensembles (`Trainer`: M >= 1 models, a model alone an ensemble of one), the one
training step and the one validation.

Models that share a ModelConfig, a TrainConfig but for the horizon, their optimisers' step count
and their dropout stream (a multi-horizon fit's, epoch after epoch) train as one ensemble
(aigem.training.ensemble), stacked when they first train together and kept stacked through the fit: each
epoch's steps and its validation run on the stack, which is unstacked into each model and its
optimiser only to write that model's checkpoint. Under DistributedDataParallel each model trains
alone, an ensemble of one whose forward goes through the DDP wrapper.

Every batch, the loader's (`aigem.model.batch.Batch`) or a static one (`aigem.training.engine.StaticBatch`),
goes through the same two functions: `Trainer._step` (forward, each member's masked loss,
backward, clipping, the optimiser's step) and `Trainer._add_validation` (each member's squared
error and count, forward only). A static batch's are assembled and, on CUDA, captured once per
capacity and replayed (`aigem.training.engine.Replays`); the learning rate is set in one place before
either (`Trainer.step`: a number, or a capturable optimiser's device tensor filled), and nothing
in a step reads a number back. The loss is aigem.model.loss's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from aigem.config import TrainConfig
from aigem.cores import ThreadChooser
from aigem.model.batch import Batch
from aigem.model.data import check_covered
from aigem.model.network import AiGem
from aigem.runs.records import RunInfo, RunState
from aigem.training import engine, ensemble
from aigem.training.engine import DeviceData, Replays, StaticBatch
from aigem.training.ensemble import Ensemble
from aigem.training.schedule import learning_rate_at, set_learning_rate
from ngsim_graphs.scaling import MinMaxScaler

RngState = tuple[torch.Tensor, torch.Tensor | None]  # the CPU generator's state, and CUDA's


def rng_state(device: torch.device) -> RngState:
    cuda = torch.cuda.get_rng_state(device) if device.type == "cuda" else None
    return torch.get_rng_state(), cuda


def _set_rng_state(state: RngState, device: torch.device) -> None:
    torch.set_rng_state(state[0])
    if state[1] is not None:
        torch.cuda.set_rng_state(state[1], device)


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
    """One model of a fit and how far it has come: the training loop's state, hence mutable.
    Between its checkpoints its parameters and optimiser state are its trainer's (stacked)."""

    run_dir: Path
    train: TrainConfig  # its horizon_s is this model's
    steps: int  # future steps predicted and scored
    model: AiGem
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
class Trainer:
    """M >= 1 models stacked into one ensemble and stepped as one, on one dropout stream: each
    member's gradient its own loss's, each clipped on its own; `running` (M,) float64 sums each
    member's training loss on the device, `sums` (2, M) its validation's squared errors (each
    batch's mean loss times its valid steps) and their count. `net` is the ensemble, or
    DistributedDataParallel around it."""

    ensemble: Ensemble
    net: nn.Module
    optimizer: torch.optim.Optimizer
    scaler: MinMaxScaler
    clip_grad_norm: float | None
    running: torch.Tensor
    rng: RngState
    replays: Replays  # a static batch's steps
    validation: Replays  # a static batch's validation (the steps' pool and stream)
    sums: torch.Tensor
    members: list[Member] = field(default_factory=list)  # in ascending order of their steps
    rate: float | None = None  # the learning rate of the last step, a number

    @property
    def train(self) -> TrainConfig:  # the members' own, but for the horizon
        return self.members[0].train

    @contextmanager
    def _own_stream(self, device: torch.device) -> Iterator[None]:
        """The members' dropout stream set as the global generator's (outside any capture: a
        replay reads it) and kept after."""
        _set_rng_state(self.rng, device)
        yield
        self.rng = rng_state(device)

    def step(self, batch: Batch | StaticBatch, rate: float) -> None:
        """One optimiser step of the members on `batch` at learning rate `rate`, set here for
        both kinds of batch (outside a capture, which reads a capturable optimiser's rate from
        its device tensor)."""
        with self._own_stream(self.running.device):
            set_learning_rate(self.optimizer, rate)
            self.rate = rate
            self.replays(self._step, batch)

    def _step(self, batch: Batch) -> None:
        """The training step, written once: forward through `net`, each member's masked MSE in
        metres^2, their sum's backward (each member's gradient its own loss's), clipping, the
        optimiser's step at the rate set, the losses summed on the device. It reads nothing
        back, so a CUDA graph captures it whole (aigem.training.engine)."""
        self.optimizer.zero_grad(set_to_none=True)  # a capture's gradients are the graph's own
        losses = self.ensemble.member_losses(self.net(batch), batch, self.scaler)
        losses.sum().backward()
        self.ensemble.clip_gradients(self.clip_grad_norm)
        self.optimizer.step()
        self.running += losses.detach()

    def add_validation(self, batch: Batch | StaticBatch) -> None:
        """Each member's squared error over `batch`'s valid target steps and their count added
        to `sums` (the ensemble in evaluation mode: `start_validation`)."""
        self.validation(self._add_validation, batch)

    def _add_validation(self, batch: Batch) -> None:
        with torch.no_grad():
            squared, counts = self.ensemble.member_sums(
                self.ensemble.predict(batch), batch, self.scaler
            )
            means = squared / counts.clamp(min=1.0)  # each member's loss, as training's
            self.sums += torch.stack([means.double() * counts.double(), counts.double()])

    def start_validation(self) -> None:
        self.ensemble.eval()
        self.sums.zero_()

    def end_validation(self) -> list[float]:
        """Each member's mean validation loss in metres^2 (read once; NaN where no target step
        counts); the ensemble back to training."""
        self.ensemble.train()
        totals, counts = self.sums.tolist()
        return [t / c if c else math.nan for t, c in zip(totals, counts, strict=True)]

    def unstack(self) -> None:
        """Each member's parameters, optimiser state (the rate of the last step) and dropout
        stream back into it, for its checkpoint."""
        ensemble.unstack(self.ensemble, [member.model for member in self.members])
        optimizers = [member.optimizer for member in self.members]
        ensemble.unstack_optimizer(self.optimizer, optimizers, self.rate)
        for member in self.members:
            member.rng = self.rng


def stack_trainer(
    models: Sequence[AiGem],
    optimizers: Sequence[torch.optim.Optimizer],
    steps: Sequence[int],
    scaler: MinMaxScaler,
    clip_grad_norm: float | None,
    device: torch.device,
    capturable: bool = False,
    distributed: bool = False,
) -> Trainer:
    """A Trainer of copies of `models` (one ModelConfig; `steps` ascending) and their
    optimisers' states, stacked; `capturable`: its steps are CUDA graphs (static batches on
    CUDA); `distributed`: its forward through DistributedDataParallel."""
    stacked = ensemble.stack(models, steps)
    optimizer = ensemble.stack_optimizer(stacked, optimizers, capturable)
    net = nn.parallel.DistributedDataParallel(stacked) if distributed else stacked
    members = len(models)
    running = torch.zeros(members, dtype=torch.float64, device=device)
    sums = torch.zeros(2, members, dtype=torch.float64, device=device)
    replays = Replays(device)  # validation shares its pool and stream: they never run at once
    validation = Replays(device, replays)
    state = rng_state(device)
    return Trainer(
        stacked, net, optimizer, scaler, clip_grad_norm, running, state, replays, validation, sums
    )


def _steps_taken(optimizer: torch.optim.Optimizer) -> float:
    state = optimizer.state_dict()["state"]
    return float(next(iter(state.values()))["step"]) if state else 0.0


def partition(active: list[Member], loop: Loop) -> list[list[Member]]:
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
    active: list[Member], loop: Loop, before: list[Trainer] | None = None
) -> list[Trainer]:
    """The trainers of this epoch, one per group of `partition`. The trainers of the epoch
    `before` serve again where the groups are the same: their stacked parameters and Adam
    states are the members' own (unstacked at that epoch's end into the checkpoints), and a
    captured step keeps their memory."""
    kept = {tuple(map(id, trainer.members)): trainer for trainer in before or []}
    trainers = []
    for group in partition(active, loop):
        trainer = kept.get(tuple(map(id, group)))
        trainers.append(_again(trainer) if trainer is not None else _stack(group, loop))
    return trainers


def _again(trainer: Trainer) -> Trainer:
    """A trainer of the epoch before for this one: its losses zeroed, its members' stream."""
    trainer.running.zero_()
    for index, member in enumerate(trainer.members):
        member.running = trainer.running[index]
    trainer.rng = trainer.members[0].rng
    return trainer


def _stack(group: list[Member], loop: Loop) -> Trainer:
    capturable = loop.data is not None and loop.device.type == "cuda"  # its steps: CUDA graphs
    trainer = stack_trainer(
        [member.model for member in group],
        [member.optimizer for member in group],
        [member.steps for member in group],
        loop.scaler,
        group[0].train.clip_grad_norm,
        loop.device,
        capturable,
        distributed=loop.world > 1,
    )
    trainer.members, trainer.rng = group, group[0].rng
    for index, member in enumerate(group):
        member.running = trainer.running[index]  # a view: the trainer's sums are the member's
    return trainer


def _train_batches(loop: Loop) -> Iterator[Batch | StaticBatch]:
    """The epoch's batches: the train loader's, checked and moved to the device once; or the
    static batches of the loader's shuffle (aigem.training.engine)."""
    data = loop.data
    if data is None:
        for batch in loop.train_loader:
            check_covered(batch, loop.scaler, loop.manifest)  # on the CPU: the step never waits
            yield batch.to(loop.device, non_blocking=True)
        return
    order = engine.shuffled(data.train.samples, loop.generator)
    yield from engine.epoch_batches(
        data.train, order, data.batch_size, data.train_base, data.batch_order, loop.device
    )


def train_steps(loop: Loop, trainers: list[Trainer], epoch: int) -> Iterator[int]:
    """Each batch of the epoch stepped by every trainer (each on its members' dropout stream, at
    its learning rate); yields the batch's graphs."""
    total = batches_per_epoch(loop)
    for index, batch in enumerate(_train_batches(loop)):
        for trainer in trainers:
            trainer.step(batch, learning_rate_at(trainer.train, epoch, index, total))
        yield batch.graphs


def validation_losses(loop: Loop, trainers: list[Trainer]) -> list[tuple[Member, float]]:
    """Each member's mean validation loss in metres^2, pooled over the validation split's valid
    target steps: one pass over its batches (the loader's, or the static ones made once) for
    every trainer, the sums read once at the end."""
    for trainer in trainers:
        trainer.start_validation()
    data = loop.data
    batches = loop.val_loader if data is None else data.val_batches
    for batch in batches:
        batch = batch.to(loop.device, non_blocking=True) if data is None else batch
        for trainer in trainers:
            trainer.add_validation(batch)
    return [
        (member, loss)
        for trainer in trainers
        for member, loss in zip(trainer.members, trainer.end_validation(), strict=True)
    ]


def batches_per_epoch(loop: Loop) -> int:
    if loop.data is None:
        return len(loop.train_loader)
    return -(-loop.data.train.samples // loop.data.batch_size)
