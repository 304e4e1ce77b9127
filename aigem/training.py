"""`aigem fit`: train AiGem on a build's train split, keep the best checkpoint by validation loss.

The loss is the mean squared error in metres^2 over the valid (unmasked) future steps up to the
horizon: predictions are made in scaled coordinates and mapped back to metres before the loss,
so x and y weigh alike. Checkpoints are written atomically after every epoch; `resume` restarts
from the last one. Under `torchrun` (WORLD_SIZE > 1) it trains with DistributedDataParallel.
"""

from __future__ import annotations

import math
import os
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from aigem import runs
from aigem.config import ModelConfig, TrainConfig
from aigem.cores import ThreadChooser, default_workers
from aigem.data import Collate, GraphDataset, Scaler
from aigem.model import AiGem, count_parameters
from ngsim_graphs.builds import open_build
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sampling import N_TARGETS
from ngsim_graphs.schema import Split

READ_LOSS_EVERY_S = 0.5  # the running loss is read from the device (and checked) this often
# (epoch, batches done, batches in the epoch, running train loss as last read): the CLI draws a
# bar from it.
ProgressCallback = Callable[[int, int, int, float], None]
# The row of metrics.jsonl written at the end of each epoch: the CLI prints it.
EpochCallback = Callable[[dict[str, float]], None]


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or infinite: training stops rather than save a broken model."""


@dataclass(frozen=True)
class FitResult:
    run_dir: Path
    parameters: int
    epochs_done: int
    best_epoch: int
    best_val_loss_m2: float
    stopped_because: str
    train_graphs_per_s: float
    device: str


class DeviceUnavailableError(ValueError):
    """The device asked for is not on this machine."""


def pick_device(choice: str) -> torch.device:
    """'auto' takes CUDA when present; 'cuda' without a GPU is an error."""
    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if choice == "cuda" and not torch.cuda.is_available():
        raise DeviceUnavailableError("--device cuda: no CUDA device is available")
    return torch.device(choice)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def masked_mse_m2(
    model_out: torch.Tensor, batch: dict[str, torch.Tensor], scaler: Scaler, steps: int
) -> torch.Tensor:
    """Mean squared error in metres^2 over valid steps; (A, steps, 2) scaled predictions."""
    predicted = scaler.xy_to_metres(model_out)
    truth = batch["target_xy"][:, :steps]
    mask = batch["target_mask"][:, :steps].to(predicted.dtype)
    squared = ((predicted - truth) ** 2).sum(dim=-1) * mask
    return squared.sum() / mask.sum().clamp(min=1.0)


def check_splits(build_dir: Path) -> None:
    """Refuse a build whose train or validation split has no samples, or no target actors: one
    gives nothing to train on (nor a scaler), the other no validation loss, which picks the best
    checkpoint and stops early; training on would only log a validation MSE of NaN."""
    build = open_build(build_dir)
    why = {
        Split.TRAIN: ("train", "there is nothing to train on (and the scaler is fitted on it)"),
        Split.VAL: ("validation", "`aigem fit` keeps the best checkpoint and stops early by validation loss"),
    }  # fmt: skip
    for split, (name, reason) in why.items():
        samples = int(build.manifest.get("splits", {}).get(split.value, 0))
        if samples == 0:
            raise NgsimInputError(build_dir, f"the {name} split ({split.value}) is empty: {reason}; "
                                  "rebuild with other split fractions or more data")  # fmt: skip
        if int(build.samples(split)[N_TARGETS].sum()) == 0:
            raise NgsimInputError(build_dir, f"the {name} split ({split.value}) has {samples} samples "
                                  f"but no target actors: {reason}")  # fmt: skip


def to_device(batch: dict[str, Any], device: torch.device) -> dict[str, Any]:
    """The batch's tensors and plan on `device` (copies from pinned memory do not wait)."""
    return {k: v.to(device, non_blocking=True) if hasattr(v, "to") else v for k, v in batch.items()}


def _distributed() -> tuple[int, int]:
    """(rank, world size), starting the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not torch.distributed.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        torch.distributed.init_process_group(backend)
    rank = torch.distributed.get_rank() if world > 1 else 0
    return rank, world


def _loaders(
    build_dir: Path,
    model: ModelConfig,
    train: TrainConfig,
    rank: int,
    world: int,
    device: torch.device,
    workers: int,
):
    # Graphs cut to the steps the model reads: the same loss, a fraction of the loading work;
    # the encoder's plan is made with each batch, in the workers.
    train_set, val_set = (
        GraphDataset(build_dir, split, history_steps=model.history_steps_read)
        for split in (Split.TRAIN, Split.VAL)
    )
    collate = Collate(train_set.scaler, layers=model.layers)
    sampler = (
        DistributedSampler(train_set, world, rank, shuffle=True, seed=train.seed)
        if world > 1
        else None
    )
    generator = torch.Generator().manual_seed(train.seed)
    common = {
        "batch_size": train.batch_size,
        "collate_fn": collate,
        "num_workers": workers,
        "pin_memory": device.type == "cuda",
        "persistent_workers": workers > 0,
        "prefetch_factor": 4 if workers > 0 else None,
    }
    train_loader = DataLoader(
        train_set, shuffle=sampler is None, sampler=sampler, generator=generator, **common
    )
    val_loader = DataLoader(val_set, shuffle=False, **common)
    return train_set, train_loader, val_loader, sampler, generator


def evaluate_loss(
    model: nn.Module, loader: DataLoader, scaler: Scaler, steps: int, device: torch.device
) -> float:
    """Mean validation loss in metres^2, weighted by valid steps."""
    model.eval()
    total = torch.zeros((), dtype=torch.float64, device=device)  # summed on the device, read once
    count = torch.zeros((), dtype=torch.float64, device=device)
    with torch.no_grad():
        for batch in loader:
            batch = to_device(batch, device)
            valid = batch["target_mask"][:, :steps].sum()
            total += masked_mse_m2(model(batch, steps), batch, scaler, steps).double() * valid
            count += valid
    model.train()
    count_value = float(count)
    return float(total) / count_value if count_value else float("nan")


def _read_loss(running: torch.Tensor, batches: int, epoch: int, first: int, last: int) -> float:
    """The mean training loss so far (one read from the device); refuses a non-finite one, which
    appeared in batches first + 1..last of the epoch."""
    mean = float(running) / batches
    if not math.isfinite(mean):
        where = f"batch {last}" if last == first + 1 else f"batches {first + 1}-{last}"
        raise NonFiniteLossError(f"non-finite training loss ({mean}) at epoch {epoch + 1}, {where}")
    return mean


def fit(
    build_dir: Path,
    run_dir: Path,
    model_config: ModelConfig,
    train: TrainConfig,
    device_choice: str = "auto",
    resume: bool = False,
    progress: ProgressCallback | None = None,
    on_epoch: EpochCallback | None = None,
) -> FitResult:
    """Train and write the run directory (see aigem.runs); returns what happened."""
    rank, world = _distributed()
    device = pick_device(device_choice)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", rank % torch.cuda.device_count())
    threads = ThreadChooser(train.threads)
    workers = (
        train.workers if train.workers is not None else default_workers(device.type, threads.cores)
    )
    seed_everything(train.seed + rank)
    check_splits(build_dir)
    train_set, train_loader, val_loader, sampler, generator = _loaders(
        build_dir, model_config, train, rank, world, device, workers
    )
    steps = train.horizon_steps(train_set.config.time_step_s)
    model = AiGem(model_config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=train.learning_rate)
    state, info = runs.start_run(
        run_dir, build_dir, model_config, train, resume, model, optimizer, rank == 0
    )
    net = nn.parallel.DistributedDataParallel(model) if world > 1 else model
    report = progress or (lambda *_: None)
    started, graphs_seen, train_seconds = time.monotonic(), 0, 0.0
    stopped = "epochs"
    epoch = state.next_epoch
    for epoch in range(state.next_epoch, train.epochs):
        # The shuffle depends on the epoch alone, so a resumed run sees the batches it would have.
        generator.manual_seed(train.seed + epoch)
        torch.manual_seed(train.seed + rank + 1000 * epoch)  # dropout
        if sampler is not None:
            sampler.set_epoch(epoch)
        epoch_start, batches, epoch_graphs = time.monotonic(), 0, 0
        # The losses are summed on the device and read every READ_LOSS_EVERY_S (and at the end
        # of the epoch): a step never waits for the device.
        running = torch.zeros((), dtype=torch.float64, device=device)
        shown, read_at, read_batches = math.nan, time.monotonic(), 0
        for index, batch in enumerate(train_loader):
            batch = to_device(batch, device)
            loss = masked_mse_m2(net(batch, steps), batch, train_set.scaler, steps)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            running += loss.detach()
            batches, epoch_graphs = batches + 1, epoch_graphs + batch["graphs"]
            last = index + 1 == len(train_loader)
            if last or time.monotonic() - read_at >= READ_LOSS_EVERY_S:
                shown = _read_loss(running, batches, epoch, read_batches, batches)
                read_at, read_batches = time.monotonic(), batches
                threads.look()
            report(epoch + 1, index + 1, len(train_loader), shown)
            if (
                train.max_minutes is not None
                and time.monotonic() - started > 60 * train.max_minutes
            ):
                stopped = "time limit"
                break
        mean_loss = _read_loss(running, max(batches, 1), epoch, read_batches, batches)
        epoch_seconds = time.monotonic() - epoch_start
        train_seconds, graphs_seen = train_seconds + epoch_seconds, graphs_seen + epoch_graphs
        val_loss = evaluate_loss(model, val_loader, train_set.scaler, steps, device)
        if not math.isfinite(val_loss):
            raise NonFiniteLossError(
                f"non-finite validation loss ({val_loss}) at epoch {epoch + 1}: the model diverged, "
                f"or no validation target has a recorded step within {train.horizon_s} s"
            )
        timing = {
            "train_seconds": round(epoch_seconds, 1),
            "train_graphs_per_s": round(epoch_graphs * world / epoch_seconds, 1),
            "val_seconds": round(time.monotonic() - epoch_start - epoch_seconds, 1),
        }
        state, row = runs.end_epoch(
            run_dir,
            state,
            info,
            epoch,
            mean_loss,
            val_loss,
            model,
            optimizer,
            rank == 0,
            timing,
        )
        if on_epoch is not None and rank == 0:
            on_epoch(row)
        if stopped != "epochs":
            break
        if train.patience_epochs is not None and epoch - state.best_epoch >= train.patience_epochs:
            stopped = "early stopping"
            break
    if rank == 0:
        runs.plot_curves(run_dir)
    return FitResult(
        run_dir=run_dir,
        parameters=count_parameters(model),
        epochs_done=state.next_epoch,
        best_epoch=state.best_epoch + 1,
        best_val_loss_m2=state.best_val_loss,
        stopped_because=stopped,
        train_graphs_per_s=graphs_seen * world / train_seconds if train_seconds else math.nan,
        device=str(device),
    )
