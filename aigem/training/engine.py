"""Static batches (docs/aigem.md): an epoch's batches of a split on the device, and the functions
of a batch run over them, on CUDA captured once per capacity and replayed.

A fit whose splits are on the device (aigem.training.resident) trains on static batches: every batch of
one capacity tier (aigem.training.capacity) has the same shapes, so a function of a batch (the training
step of aigem.training.trainers, validation's sums, scoring's forward) run on a static batch, the batch's
assembly by index included, is one function of the batch's sample ids. On CUDA `Replays`
captures it as a CUDA graph after WARMUP eager calls (PyTorch's documented whole-network
capture: the warm-up on a side stream, the gradients set to None before the capture so that the
graph owns them, Adam `capturable` with its learning rate a device tensor) and replays it for
every later batch of the tier; elsewhere it calls it eagerly, which is the same computation. A
loader's batch (`aigem.model.batch.Batch`) it hands to the function as it is: the same function runs
on both kinds of batch. Nothing in such a function reads a number back, so the host runs ahead
of the device through the epoch, and only the epoch's end waits.
"""

from __future__ import annotations

import gc
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import torch

from aigem.model.batch import Batch
from aigem.training import capacity as capacities
from aigem.training.capacity import Capacity
from aigem.training.resident import ResidentSplit

WARMUP = 2  # eager calls of a tier before its capture (the documentation's warm-up)
BatchFunction = Callable[[Batch], object]  # what runs on a batch; its result is not kept


@dataclass(frozen=True)
class StaticBatch:
    """A static batch before its assembly: the samples `ids` of `split` ((capacity.samples,) on
    the device, padded with the split's empty sample), its capacity tier and capacity, and its
    real samples (`graphs`)."""

    split: ResidentSplit
    ids: torch.Tensor
    tier: int
    capacity: Capacity
    graphs: int

    def assembled(self, ids: torch.Tensor | None = None) -> Batch:
        """The batch, assembled on the device (of `ids`, a captured step's input, if given)."""
        return self.split.batch(self.ids if ids is None else ids, self.capacity)


class Replays:
    """Runs functions of a batch: a loader's batch handed over as it is; a static batch
    assembled and, per capacity tier, on CUDA captured as a CUDA graph after WARMUP eager calls,
    then replayed; elsewhere called eagerly.

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

    def __call__(self, function: BatchFunction, batch: Batch | StaticBatch) -> None:
        if isinstance(batch, Batch):
            function(batch)
            return
        if self.device.type != "cuda":
            function(batch.assembled())
            return
        tier = batch.tier
        if tier not in self.ids:
            self.ids[tier] = torch.empty_like(batch.ids)
        self.ids[tier].copy_(batch.ids)
        if tier in self.graphs:
            self.graphs[tier].replay()
        elif self.calls[tier] < WARMUP:
            self.calls[tier] += 1
            self.stream.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(self.stream), warnings.catch_warnings():
                # capturable Adam, stepped eagerly before its capture, warns that it is
                warnings.filterwarnings("ignore", message=".*capturable=True.*")
                function(batch.assembled(self.ids[tier]))
            torch.cuda.current_stream(self.device).wait_stream(self.stream)
        else:
            self.graphs[tier] = self._capture(function, batch, self.ids[tier])
            self.graphs[tier].replay()

    def _capture(
        self, function: BatchFunction, batch: StaticBatch, ids: torch.Tensor
    ) -> torch.cuda.CUDAGraph:
        graph, collecting = torch.cuda.CUDAGraph(), gc.isenabled()
        gc.collect()  # whatever graph is garbage goes now, not in the middle of the capture
        gc.disable()
        try:
            with torch.cuda.graph(graph, pool=self.pool, stream=self.stream):
                function(batch.assembled(ids))
        finally:
            if collecting:
                gc.enable()
        return graph


@dataclass(frozen=True)
class Batches:
    """An epoch's static batches of `split`: each batch's sample ids, padded, its capacity tier
    (of `base`) and its real samples; item i is static batch i."""

    split: ResidentSplit
    base: Capacity
    ids: torch.Tensor  # (n, B) on the device
    tiers: list[int]
    graphs: list[int]  # the samples of each batch (B but for the last)

    def __len__(self) -> int:
        return len(self.tiers)

    def __getitem__(self, index: int) -> StaticBatch:
        tier = self.tiers[index]
        capacity = capacities.tier(self.base, tier)
        return StaticBatch(self.split, self.ids[index], tier, capacity, self.graphs[index])

    def __iter__(self) -> Iterator[StaticBatch]:
        return (self[index] for index in range(len(self)))


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
    graphs = [len(part) for part in parts]
    return Batches(split, base, torch.from_numpy(ids).to(device), tiers, graphs)


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
    val_batches: Batches  # the validation split's, in order, made once
    batch_order: Callable[[np.ndarray], np.ndarray]  # the train split's (by recording)
