"""`aigem fit`: train AiGem on a build's train split, keep the best checkpoint by validation loss.

Here a fit is set up: the device, the loaders, each model with its optimizer and its run
directory (new or resumed), constant velocity's validation loss; aigem.training.epochs runs the epochs
(the loss, the steps, a checkpoint per epoch). Checkpoints are written atomically after every
epoch; `resume` restarts from the last one. Under `torchrun` (WORLD_SIZE > 1) it trains with
DistributedDataParallel (aigem.training.trainers: each model an ensemble of one, through its wrapper).

`fit_horizons` trains one model per horizon, as the paper does, in one loop over one loader: each
batch, moved to the device once, trains every model, the models as one ensemble stacked through
the fit (aigem.training.trainers, aigem.training.ensemble), each with its own optimizer, checkpoints, log and early
stopping. On the CPU each model is the one `fit` would train for its horizon with the same seed
and settings (the same initialisation, batches and dropout masks), to float rounding, which the
ensemble's other order of summation changes: the members draw one dropout mask from the global
generator, as a model alone draws its own (aigem.model.network). With `--compile` (on CUDA, the loader's
batches) an ensemble decodes through its first model's compiled decoder.
"""

from __future__ import annotations

import os
import random
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from aigem.config import ModelConfig, TrainConfig
from aigem.cores import ThreadChooser, default_workers
from aigem.devices import pick_device
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem, count_parameters
from aigem.processes import EndWithParent, compile_in_process, release_workers
from aigem.runs import folder
from aigem.runs.baseline import record_baselines
from aigem.runs.checkpoints import check_logs
from aigem.runs.records import Group, RunState, planned_group
from aigem.runs.refusals import check_splits, model_of_build
from aigem.training import capacity, engine
from aigem.training.engine import DeviceData
from aigem.training.epochs import EpochCallback, TrainProgress, draw_curves, train_epochs
from aigem.training.loading import load_split
from aigem.training.resident import fits
from aigem.training.trainers import Loop, Member
from ngsim_graphs.build import open_build
from ngsim_graphs.layout import manifest_path
from ngsim_graphs.schema import Split
from ngsim_graphs.synth.marker import synthetic_build


@dataclass(frozen=True)
class FitResult:
    run_dir: Path
    horizon_s: float
    parameters: int
    epochs_done: int
    best_epoch: int
    best_val_loss_m2: float
    stopped_because: str
    train_graphs_per_s: float
    device: str


def make_optimizer(model: nn.Module, train: TrainConfig, device: torch.device) -> torch.optim.Adam:
    """The paper's Adam; fused (one operator for all parameters instead of ~9 per parameter
    tensor, 576 for AiGem) where PyTorch has the fused kernel: the CPU and CUDA."""
    fused = device.type in ("cpu", "cuda")
    return torch.optim.Adam(model.parameters(), lr=train.learning_rate, fused=fused or None)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


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
        "worker_init_fn": EndWithParent(),  # a killed fit's workers end with it
    }
    train_loader = DataLoader(
        train_set, shuffle=sampler is None, sampler=sampler, generator=generator, **common
    )
    val_loader = DataLoader(val_set, shuffle=False, **common)
    return train_set, train_loader, val_loader, sampler, generator


# (what is loaded, samples done, samples in all): the splits induced onto the device
LoadProgress = Callable[[str, int, int], None]


def device_data(
    build_dir: Path,
    model: ModelConfig,
    train: TrainConfig,
    device: torch.device,
    workers: int,
    loading: LoadProgress | None = None,
    note: Callable[[str], None] | None = None,
) -> DeviceData | None:
    """The train and validation splits loaded onto `device` (aigem.training.resident), with their batches'
    capacities; None, said in `note`, where they would take more than half of a GPU's free
    memory (aigem.training.resident.fits): then the loader serves."""
    splits = []
    for split, name in ((Split.TRAIN, "train"), (Split.VAL, "validation")):
        dataset = GraphDataset(build_dir, split, history_steps=model.history_steps_read)
        report = None if loading is None else partial(loading, f"the {name} split")
        loaded = load_split(dataset, model.layers, workers, split is Split.TRAIN, report)
        splits.append((dataset, loaded))
    size = sum(loaded.nbytes() for _, loaded in splits)
    room, free = fits(size, device)
    say = note or (lambda line: None)
    if not room:
        say(
            f"the splits take {size / 1e9:.1f} GB, more than half of {device}'s free "
            f"{free / 1e9:.1f} GB: the DataLoader's batches serve"
        )
        return None
    (train_set, train_split), (val_set, val_split) = [(d, s.to(device)) for d, s in splits]
    batch = train.batch_size
    train_base = capacity.base_capacity(train_split.counts, batch, model.layers)
    val_base = capacity.base_capacity(val_split.counts, batch, model.layers)
    in_order = np.arange(len(val_set))
    val_batches = engine.epoch_batches(
        val_split, in_order, batch, val_base, val_set.batch_order, device
    )
    steps = "captured once and replayed" if device.type == "cuda" else "run eagerly"
    say(f"the splits on {device} ({size / 1e9:.2f} GB): static batches of {batch} graphs, {steps}")
    return DeviceData(train_split, val_split, batch, train_base, val_batches, train_set.batch_order)


def _start_members(
    build_dir: Path,
    group: Group,
    model_config: ModelConfig,
    train: TrainConfig,
    resume: bool,
    time_step_s: float,
    loop: Loop,
) -> list[Member]:
    """The models of a fit, new or resumed: one per horizon of `group`, in its member directory,
    where a resume starts over a member that has no checkpoint yet. A horizon of less than one of
    the build's time steps is refused before any directory is made."""
    for horizon_s in group.horizons_s:
        replace(train, horizon_s=horizon_s).horizon_steps(time_step_s)
    if resume:
        check_logs(group)  # every model's, before any is resumed
    folder.start_group(group, resume, loop.rank == 0)
    plans = [
        (d, replace(train, horizon_s=h), resume and (d / folder.LAST).is_file(), group.who(d))
        for d, h in zip(group.members, group.horizons_s, strict=True)
    ]
    members = []
    for member_dir, member_train, member_resume, who in plans:
        seed_everything(train.seed + loop.rank)  # initialised as a fit of this model alone would
        model = AiGem(model_config).to(loop.device)
        if train.compiles_on(loop.device.type) and loop.data is None:  # a captured step needs none
            compile_in_process()  # no pool of compile workers for the exit to wait for
            model.compile_decoder()
        optimizer = make_optimizer(model, member_train, loop.device)
        state, info = folder.start_run(
            member_dir,
            build_dir,
            model_config,
            member_train,
            member_resume,
            model,
            optimizer,
            loop.rank == 0,
        )
        steps = member_train.horizon_steps(time_step_s)
        members.append(
            Member(
                member_dir,
                member_train,
                steps,
                model,
                optimizer,
                info,
                state,
                who,
                _done_before(state, member_train),
                group=group.run_dir,
            )
        )
    return members


def _done_before(state: RunState, train: TrainConfig) -> str | None:
    """Why a resumed model has nothing left to train (None: it trains on)."""
    if state.next_epoch >= train.epochs:
        return "epochs"
    patience = train.patience_epochs
    waited = state.next_epoch - 1 - state.best_epoch  # epochs since the best one
    if state.next_epoch > 0 and patience is not None and waited >= patience:
        return "early stopping"
    return None


def fit(
    build_dir: str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    model_config: ModelConfig,
    train: TrainConfig,
    device_choice: str = "auto",
    resume: bool = False,
    progress: TrainProgress | None = None,
    on_epoch: EpochCallback | None = None,
) -> FitResult:
    """Train one model for `train.horizon_s` and write the run directory (see aigem.runs.folder)."""
    (result,) = fit_horizons(
        build_dir,
        run_dir,
        (train.horizon_s,),
        model_config,
        train,
        device_choice,
        resume,
        progress,
        on_epoch,
    )
    return result


def fit_horizons(
    build_dir: str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    horizons_s: tuple[float, ...],
    model_config: ModelConfig,
    train: TrainConfig,
    device_choice: str = "auto",
    resume: bool = False,
    progress: TrainProgress | None = None,
    on_epoch: EpochCallback | None = None,
    loading: LoadProgress | None = None,
    note: Callable[[str], None] | None = None,
) -> tuple[FitResult, ...]:
    """Train one model per horizon (ascending; each replaces `train.horizon_s`) in one loop, and
    write the run directory (see aigem.runs.folder; one model: in `run_dir` itself, as `fit` writes it);
    returns each model's result. `loading` reports the splits'
    loading onto the device, `note` says in a line where the batches come from."""
    build_dir, run_dir = Path(build_dir), Path(run_dir)
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
    model_config = model_of_build(model_config, build_dir)
    train_set, train_loader, val_loader, sampler, generator = _loaders(
        build_dir, model_config, train, rank, world, device, workers
    )
    synthetic = synthetic_build(open_build(build_dir).manifest)
    data = None
    if world == 1 and train.resident_on(device.type):
        data = device_data(build_dir, model_config, train, device, workers, loading, note)
    loop = Loop(
        device,
        rank,
        world,
        train_set.scaler,
        train_loader,
        val_loader,
        sampler,
        generator,
        threads,
        synthetic,
        manifest_path(build_dir),
        data,
    )
    members = _start_members(
        build_dir,
        planned_group(run_dir, horizons_s),
        model_config,
        train,
        resume,
        train_set.config.time_step_s,
        loop,
    )
    if rank == 0:  # constant velocity's validation loss at each horizon, once per run
        record_baselines(build_dir, [(m.run_dir, m.steps) for m in members])
    try:
        graphs_per_s, timed_out = train_epochs(
            loop, members, train, progress or (lambda *_: None), on_epoch
        )
    finally:  # after an error or an interrupt too, when a traceback would keep the loaders
        release_workers(train_loader, val_loader)
        for member in members:  # the curves of every epoch kept, also of a stopped fit
            if rank == 0 and member.drawn < member.state.next_epoch:
                draw_curves(member, synthetic, member.drawn_at)
    for member in members:
        member.stopped = member.stopped or ("time limit" if timed_out else "epochs")
    return tuple(
        FitResult(
            m.run_dir,
            m.train.horizon_s,
            count_parameters(m.model),
            m.state.next_epoch,
            m.state.best_epoch + 1,
            m.state.best_val_loss,
            m.stopped,
            graphs_per_s,
            str(device),
        )
        for m in members
    )
