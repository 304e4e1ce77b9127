"""Steps over static batches (docs/aigem.md): captured once per capacity, then replayed.

A fit whose splits are on the device (aigem.resident) trains on static batches: every batch of
one capacity tier (aigem.capacity) has the same shapes, so its whole training step (the batch
assembled by index, the forward of all members, the loss, the backward, the clipping, Adam's
step and the running loss) is one function of the batch's sample ids. On CUDA `Replays`
captures it as a CUDA graph after WARMUP eager calls (PyTorch's documented whole-network
capture: the warm-up on a side stream, the gradients set to None before the capture so that the
graph owns them, Adam `capturable` with its learning rate a device tensor) and replays it for
every later batch of the tier; elsewhere it calls it eagerly, which is the same computation.
Validation likewise, forward only, its sums kept on the device. Nothing in a step reads a number
back, so the host runs ahead of the device through the epoch, and only the epoch's end waits.
"""

from __future__ import annotations

import gc
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from aigem import capacity as capacities
from aigem.capacity import Capacity
from aigem.data import xy_to_metres
from aigem.ensemble import Ensemble
from aigem.resident import ResidentSplit
from aigem.schedule import set_learning_rate
from ngsim_graphs.scaling import MinMaxScaler

WARMUP = 2  # eager calls of a tier before its capture (the documentation's warm-up)
StepFunction = Callable[[torch.Tensor, Capacity], None]  # (sample ids, capacity) -> None


class Replays:
    """Functions of a batch's sample ids, one call per capacity tier: on CUDA each captured as a
    CUDA graph after WARMUP eager calls, then replayed; elsewhere called eagerly.

    It holds no reference to its functions (the caller passes one each call), so that an owner
    dropped with its graphs is freed at once rather than by the garbage collector, which must
    not destroy a graph while another is being captured (the collector is held off during a
    capture). Its graphs share one memory pool and one side stream, with those of `shared`
    (another Replays) where given. PyTorch documents a shared pool as safe for graphs replayed
    in the order they were captured, and these replay in the data's order of tiers; it holds
    because no graph reads what another wrote in the pool: every state that lasts (the
    parameters, Adam's, the losses, the outputs, the sample ids) lives outside it, and they
    never run at once. The gradients alone live in the pool: outside a step they mean nothing."""

    def __init__(self, device: torch.device, shared: Replays | None = None) -> None:
        self.device = device
        self.ids: dict[int, torch.Tensor] = {}  # per tier: the captured input
        self.graphs: dict[int, torch.cuda.CUDAGraph] = {}
        self.calls: Counter[int] = Counter()
        cuda = device.type == "cuda"
        if shared is not None:  # a pool shared takes its capture's stream (torch.cuda.graph)
            self.pool, self.stream = shared.pool, shared.stream
        else:
            self.pool = torch.cuda.graph_pool_handle() if cuda else None
            self.stream = torch.cuda.Stream(device) if cuda else None

    def __call__(
        self, function: StepFunction, ids: torch.Tensor, tier: int, capacity: Capacity
    ) -> None:
        if self.device.type != "cuda":
            function(ids, capacity)
            return
        if tier not in self.ids:
            self.ids[tier] = torch.empty_like(ids)
        self.ids[tier].copy_(ids)
        if tier in self.graphs:
            self.graphs[tier].replay()
        elif self.calls[tier] < WARMUP:
            self.calls[tier] += 1
            self.stream.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(self.stream), warnings.catch_warnings():
                # capturable Adam, stepped eagerly before its capture, warns that it is
                warnings.filterwarnings("ignore", message=".*capturable=True.*")
                function(self.ids[tier], capacity)
            torch.cuda.current_stream(self.device).wait_stream(self.stream)
        else:
            self.graphs[tier] = self._capture(function, self.ids[tier], capacity)
            self.graphs[tier].replay()

    def _capture(
        self, function: StepFunction, ids: torch.Tensor, capacity: Capacity
    ) -> torch.cuda.CUDAGraph:
        graph, collecting = torch.cuda.CUDAGraph(), gc.isenabled()
        gc.collect()  # whatever graph is garbage goes now, not in the middle of the capture
        gc.disable()
        try:
            with torch.cuda.graph(graph, pool=self.pool, stream=self.stream):
                function(ids, capacity)
        finally:
            if collecting:
                gc.enable()
        return graph


@dataclass(frozen=True)
class Batches:
    """An epoch's static batches: each batch's sample ids, padded, and its capacity tier."""

    ids: torch.Tensor  # (n, B) on the device
    tiers: list[int]
    graphs: list[int]  # the samples of each batch (B but for the last)

    def __len__(self) -> int:
        return len(self.tiers)


def epoch_batches(
    split: ResidentSplit,
    order: np.ndarray,
    batch_size: int,
    base: Capacity,
    batch_order: Callable[[np.ndarray], np.ndarray],
    device: torch.device,
) -> Batches:
    """The batches of `batch_size` consecutive samples of `order` (the epoch's sample ids), each
    in `batch_order` (the loader's: by recording), padded with the split's empty sample; one
    copy to the device for the whole epoch."""
    parts = [batch_order(order[i : i + batch_size]) for i in range(0, len(order), batch_size)]
    ids = np.full((len(parts), batch_size), split.empty_id, dtype=np.int64)
    for row, part in zip(ids, parts, strict=True):
        row[: len(part)] = part
    tiers = [capacities.tier_of(base, split.counts[part].sum(0)) for part in parts]
    return Batches(torch.from_numpy(ids).to(device), tiers, [len(part) for part in parts])


class TrainSteps:
    """An ensemble's training steps over static batches of `split`: `running` (M,) float64
    sums each member's loss of the epoch on the device."""

    def __init__(
        self,
        ensemble: Ensemble,
        optimizer: torch.optim.Optimizer,
        split: ResidentSplit,
        scaler: MinMaxScaler,
        clip_grad_norm: float | None,
        running: torch.Tensor,
        device: torch.device,
    ) -> None:
        self.ensemble, self.optimizer, self.split = ensemble, optimizer, split
        self.scaler, self.clip_grad_norm, self.running = scaler, clip_grad_norm, running
        self.replays = Replays(device)
        self.rate: float | None = None  # the learning rate of the last step, as a number

    def _step(self, ids: torch.Tensor, capacity: Capacity) -> None:
        batch = self.split.batch(ids, capacity)
        self.optimizer.zero_grad(set_to_none=True)  # a capture's gradients are the graph's own
        losses = self.ensemble.member_losses(self.ensemble(batch), batch, self.scaler)
        losses.sum().backward()
        self.ensemble.clip_gradients(self.clip_grad_norm)
        self.optimizer.step()
        self.running += losses.detach()

    def __call__(self, ids: torch.Tensor, tier: int, base: Capacity, learning_rate: float) -> None:
        set_learning_rate(self.optimizer, learning_rate)
        self.rate = learning_rate
        self.replays(self._step, ids, tier, capacities.tier(base, tier))


class ValidationSums:
    """Each member's squared error (metres^2) over its valid target steps, and their count,
    summed on the device over static batches of `split` (forward only)."""

    def __init__(
        self,
        ensemble: Ensemble,
        split: ResidentSplit,
        scaler: MinMaxScaler,
        device: torch.device,
        shared: Replays | None = None,
    ) -> None:
        self.ensemble, self.split, self.scaler = ensemble, split, scaler
        self.sums = torch.zeros(2, ensemble.members, dtype=torch.float64, device=device)
        self.replays = Replays(device, shared)  # the training steps' pool and stream

    def _add(self, ids: torch.Tensor, capacity: Capacity) -> None:
        with torch.no_grad():
            batch = self.split.batch(ids, capacity)
            sums = self.ensemble.member_sums(self.ensemble(batch), batch, self.scaler)
            self.sums += torch.stack(sums).double()

    def losses(self, batches: Batches, base: Capacity) -> list[float]:
        """Each member's mean validation loss in metres^2 over `batches` (read once, at the end;
        NaN where no target step counts)."""
        self.ensemble.eval()
        self.sums.zero_()
        for row, tier in enumerate(batches.tiers):
            self.replays(self._add, batches.ids[row], tier, capacities.tier(base, tier))
        self.ensemble.train()
        totals, counts = self.sums.tolist()
        return [t / c if c else float("nan") for t, c in zip(totals, counts, strict=True)]


def shuffled(samples: int, generator: torch.Generator) -> np.ndarray:
    """The epoch's order of the samples: the permutation a DataLoader's shuffle draws from
    `generator` (its iterator first draws a base seed for its workers, then the sampler's
    `torch.randperm`), so that static batches hold the samples the loader's would."""
    torch.empty((), dtype=torch.int64).random_(generator=generator)
    return torch.randperm(samples, generator=generator).numpy()


@dataclass(frozen=True)
class DeviceData:
    """A fit's train and validation splits on the device, and the capacities of their batches."""

    train: ResidentSplit
    val: ResidentSplit
    batch_size: int
    train_base: Capacity
    val_base: Capacity
    val_batches: Batches  # the validation split's, in order, made once
    batch_order: Callable[[np.ndarray], np.ndarray]  # the train split's (by recording)


class Predictions:
    """An ensemble's predictions in metres ((M, capacity.targets, K, 2), padding after each
    batch's targets) of static batches of `split`, forward only; on CUDA each tier's forward is
    captured and replayed into a buffer of its own."""

    def __init__(
        self, ensemble: Ensemble, split: ResidentSplit, scaler: MinMaxScaler, device: torch.device
    ) -> None:
        self.ensemble, self.split, self.scaler, self.device = ensemble, split, scaler, device
        self.out: dict[Capacity, torch.Tensor] = {}
        self.replays = Replays(device)

    def _forward(self, ids: torch.Tensor, capacity: Capacity) -> None:
        with torch.no_grad():
            batch = self.split.batch(ids, capacity)
            self.out[capacity].copy_(xy_to_metres(self.scaler, self.ensemble(batch)))

    def __call__(self, ids: torch.Tensor, tier: int, base: Capacity) -> torch.Tensor:
        capacity = capacities.tier(base, tier)
        if capacity not in self.out:  # before any capture
            shape = (self.ensemble.members, capacity.targets, max(self.ensemble.steps), 2)
            self.out[capacity] = torch.empty(shape, device=self.device)
        self.replays(self._forward, ids, tier, capacity)
        return self.out[capacity]
