"""The training loop of `aigem fit`: epochs of optimiser steps, each batch (moved to the device
once) training every model of a fit on its own dropout stream, the validation loss after each
epoch, a checkpoint and a log row per epoch (aigem.runs), early stopping and the time limit.
aigem.training sets up the models and the data and calls `train_epochs`.

Models that share a ModelConfig, a TrainConfig but for the horizon and their optimisers' step
count (a multi-horizon fit's, epoch after epoch) train through each epoch as one ensemble
(aigem.ensemble): stacked at the start of the epoch (parameters, Adam states, dropout streams),
stepped together, and unstacked into each model and its optimiser at the end, before each is
validated and checkpointed as a model trained alone. A model alone, or under DDP, steps alone.
The ensemble runs eagerly: a compiled decoder (`TrainConfig.compile`) serves a model alone.

The loss is the mean squared error in metres^2 over the valid (unmasked) future steps up to the
horizon: predictions are made in scaled coordinates and mapped back to metres before the loss,
so x and y weigh alike.
"""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from aigem import ensemble, runs
from aigem.config import TrainConfig
from aigem.cores import ThreadChooser
from aigem.data import check_covered, xy_to_metres
from aigem.devices import to_device
from aigem.ensemble import Ensemble
from aigem.model import AiGem
from aigem.schedule import clip_gradients, learning_rate_at, set_learning_rate
from ngsim_graphs.interrupts import interrupts_held
from ngsim_graphs.scaling import MinMaxScaler

READ_LOSS_EVERY_S = 0.5  # the running loss is read from the device (and checked) this often
# (epoch, batches done, batches in the epoch, each model's running train loss as last read, NaN
# for a model not training in this epoch): the CLI draws a bar from it.
TrainProgress = Callable[[int, int, int, tuple[float, ...]], None]
# (the model's horizon in s, the row of its metrics.jsonl written at the end of an epoch): the CLI
# prints it.
EpochCallback = Callable[[float, dict[str, float]], None]
RngState = tuple[torch.Tensor, torch.Tensor | None]  # the CPU generator's state, and CUDA's


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or infinite: training stops rather than save a broken model."""


def masked_mse_m2(
    model_out: torch.Tensor, batch: dict[str, torch.Tensor], scaler: MinMaxScaler, steps: int
) -> torch.Tensor:
    """Mean squared error in metres^2 over valid steps; (A, steps, 2) scaled predictions."""
    predicted = xy_to_metres(scaler, model_out)
    truth = batch["target_xy"][:, :steps]
    mask = batch["target_mask"][:, :steps].to(predicted.dtype)
    squared = ((predicted - truth) ** 2).sum(dim=-1) * mask
    return squared.sum() / mask.sum().clamp(min=1.0)


def evaluate_losses(
    models: Sequence[tuple[nn.Module, int]],
    loader: DataLoader,
    scaler: MinMaxScaler,
    device: torch.device,
) -> list[float]:
    """Mean validation loss in metres^2 of each (model, steps), weighted by valid steps; one pass
    over `loader` for all of them."""
    totals = torch.zeros(len(models), dtype=torch.float64, device=device)  # read once, at the end
    counts = torch.zeros(len(models), dtype=torch.float64, device=device)
    for model, _ in models:
        model.eval()
    with torch.no_grad():
        for batch in loader:
            batch = to_device(batch, device)
            for index, (model, steps) in enumerate(models):
                valid = batch["target_mask"][:, :steps].sum()
                loss = masked_mse_m2(model(batch, steps), batch, scaler, steps)
                totals[index] += loss.double() * valid
                counts[index] += valid
    for model, _ in models:
        model.train()
    return [t / c if c else math.nan for t, c in zip(totals.tolist(), counts.tolist(), strict=True)]


def _read_loss(
    running: torch.Tensor, batches: int, epoch: int, first: int, last: int, who: str = ""
) -> float:
    """The mean training loss so far (one read from the device); refuses a non-finite one, which
    appeared in batches first + 1..last of the epoch. `who` names the model in the message."""
    mean = float(running) / batches
    if not math.isfinite(mean):
        where = f"batch {last}" if last == first + 1 else f"batches {first + 1}-{last}"
        raise NonFiniteLossError(
            f"{who}non-finite training loss ({mean}) at epoch {epoch + 1}, {where}"
        )
    return mean


def _rng_state(device: torch.device) -> RngState:
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


@dataclass(eq=False)
class Member:
    """One model of a fit and how far it has come: the training loop's state, hence mutable."""

    run_dir: Path
    train: TrainConfig  # its horizon_s is this model's
    steps: int  # future steps predicted and scored
    model: AiGem
    net: nn.Module  # the model, or DistributedDataParallel around it
    optimizer: torch.optim.Optimizer
    info: dict[str, Any]  # what its checkpoints carry
    state: runs.RunState
    who: str  # how errors name it: "" when it trains alone
    stopped: str | None  # why it trains no more: epochs, early stopping, time limit
    rng: RngState | None = None  # its dropout stream, between its steps
    running: torch.Tensor | None = None  # its training loss of the epoch, summed on the device
    shown: float = math.nan  # its mean training loss of the epoch, as last read
    group: Path | None = None  # the multi-horizon run it is a member of


@dataclass(eq=False)
class Together:
    """Members trained through an epoch as one ensemble, in ascending order of their steps."""

    members: list[Member]
    ensemble: Ensemble
    optimizer: torch.optim.Optimizer
    running: torch.Tensor  # (M,) the members' training losses of the epoch; member.running views
    rng: RngState  # the members' one dropout stream, between their steps

    @property
    def train(self) -> TrainConfig:  # the members' own, but for the horizon
        return self.members[0].train


def _steps_taken(optimizer: torch.optim.Optimizer) -> float:
    state = optimizer.state_dict()["state"]
    return float(next(iter(state.values()))["step"]) if state else 0.0


def _group(active: list[Member], loop: Loop) -> list[Member | Together]:
    """The active members as they train this epoch: those that share a ModelConfig, a
    TrainConfig but for the horizon, a step count and a dropout stream stacked into one ensemble
    each (at the start of the epoch), the others alone."""
    if loop.world > 1:
        return list(active)
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
    return [_stack(group, loop.device) if len(group) > 1 else group[0] for group in groups.values()]


def _stack(group: list[Member], device: torch.device) -> Together:
    group = sorted(group, key=lambda member: member.steps)
    models = [member.model for member in group]
    stacked = ensemble.stack(models, [member.steps for member in group])
    optimizer = ensemble.stack_optimizer(stacked, [member.optimizer for member in group])
    running = torch.zeros(len(group), dtype=torch.float64, device=device)
    for index, member in enumerate(group):
        member.running = running[index]  # a view: the group's sums are the member's
    return Together(group, stacked, optimizer, running, group[0].rng)


def _unstack(together: Together) -> None:
    """Each member's parameters, optimiser state and dropout stream back into it."""
    ensemble.unstack(together.ensemble, [member.model for member in together.members])
    ensemble.unstack_optimizer(together.optimizer, [m.optimizer for m in together.members])
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
    _set_rng_state(member.rng, device)
    loss = masked_mse_m2(member.net(batch, member.steps), batch, scaler, member.steps)
    member.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    clip_gradients(member.model.parameters(), member.train.clip_grad_norm)
    set_learning_rate(member.optimizer, learning_rate)
    member.optimizer.step()
    member.running += loss.detach()
    member.rng = _rng_state(device)


def _step_together(
    together: Together,
    batch: dict[str, Any],
    scaler: MinMaxScaler,
    device: torch.device,
    learning_rate: float,
) -> None:
    """One optimiser step of an ensemble: its members' loss summed, each member's gradient its
    own loss's; clipped per member; on the members' one dropout stream."""
    _set_rng_state(together.rng, device)
    stacked = together.ensemble
    losses = stacked.member_losses(stacked(batch), batch, scaler)  # (M,)
    together.optimizer.zero_grad(set_to_none=True)
    losses.sum().backward()
    stacked.clip_gradients(together.train.clip_grad_norm)
    set_learning_rate(together.optimizer, learning_rate)
    together.optimizer.step()
    together.running += losses.detach()
    together.rng = _rng_state(device)


def _train_epoch(
    loop: Loop,
    members: list[Member],
    active: list[Member],
    epoch: int,
    report: TrainProgress,
    deadline: float,
) -> tuple[int, bool]:
    """One pass over the train loader, each batch (moved to the device once) training every model
    of `active` (in ensembles where they can, unstacked at the end); returns the graphs seen and
    whether the time limit cut the epoch short. The losses are summed on the device and read
    every READ_LOSS_EVERY_S (and at the end of the epoch): a step never waits for the device."""
    batches, graphs, read_batches, read_at, cut = 0, 0, 0, time.monotonic(), False
    total = len(loop.train_loader)
    trainers = _group(active, loop)
    for index, batch in enumerate(loop.train_loader):
        check_covered(batch, loop.scaler, loop.manifest)  # on the CPU: the step never waits
        batch = to_device(batch, loop.device)
        for trainer in trainers:
            rate = learning_rate_at(trainer.train, epoch, index, total)
            if isinstance(trainer, Together):
                _step_together(trainer, batch, loop.scaler, loop.device, rate)
            else:
                _step(trainer, batch, loop.scaler, loop.device, rate)
        batches, graphs = batches + 1, graphs + batch["graphs"]
        if index + 1 == total or time.monotonic() - read_at >= READ_LOSS_EVERY_S:
            for member in active:
                member.shown = _read_loss(
                    member.running, batches, epoch, read_batches, batches, member.who
                )
            read_at, read_batches = time.monotonic(), batches
            loop.threads.look()
        shown = tuple(m.shown if m in active else math.nan for m in members)
        report(epoch + 1, batches, total, shown)
        cut = time.monotonic() > deadline
        if cut:
            break
    for trainer in trainers:
        if isinstance(trainer, Together):
            _unstack(trainer)
    for member in active:  # the mean of the epoch (a time limit may have cut it)
        member.shown = _read_loss(
            member.running, max(batches, 1), epoch, read_batches, batches, member.who
        )
    return graphs, cut


def _end_epoch(
    member: Member, epoch: int, val_loss: float, timing: dict[str, float], loop: Loop
) -> dict[str, float]:
    """Check the validation loss, log and checkpoint the epoch, stop early when the patience is
    out; returns the metrics row."""
    if not math.isfinite(val_loss):
        raise NonFiniteLossError(
            f"{member.who}non-finite validation loss ({val_loss}) at epoch {epoch + 1}: the model "
            f"diverged, or no validation target has a recorded step within {member.train.horizon_s} s"
        )
    member.state, row = runs.end_epoch(
        member.run_dir,
        member.state,
        member.info,
        epoch,
        member.shown,
        val_loss,
        member.model,
        member.optimizer,
        loop.rank == 0,
        timing,
    )
    if loop.rank == 0:  # after every epoch: a long run shows its course
        if member.group is not None:  # a checkpoint is kept: not a group a fit may start over
            runs.unmark_started(member.group)
        runs.plot_curves(member.run_dir, loop.synthetic)
    patience = member.train.patience_epochs
    if patience is not None and epoch - member.state.best_epoch >= patience:
        member.stopped = "early stopping"
    return row


def _end_epochs(
    active: list[Member],
    epoch: int,
    val_losses: list[float],
    timing: dict[str, float],
    loop: Loop,
    on_epoch: EpochCallback | None,
) -> None:
    """Each model's epoch logged and checkpointed, with Ctrl-C and SIGTERM held off until all are
    (then raised): the models of a fit keep the same epoch, so a resumed fit trains them in the
    same ensembles as an uninterrupted one (an ensemble's sums depend on its members at float
    rounding)."""
    came: list[int] = []
    try:
        with interrupts_held() as came:
            for member, val_loss in zip(active, val_losses, strict=True):
                rate = {"learning_rate": member.optimizer.param_groups[0]["lr"]}  # its last step's
                row = _end_epoch(member, epoch, val_loss, timing | rate, loop)
                if on_epoch is not None and loop.rank == 0:
                    on_epoch(member.train.horizon_s, row)
    finally:  # also after an error: the interrupt is what the user asked for
        for signum in came:
            signal.raise_signal(signum)


def train_epochs(
    loop: Loop,
    members: list[Member],
    train: TrainConfig,
    report: TrainProgress,
    on_epoch: EpochCallback | None,
) -> tuple[float, bool]:
    """The epochs, each training the models due for it (a resumed model may be ahead of the
    others); returns the graphs/s in training and whether the time limit ended it."""
    graphs_seen, train_seconds, timed_out = 0, 0.0, False
    deadline = time.monotonic() + 60 * (
        train.max_minutes if train.max_minutes is not None else math.inf
    )
    first = min((m.state.next_epoch for m in members if m.stopped is None), default=train.epochs)
    for epoch in range(first, train.epochs):
        if all(m.stopped for m in members):
            break
        active = [m for m in members if m.stopped is None and m.state.next_epoch == epoch]
        if not active:
            continue
        # The shuffle depends on the epoch alone, so a resumed run sees the batches it would have;
        # every model's dropout stream starts from the same seed, as when it trains alone.
        loop.generator.manual_seed(train.seed + epoch)
        torch.manual_seed(train.seed + loop.rank + 1000 * epoch)
        for member in active:
            member.rng = _rng_state(loop.device)
            member.running = torch.zeros((), dtype=torch.float64, device=loop.device)
        if loop.sampler is not None:
            loop.sampler.set_epoch(epoch)
        epoch_start = time.monotonic()
        epoch_graphs, timed_out = _train_epoch(loop, members, active, epoch, report, deadline)
        epoch_seconds = time.monotonic() - epoch_start
        train_seconds, graphs_seen = train_seconds + epoch_seconds, graphs_seen + epoch_graphs
        models = [(m.model, m.steps) for m in active]
        val_losses = evaluate_losses(models, loop.val_loader, loop.scaler, loop.device)
        timing = {
            # fewer than the split's if the time ran out (under DDP each rank's share is padded)
            "train_graphs": epoch_graphs * loop.world,
            "train_seconds": round(epoch_seconds, 1),
            "train_graphs_per_s": round(epoch_graphs * loop.world / epoch_seconds, 1),
            "val_seconds": round(time.monotonic() - epoch_start - epoch_seconds, 1),
        }
        _end_epochs(active, epoch, val_losses, timing, loop, on_epoch)
        if timed_out:
            for member in active:
                member.stopped = "time limit"
            break
    return (graphs_seen * loop.world / train_seconds if train_seconds else math.nan), timed_out
