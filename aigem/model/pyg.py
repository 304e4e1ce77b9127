"""PyTorch Geometric's view of a build: one `HeteroData` per sample, batched by PyG's own loader.

PyG batches `HeteroData` by concatenating every attribute and offsetting only edge indices (and
attributes named `*batch*`). Targets kept as a list of node indices would then point at the wrong
nodes of every graph but the first, so here a target is a node-level mask (`is_target`) with
node-level ground truth (`y`, `y_mask`), which concatenation keeps right. Per sample, with N
nodes, E edges of a type, K = K_F future steps:

    data["vehicle"].x          (N, 4) float32 [x, y, heading, speed], scaled as `Collate` does
    data["vehicle"].step       (N,) int64 history step k, 0..K_H-1 (K_H-1 is the present)
    data["vehicle"].is_ego     (N,) bool
    data["vehicle"].track_id   (N,) int64 the build's track id (a node is a track at a step)
    data["vehicle"].is_target  (N,) bool: the targets (actor nodes at the present step)
    data["vehicle"].y          (N, K, 2) float32 future positions, metres, in the sample's frame;
                               0 for non-targets and at masked steps
    data["vehicle"].y_mask     (N, K) bool: True where y is recorded (all False for non-targets)
    data["vehicle", name, "vehicle"]  for each edge type of the build (BuildConfig.edge_types):
                               edge_index (2, E), edge_attr (E, 1) as `Collate` gives them
                               (spatial: the scaled distance; temporal: t_s in seconds)
    data.sample_id             (1,) int64 the sample's index in its split

The targets come in node order, which is the order of `Collate`'s `target_node`;
`to_model_batch` turns a (batched) `HeteroData` into AiGem's input, an `aigem.model.batch.Batch`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Callable

import numpy as np
import torch
from torch_geometric.data import Dataset as PygDataset
from torch_geometric.data import HeteroData
from torch_geometric.data.summary import Stats, Summary

from aigem.model.batch import Batch, Edges
from aigem.model.data import GraphDataset
from ngsim_graphs import edges
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.schema import Split

NODE = "vehicle"


def relation(edge: edges.EdgeType) -> tuple[str, str, str]:
    """The HeteroData edge type of an edge type: (NODE, its name, NODE)."""
    return (NODE, edge.name, NODE)


SPATIAL = relation(edges.SPATIAL)
TEMPORAL = relation(edges.TEMPORAL)


def to_hetero_data(
    graph: GraphBatch, scaler: MinMaxScaler, sample_id: int | None = None
) -> HeteroData:
    """One sample's graph (a one-sample GraphBatch) as a HeteroData that PyG batches correctly."""
    if graph.n_samples != 1:
        raise ValueError(f"one sample's graph expected, got {graph.n_samples}: PyG batches them")
    n_nodes, future_steps = len(graph.node_sample), graph.target_xy.shape[1]
    y = np.zeros((n_nodes, future_steps, 2), dtype=np.float32)
    y_mask = np.zeros((n_nodes, future_steps), dtype=bool)
    is_target = np.zeros(n_nodes, dtype=bool)
    y[graph.target_node], y_mask[graph.target_node] = graph.target_xy, graph.target_mask
    is_target[graph.target_node] = True
    data = HeteroData()
    node = data[NODE]
    node.x = torch.from_numpy(scaler.scale_features(graph.node_features))
    node.step = torch.from_numpy(graph.node_step.astype(np.int64))
    node.is_ego = torch.from_numpy(graph.node_is_ego)
    node.track_id = torch.from_numpy(graph.node_track.astype(np.int64))
    node.is_target = torch.from_numpy(is_target)
    node.y, node.y_mask = torch.from_numpy(y), torch.from_numpy(y_mask)
    for edge in edges.types_of(tuple(graph.edges)):
        edge_set = graph.edges[edge.name]
        data[relation(edge)].edge_index = torch.from_numpy(edge_set.index)
        data[relation(edge)].edge_attr = torch.from_numpy(
            scaler.scale_edges(edge, edge_set.attribute)
        )
    if sample_id is not None:
        data.sample_id = torch.tensor([sample_id])
    return data


def to_model_batch(data: HeteroData) -> Batch:
    """AiGem's `aigem.model.batch.Batch` (the fields of `Collate`'s but `target_state` and `cv_step`,
    and no plan) from one HeteroData of `to_hetero_data` or a PyG batch of them; A targets in
    node order."""
    node = data[NODE]
    target = torch.nonzero(node.is_target).squeeze(1)  # (A,)
    node_sample = node.batch if "batch" in node else torch.zeros(node.num_nodes, dtype=torch.long)
    names = tuple(name for _, name, _ in data.edge_types)  # the build's, in its order
    return Batch(
        x=node.x,  # (N, 4) scaled
        target_node=target,
        target_sample=node_sample[target],  # (A,)
        target_xy=node.y[target],  # (A, K, 2) metres
        target_mask=node.y_mask[target],  # (A, K)
        edges={
            name: Edges(data[NODE, name, NODE].edge_index, data[NODE, name, NODE].edge_attr)
            for name in names
        },
        node_sample=node_sample,  # (N,)
        graphs=getattr(data, "num_graphs", 1),  # a PyG batch's; one HeteroData is one graph
    )


class GraphPygDataset(PygDataset):
    """The samples of one split of a build as a PyG dataset: `get(i)` is sample i's HeteroData.

    Graphs are induced on demand from the memory-mapped build (nothing is processed or stored):
    its `root` is the build's directory, and it has no raw or processed files. `history_steps`
    and `scaler` mean what they mean for `aigem.model.data.GraphDataset`. Batch with
    `torch_geometric.loader.DataLoader`. PyG's `print_summary` formats its tables with the
    package tabulate where it is installed, else as plain columns (`get_summary`).
    """

    def __init__(
        self,
        build_dir: str | os.PathLike[str],
        split: Split | str = Split.TRAIN,
        history_steps: int | None = None,
        scaler: MinMaxScaler | None = None,
        transform: Callable[[HeteroData], HeteroData] | None = None,
    ) -> None:
        self.samples = GraphDataset(build_dir, split, history_steps, scaler)
        # No download() or process() of ours: PyG makes no raw or processed folder in the root.
        super().__init__(root=str(self.samples.build_dir), transform=transform)

    def __repr__(self) -> str:
        samples = self.samples
        return (
            f"{type(self).__name__}(build={str(samples.build_dir)!r}, "
            f"split={samples.split.value!r}, samples={len(self)})"
        )

    def get_summary(self) -> Summary:
        """PyG's statistics of the graphs' sizes (every graph is induced: a pass over the split),
        shown without the package tabulate too (PlainSummary)."""
        return PlainSummary(**vars(super().get_summary()))

    @property
    def scaler(self) -> MinMaxScaler:
        return self.samples.scaler

    def len(self) -> int:
        return len(self.samples)

    def get(self, idx: int) -> HeteroData:
        return to_hetero_data(self.samples[idx], self.samples.scaler, sample_id=idx)


class PlainSummary(Summary):
    """PyG's Summary, formatted as plain columns where the package tabulate (which PyG's own
    format needs) is not installed; with it, as PyG formats it (`fmt`)."""

    def format(self, fmt: str = "psql") -> str:
        if importlib.util.find_spec("tabulate") is not None:
            return super().format(fmt)
        parts = [
            f"{self.name} (#graphs={self.num_graphs}):",
            *_columns({"#nodes": self.num_nodes, "#edges": self.num_edges}),
        ]
        for title, per_type in (
            ("Number of nodes per node type:", self.num_nodes_per_type),
            ("Number of edges per edge type:", self.num_edges_per_type),
        ):
            if per_type is not None:
                named = {
                    (k if isinstance(k, str) else f"({', '.join(k)})"): v
                    for k, v in per_type.items()
                }
                parts += [title, *_columns(named)]
        return "\n".join(parts)


def _columns(stats: dict[str, Stats]) -> list[str]:
    """One row per statistic (mean, std, min, ...), one right-aligned column per entry."""
    names = [field.name for field in dataclasses.fields(Stats)]
    rows = [["", *stats]] + [
        [name, *(f"{getattr(s, name):.1f}" for s in stats.values())] for name in names
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return [
        "  ".join(cell.rjust(width) for cell, width in zip(row, widths, strict=True))
        for row in rows
    ]
