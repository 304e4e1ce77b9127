"""Scores of models and of constant velocity over a split's targets, batch by batch (metres).

`score_members` scores the models of a multi-horizon run in one pass (`score_targets` one model):
each batch is loaded once, the models run as one ensemble (aigem.training.ensemble, each model over its
own future steps; on the CPU one after the other, faster there than stacked), and constant
velocity is computed once, for the longest horizon, each model's baseline being the first steps
of it (constant velocity's position at a step does not depend on how many steps follow). Each
model's scores are those it gets scored alone: constant velocity's exactly, the model's to float
rounding (batched products sum in another order).

One scorer for both kinds of batch: the loader's, or on CUDA (`resident`) static batches of the
split loaded onto the device once (aigem.training.resident, aigem.training.engine), each batch through one forward
function (on CUDA captured and replayed per capacity) and its targets summed on the host by the
same code (a static batch's from the split's host copy).
aigem.evaluation.evaluate turns scores into the numbers `aigem evaluate` reports.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import DataLoader

from aigem.cores import default_workers
from aigem.evaluation.results import FinalErrors, Scores
from aigem.metrics import ErrorTotals, SampleTotals
from aigem.model.batch import Batch
from aigem.model.data import Collate, GraphDataset, xy_to_metres
from aigem.model.network import AiGem
from aigem.runs.baseline import constant_velocity
from aigem.training import capacity, engine
from aigem.training.capacity import Capacity
from aigem.training.ensemble import Ensemble, stack
from aigem.training.loading import load_split
from aigem.training.resident import ResidentSplit, fits
from ngsim_graphs.budget import available_cores
from ngsim_graphs.grid import concat_ranges
from ngsim_graphs.scaling import MinMaxScaler


class NonFinitePredictionError(ValueError):
    """The model predicted NaN or infinite positions: no metric of them would mean anything.
    `member`: which model of a stacked pass (0 for a model scored alone)."""

    def __init__(self, where: str, member: int = 0) -> None:
        super().__init__(where)
        self.member = member


@dataclass(frozen=True)
class BatchTargets:
    """A batch's targets as the metrics take them, over its first K future steps: `truth`
    (A, K, 2) float32 and `cv` (A, K, 2) float64 constant-velocity positions (metres), `mask`
    (A, K) bool, `present_y_m` (A,) float64, `sample` (A,) each target's sample id in the split."""

    truth: np.ndarray
    cv: np.ndarray
    mask: np.ndarray
    present_y_m: np.ndarray
    sample: np.ndarray


def batch_targets(batch: Batch, dataset: GraphDataset, first: int, steps: int) -> BatchTargets:
    """The targets of a loader's batch that starts at sample index `first` (the loader's batches
    are consecutive indices, unshuffled), over `steps` future steps."""
    state = batch.target_state.numpy().astype(np.float64)  # (A, 4)
    ids = dataset.batch_order(np.arange(first, first + batch.graphs))
    return BatchTargets(
        truth=batch.target_xy[:, :steps].numpy(),
        cv=constant_velocity(state, steps, dataset.config.time_step_s),
        mask=batch.target_mask[:, :steps].numpy(),
        present_y_m=state[:, 1],
        sample=ids[batch.target_sample.numpy()],
    )


class ScoreSums:
    """What `Scores` sums over a split of `samples` samples for a model of `steps` future steps,
    batch by batch: per region and, for the bootstrap's intervals, per sample. The batch's
    targets may reach further: a model and constant velocity are scored over their first
    `steps` steps only, as if they had been computed for `steps` (constant velocity's positions
    at a step do not depend on how many steps follow)."""

    def __init__(self, steps: int, samples: int) -> None:
        self.steps = steps
        self.model, self.constant_velocity = ErrorTotals(steps), ErrorTotals(steps)
        self.by_sample = SampleTotals(samples, steps), SampleTotals(samples, steps)
        self._finals: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, predicted: np.ndarray, targets: BatchTargets) -> None:
        """Add a batch: `predicted` (A, >= steps, 2) positions in metres."""
        k = self.steps
        truth, mask, cv = targets.truth[:, :k], targets.mask[:, :k], targets.cv[:, :k]
        model_m = self.model.add(predicted[:, :k], truth, mask, targets.present_y_m)  # (A, K)
        cv_m = self.constant_velocity.add(cv, truth, mask, targets.present_y_m)
        for by_sample, error_m in zip(self.by_sample, (model_m, cv_m), strict=True):
            by_sample.add(error_m, mask, targets.sample)
        last = mask[:, -1]
        self._finals.append(
            (targets.sample[last], model_m[last, -1].astype(float), cv_m[last, -1].astype(float))
        )

    def scores(self) -> Scores:
        finals = self._finals or [(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))]  # no batch
        final = FinalErrors(*(np.concatenate(part) for part in zip(*finals, strict=True)))
        return Scores(self.model, self.constant_velocity, final, *self.by_sample)


def score_targets(
    model: AiGem,
    dataset: GraphDataset,
    steps: int,
    device: torch.device,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    resident: bool | None = None,
) -> Scores:
    """Error totals (metres) of the model and of constant velocity over `dataset`'s targets,
    `steps` future steps, and each target's final error; inputs scaled with `dataset.scaler`
    (`score_members` of the one model)."""
    return score_members([model], dataset, [steps], device, batch_size, progress, resident)[0]


def score_members(
    models: Sequence[AiGem],
    dataset: GraphDataset,
    steps: Sequence[int],
    device: torch.device,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    resident: bool | None = None,
) -> list[Scores]:
    """`score_targets` of each model (one ModelConfig; `steps` ascending, model m's future
    steps) in one pass over `dataset`: each batch is loaded once, the models run as one ensemble
    (aigem.training.ensemble: stacked, or on the CPU one after the other), and constant velocity is
    computed once, for the longest steps.
    A non-finite prediction raises NonFinitePredictionError naming the model's index.
    `resident` (None: on CUDA): the split loaded onto the device, scored in static batches of
    RESIDENT_BATCH (aigem.training.engine), where it takes at most half the device's free memory."""
    ensemble = stack(models, steps).eval()
    batches = None
    if resident if resident is not None else device.type == "cuda":
        batches = _static_batches(dataset, models[0].config.layers, max(steps), device)
    if batches is None:
        batches = _loader_batches(dataset, models[0].config.layers, batch_size, max(steps), device)
    count, pairs = batches
    forward = _Forward(ensemble, dataset.scaler, device)
    sums = [ScoreSums(k, len(dataset)) for k in steps]
    for index, (batch, targets) in enumerate(pairs):
        predicted = forward(batch)[:, : len(targets.sample)].cpu().numpy()  # (M, A, K, 2) metres
        _add_batch(sums, predicted, targets, f"batch {index + 1} of {count}")
        if progress:
            progress(index + 1, count)
    return [member_sums.scores() for member_sums in sums]


def _add_batch(
    sums: list[ScoreSums], predicted: np.ndarray, targets: BatchTargets, where: str
) -> None:
    """Each member's predictions (M, A, K, 2) metres of a batch added to its sums; a non-finite
    one raises NonFinitePredictionError naming the member and `where`."""
    for member, member_sums in enumerate(sums):
        if not np.isfinite(predicted[member, :, : member_sums.steps]).all():
            raise NonFinitePredictionError(where, member)
        member_sums.add(predicted[member], targets)


class _Forward:
    """The ensemble's predictions in metres ((M, A, K, 2), K = max(steps)) of a batch, the
    loader's or a static one, forward only: one function of a batch for both, on CUDA each
    static capacity's captured and replayed (aigem.training.engine) into a buffer of its own (padding
    after the batch's targets)."""

    def __init__(self, ensemble: Ensemble, scaler: MinMaxScaler, device: torch.device) -> None:
        self.ensemble, self.scaler, self.device = ensemble, scaler, device
        self.out: dict[Capacity, torch.Tensor] = {}
        self.replays = engine.Replays(device)

    def _metres(self, batch: Batch) -> torch.Tensor:
        with torch.no_grad():
            return xy_to_metres(self.scaler, self.ensemble.predict(batch))

    def __call__(self, batch: Batch | engine.StaticBatch) -> torch.Tensor:
        if isinstance(batch, Batch):
            return self._metres(batch)
        if batch.capacity not in self.out:  # before any capture
            shape = (self.ensemble.members, batch.capacity.targets, max(self.ensemble.steps), 2)
            self.out[batch.capacity] = torch.empty(shape, device=self.device)
        out = self.out[batch.capacity]
        self.replays(lambda assembled: out.copy_(self._metres(assembled)), batch)
        return out


# The batches of a pass: how many, and each batch (on the device) with its targets (on the host)
Pass = tuple[int, Iterator[tuple[Batch | engine.StaticBatch, BatchTargets]]]


def _loader_batches(
    dataset: GraphDataset, layers: int, batch_size: int, steps: int, device: torch.device
) -> Pass:
    """The split in order, in the loader's batches planned for an encoder of `layers` layers."""
    collate = Collate(dataset.scaler, layers=layers)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, collate_fn=collate)
    pairs = (
        (
            batch.to(device, non_blocking=True),
            batch_targets(batch, dataset, index * batch_size, steps),
        )
        for index, batch in enumerate(loader)
    )
    return len(loader), pairs


RESIDENT_BATCH = 1024  # samples a static batch of evaluation: the batch changes no number


def _host_targets(
    host: ResidentSplit, ids: np.ndarray, time_step_s: float, steps: int
) -> BatchTargets:
    """The targets of samples `ids` (a static batch's, in its order) from the split's host copy."""
    counts = host.counts[ids, 0]
    starts = host.target_start.numpy()[ids]
    _, rows = concat_ranges(starts, starts + counts)
    state = host.targets.state.numpy()[rows].astype(np.float64)  # (A, 4)
    return BatchTargets(
        truth=host.targets.xy.numpy()[rows, :steps],
        cv=constant_velocity(state, steps, time_step_s),
        mask=host.targets.mask.numpy()[rows, :steps],
        present_y_m=state[:, 1],
        sample=np.repeat(ids, counts),
    )


def _static_batches(
    dataset: GraphDataset, layers: int, steps: int, device: torch.device
) -> Pass | None:
    """The split loaded onto the device, in static batches of RESIDENT_BATCH samples, their
    targets from its host copy (None where it would take more than half of a GPU's free memory:
    then the loader serves)."""
    host = load_split(dataset, layers, default_workers(device.type, available_cores()))
    if not fits(host.nbytes(), device)[0]:
        return None
    split = host.to(device)
    base = capacity.base_capacity(host.counts, RESIDENT_BATCH, layers)
    order = np.arange(len(dataset))
    batches = engine.epoch_batches(split, order, RESIDENT_BATCH, base, dataset.batch_order, device)
    time_step_s = dataset.config.time_step_s
    pairs = (
        (
            batch,
            _host_targets(
                host, dataset.batch_order(order[first : first + RESIDENT_BATCH]), time_step_s, steps
            ),
        )
        for batch, first in zip(batches, range(0, len(order), RESIDENT_BATCH), strict=True)
    )
    return len(batches), pairs
