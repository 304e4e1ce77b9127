"""The training loop of `aigem fit`: epochs of optimiser steps, each batch training every model
of a fit (aigem.training.trainers: stacked into ensembles, a model alone an ensemble of one; on the
loader's batches or, with the splits on the device, on static ones, aigem.training.engine), the
validation loss after each epoch, a checkpoint and a log row per epoch (aigem.runs.folder: each model
unstacked from its ensemble to write it), early stopping and the time limit. aigem.training.fit sets
up the models and the data and calls `train_epochs`.

The running training losses stay on the device and are read without waiting for it
(`RunningLosses`), checked finite there and once more at the end of the epoch: within an epoch
no step waits for the device.
"""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Callable

import torch

from aigem.config import TrainConfig
from aigem.runs import folder
from aigem.runs.run_log import EpochRow
from aigem.training.trainers import (
    Loop,
    Member,
    Trainer,
    batches_per_epoch,
    group_trainers,
    rng_state,
    train_steps,
    validation_losses,
)
from ngsim_graphs.interrupts import interrupts_held

READ_LOSS_EVERY_S = 0.5  # the running loss is read from the device (and checked) this often
# A model's curves.png is drawn after an epoch when this long has passed since its last drawing,
# and when the fit ends or stops: epochs of seconds (a GPU's) would otherwise spend a fifth of
# their time drawing.
CURVES_EVERY_S = 30.0
# (epoch, batches done, batches in the epoch, each model's running train loss as last read, NaN
# for a model not training in this epoch or before its first read): the CLI draws a bar from it.
TrainProgress = Callable[[int, int, int, tuple[float, ...]], None]
# (the model's horizon in s, the row of its metrics.jsonl written at the end of an epoch): the CLI
# prints it.
EpochCallback = Callable[[float, EpochRow], None]


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or infinite: training stops rather than save a broken model."""


def _read_loss(running: float, batches: int, epoch: int, who: str = "") -> float:
    """The mean training loss of the epoch's first `batches` batches from their sum; refuses a
    non-finite one. `who` names the model in the message."""
    mean = running / batches
    if not math.isfinite(mean):
        raise NonFiniteLossError(
            f"{who}non-finite training loss ({mean}) at epoch {epoch + 1}, batch {batches} or before"
        )
    return mean


class RunningLosses:
    """The active models' running training losses, read without waiting for the device: a copy
    to pinned host memory is started, and read once it has landed (on the CPU at once)."""

    def __init__(self, active: list[Member], device: torch.device) -> None:
        self.active, self.cuda = active, device.type == "cuda"
        self.host = torch.zeros(len(active), dtype=torch.float64, pin_memory=self.cuda)
        self.event = torch.cuda.Event() if self.cuda else None
        self.pending: int | None = None  # the batches summed in the copy under way

    def poll(self, batches: int) -> list[tuple[float, int]] | None:
        """Each model's (loss sum, batches summed) from the last copy that landed (None: none
        since the last poll); starts the next copy, of the sums after `batches` batches."""
        if not self.cuda:
            return [(float(member.running), batches) for member in self.active]
        landed = None
        if self.pending is not None and self.event.query():
            landed = [(value, self.pending) for value in self.host.tolist()]
            self.pending = None
        if self.pending is None:
            sums = torch.stack([member.running for member in self.active])
            self.host.copy_(sums, non_blocking=True)
            self.event.record()
            self.pending = batches
        return landed


def _train_epoch(
    loop: Loop,
    members: list[Member],
    active: list[Member],
    trainers: list[Trainer],
    epoch: int,
    report: TrainProgress,
    deadline: float,
) -> tuple[int, bool]:
    """One pass over the train split, each batch training every model of `active` (in the
    ensembles of `trainers`); returns the graphs seen and whether the time limit cut the epoch
    short. The losses are summed on the device and read without waiting for it
    (`RunningLosses`) every READ_LOSS_EVERY_S, and at the end of the epoch."""
    batches, graphs, read_at, cut = 0, 0, time.monotonic(), False
    total, losses = batches_per_epoch(loop), RunningLosses(active, loop.device)

    def shown() -> tuple[float, ...]:  # the bar's losses: NaN for a model that stopped
        return tuple(m.shown if m in active else math.nan for m in members)

    for batch_graphs in train_steps(loop, trainers, epoch):
        batches, graphs = batches + 1, graphs + batch_graphs
        if time.monotonic() - read_at >= READ_LOSS_EVERY_S:
            landed = losses.poll(batches)
            if landed is not None:
                for member, (running, upto) in zip(active, landed, strict=True):
                    member.shown = _read_loss(running, upto, epoch, member.who)
            read_at = time.monotonic()
            loop.threads.look()
        if batches < total:  # the epoch's last batch is reported below, with its mean loss
            report(epoch + 1, batches, total, shown())
        cut = time.monotonic() > deadline
        if cut:
            break
    for member in active:  # the mean of the epoch (a time limit may have cut it)
        member.shown = _read_loss(float(member.running), max(batches, 1), epoch, member.who)
    # The bar's last frame of the epoch shows its mean loss (an epoch shorter than two reads
    # would otherwise end showing none).
    report(epoch + 1, batches, total, shown())
    return graphs, cut


def _validate(loop: Loop, active: list[Member], trainers: list[Trainer]) -> list[float]:
    """Each active model's validation loss: one pass over the validation split for all, each
    ensemble on its stacked models (aigem.training.trainers.validation_losses)."""
    losses = {id(member): loss for member, loss in validation_losses(loop, trainers)}
    return [losses[id(member)] for member in active]


def _end_epoch(
    member: Member, epoch: int, val_loss: float, timing: dict[str, float], loop: Loop, now: float
) -> EpochRow:
    """Check the validation loss, log and checkpoint the epoch, draw its curves if they are
    CURVES_EVERY_S old at `now`, stop early when the patience is out; returns the metrics row."""
    if not math.isfinite(val_loss):
        raise NonFiniteLossError(
            f"{member.who}non-finite validation loss ({val_loss}) at epoch {epoch + 1}: the model "
            f"diverged, or no validation target has a recorded step within {member.train.horizon_s} s"
        )
    member.state, row = folder.end_epoch(
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
    if loop.rank == 0:
        if member.group is not None:  # a checkpoint is kept: not a group a fit may start over
            folder.unmark_started(member.group)
        if now - member.drawn_at >= CURVES_EVERY_S:  # a long run shows its course
            draw_curves(member, loop.synthetic, now)
    patience = member.train.patience_epochs
    if patience is not None and epoch - member.state.best_epoch >= patience:
        member.stopped = "early stopping"
    return row


def draw_curves(member: Member, synthetic: bool, now: float) -> None:
    """Draw the model's curves.png from its metrics (runs.folder.plot_curves) at `now`."""
    folder.plot_curves(member.run_dir, synthetic)
    member.drawn_at, member.drawn = now, member.state.next_epoch


def _end_epochs(
    active: list[Member],
    trainers: list[Trainer],
    epoch: int,
    val_losses: list[float],
    timing: dict[str, float],
    loop: Loop,
    on_epoch: EpochCallback | None,
) -> None:
    """Each model unstacked from its trainer and its epoch logged and checkpointed, with Ctrl-C
    and SIGTERM held off until all are (then raised): the models of a fit keep the same epoch,
    so a resumed fit trains them in the same ensembles as an uninterrupted one (an ensemble's
    sums depend on its members at float rounding)."""
    for trainer in trainers:
        trainer.unstack()
    came: list[int] = []
    now = time.monotonic()  # one reading for all: the loop reads the clock alike for any models
    try:
        with interrupts_held() as came:
            for member, val_loss in zip(active, val_losses, strict=True):
                rate = {"learning_rate": member.optimizer.param_groups[0]["lr"]}  # its last step's
                row = _end_epoch(member, epoch, val_loss, timing | rate, loop, now)
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
    trainers: list[Trainer] = []
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
            member.rng = rng_state(loop.device)
            member.running = torch.zeros((), dtype=torch.float64, device=loop.device)
            member.shown = math.nan  # not the last epoch's loss until this one's is read
        if loop.sampler is not None:
            loop.sampler.set_epoch(epoch)
        epoch_start = time.monotonic()
        trainers = group_trainers(active, loop, trainers)
        epoch_graphs, timed_out = _train_epoch(
            loop, members, active, trainers, epoch, report, deadline
        )
        epoch_seconds = time.monotonic() - epoch_start
        train_seconds, graphs_seen = train_seconds + epoch_seconds, graphs_seen + epoch_graphs
        val_losses = _validate(loop, active, trainers)
        timing = {
            # fewer than the split's if the time ran out (under DDP each rank's share is padded)
            "train_graphs": epoch_graphs * loop.world,
            "train_seconds": round(epoch_seconds, 1),
            "train_graphs_per_s": round(epoch_graphs * loop.world / epoch_seconds, 1),
            "val_seconds": round(time.monotonic() - epoch_start - epoch_seconds, 1),
        }
        _end_epochs(active, trainers, epoch, val_losses, timing, loop, on_epoch)
        if timed_out:
            for member in active:
                member.stopped = "time limit"
            break
    return (graphs_seen * loop.world / train_seconds if train_seconds else math.nan), timed_out
