"""The training dataset over a finished ngsim-graphs build, and its batching.

Opening a split costs the same for a tiny build and for the six-recording one: the manifest is
read and the arrays are memory-mapped. An item is one sample's graph induced from the mapped
arrays; `__getitems__` induces a whole batch at once (PyTorch's DataLoader calls it when it
exists), and the collate function concatenates graphs with vectorised index offsets and applies
the scaler (the build's own, or a run's) into an `aigem.model.batch.Batch`. Shapes: N nodes, E edges, A
target actors, K future steps. PyTorch Geometric's view of the same samples is in aigem.model.pyg.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from aigem.model.batch import Batch, Edges
from aigem.model.plan import make_plan
from ngsim_graphs import edges
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.graphs import GraphBatch, concat_batches
from ngsim_graphs.scaling import FEATURES, SCALED, MinMaxScaler
from ngsim_graphs.schema import Split
from ngsim_graphs.splits import split_named

XY = FEATURES[:2]  # the scaled quantities a model predicts: x_m, y_m


def run_scaler(values: object, path: Path) -> MinMaxScaler:
    """A scaler recorded elsewhere (a run's, for another build); `path` names its file."""
    try:
        scaler = MinMaxScaler.from_dict(values)
    except ValueError:
        scaler = None
    if scaler is None or not scaler.is_fitted:
        raise NgsimInputError(
            path, f"records no complete scaler (min, max and target range of {', '.join(SCALED)})"
        )
    return scaler


def xy_to_metres(scaler: MinMaxScaler, scaled: torch.Tensor) -> torch.Tensor:
    """(..., 2) scaled positions back to metres (differentiable)."""
    return torch.stack([scaler.unscale(name, scaled[..., i]) for i, name in enumerate(XY)], dim=-1)


COVER_TOLERANCE = 1e-3  # scaled units: float32 rounding, far below any edit that matters
QUANTITIES = {  # how a scaled quantity is named to a user, and its unit
    "x_m": ("x", "m"),
    "y_m": ("y", "m"),
    "heading_rad": ("heading", "rad"),
    "speed_mps": ("speed", "m/s"),
    "distance_m": ("spatial-edge distance", "m"),
}


def check_covered(batch: Batch, scaler: MinMaxScaler, manifest: Path) -> None:
    """Refuse a train batch whose scaled inputs leave the scaler's target ranges: the scaler is
    fitted on exactly the train split's values, so a value outside says the scaler recorded in
    `manifest` is not the one fitted (an edited manifest, re-sealed: its checksum is unkeyed and
    anyone can recompute it). A min and max per quantity of the batch's (N, 4) features and
    (E, 1) scaled edge attributes, on the CPU."""
    columns = [
        (edge.attribute, batch.edges[edge.name].attr[:, 0])
        for edge in edges.types_of(batch.edge_types)
        if edge.scaled
    ]
    columns += [(name, batch.x[:, i]) for i, name in enumerate(FEATURES)]
    for name, values in columns:
        if not len(values):
            continue
        low, high = (float(v) for v in torch.aminmax(values))
        to_low, to_high = scaler.target[name]
        label, unit = QUANTITIES[name]
        for value, outside, end in (
            (high, high > to_high + COVER_TOLERANCE, scaler.high[name]),
            (low, low < to_low - COVER_TOLERANCE, scaler.low[name]),
        ):
            if outside:
                raise NgsimInputError(
                    manifest,
                    f"the scaler does not cover the train split: {label} "
                    f"{float(scaler.unscale(name, value)):.1f} {unit} where its range ends at "
                    f"{end:.1f} {unit}; edited manifest? build again",
                )


class GraphDataset(Dataset):
    """The samples of one split of a build; item i is sample i's graph (a one-sample GraphBatch).

    `history_steps`: keep only the last that many history steps of each graph (None, or K_H or
    more: all K_H). A model that reads no further back predicts the same from the smaller graphs,
    and the loader does a fraction of the work: AiGem with L layers reads L + 1 steps
    (`ModelConfig.history_steps_read`).

    `scaler`: the scaler that `Collate` should apply (None: the build's own). A model trained on
    one build and evaluated on another must see its inputs scaled as in training, so evaluation
    passes the run's scaler; the build then needs no fitted scaler of its own.

    A batch (`__getitems__`, which PyTorch's DataLoader calls) holds its graphs grouped by
    recording, not in the order of the indices asked for.
    """

    def __init__(
        self,
        build_dir: str | os.PathLike[str],
        split: Split | str = Split.TRAIN,
        history_steps: int | None = None,
        scaler: MinMaxScaler | None = None,
    ) -> None:
        self.build_dir = Path(build_dir)
        self.split = split_named(split)
        build = open_build(self.build_dir)  # refuses unfinished builds and unknown versions
        self.config = build.config
        if history_steps is not None and history_steps < 1:
            raise ValueError(f"history_steps must be at least 1, got {history_steps}")
        keep = self.config.history_steps if history_steps is None else history_steps
        self.first_step = max(0, self.config.history_steps - keep)
        if scaler is None and not build.manifest.scaler.is_fitted:
            raise NgsimInputError(
                self.build_dir, "the build has no fitted scaler (is its train split empty?)"
            )
        self.scaler = scaler if scaler is not None else build.manifest.scaler
        self.size = int(build.manifest.splits[self.split.value])
        self._build: OpenBuild | None = build  # None in a worker process: it opens its own

    @property
    def build(self) -> OpenBuild:
        if self._build is None:
            self._build = open_build(self.build_dir)
        return self._build

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: int) -> GraphBatch:
        return self.build.graphs(self.split, np.array([index]), self.first_step)

    def __getitems__(self, indices: list[int]) -> list[GraphBatch]:
        """The whole batch's graphs, induced once per recording: grouped by recording (in
        recording order), and in the given order within a recording. Losses and metrics are sums
        over a batch's targets, so the order changes them by float rounding only; in training it
        decides which dropout mask a target gets."""
        return [self.build.graphs(self.split, self.batch_order(indices), self.first_step)]

    def batch_order(self, indices: list[int] | np.ndarray) -> np.ndarray:
        """(B,) the sample ids of a batch of `indices` in the order its graphs come: by
        recording, stable (sample b of the batch is split sample batch_order(indices)[b])."""
        ids = np.asarray(indices, dtype=np.int64)
        recording = self.build.sample_arrays(self.split)["recording_index"][ids]
        return ids[np.argsort(recording, kind="stable")]

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_build": None}  # memory maps are reopened by each worker


@dataclass(frozen=True)
class Collate:
    """Batches graphs into one `aigem.model.batch.Batch` (picklable, for DataLoader workers).

    `layers`: also plan the encoder of a model with that many layers for the batch's targets
    (`Batch.plan`, an `aigem.model.plan.Plan`), so that the model step, on any device, neither plans
    nor waits for the device to read the plan's sizes.
    """

    scaler: MinMaxScaler
    layers: int | None = None

    def cv_step(self, present: np.ndarray, time_step_s: float) -> np.ndarray:
        """(A, 4) physical present states -> (A, 2) float32 constant velocity's displacement over
        one time step (the present speed along the present heading) in scaled units."""
        heading, speed = present[:, 2], present[:, 3]
        metres = (speed * time_step_s)[:, None] * np.stack([np.sin(heading), np.cos(heading)], 1)
        scaled = [
            self.scaler.scale(name, metres[:, i]) - self.scaler.scale(name, 0.0)
            for i, name in enumerate(XY)
        ]
        return np.stack(scaled, axis=1).astype(np.float32)

    def __call__(self, graphs: list[GraphBatch]) -> Batch:
        batch = concat_batches(graphs)
        targets = batch.target_node
        present = batch.node_features[targets]
        batch_edges = {  # the build's edge types, in its order
            edge.name: Edges(
                torch.from_numpy(batch.edges[edge.name].index),
                torch.from_numpy(self.scaler.scale_edges(edge, batch.edges[edge.name].attribute)),
            )
            for edge in edges.types_of(tuple(batch.edges))
        }
        out = Batch(
            x=torch.from_numpy(self.scaler.scale_features(batch.node_features)),
            target_node=torch.from_numpy(targets),
            target_sample=torch.from_numpy(batch.node_sample[targets]),
            target_xy=torch.from_numpy(batch.target_xy.astype(np.float32)),
            target_mask=torch.from_numpy(batch.target_mask),
            edges=batch_edges,
            node_sample=torch.from_numpy(batch.node_sample),
            target_state=torch.from_numpy(present.astype(np.float32)),
            cv_step=torch.from_numpy(self.cv_step(present, batch.time_step_s)),
            graphs=batch.n_samples,
        )
        if self.layers is None:
            return out
        plan = make_plan(len(batch.node_sample), out.target_node, out.edge_inputs(), self.layers)
        return replace(out, plan=plan)
