"""One sample of a `GraphBatch` in the plotted road frame, for the scene pictures.

A road is drawn as seen from above with the traffic travelling left to right, as road plots
are: the horizontal axis is the sample frame's y (along the road, growing with travel), the
vertical axis the lateral offset to the LEFT of travel, -x (x grows to the driver's right in
both NGSIM and highD builds), so that both axes' numbers grow right and up and no axis is
inverted. Positions are metres, the ego at (0, 0) at the present step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ngsim_graphs.graphs import GraphBatch

ALONG_LABEL = "along the road (m), travel to the right"
LEFT_LABEL = "to the left of travel (m)"


@dataclass(frozen=True)
class SampleParts:
    """One sample of a batch, with batch-global node indices."""

    nodes: np.ndarray  # (n,) its nodes
    present: int  # its present step (K_H-1: the ego is a node at every step)
    spatial: np.ndarray  # (2, e) its directed spatial edges at the present step
    temporal: np.ndarray  # (2, t) its temporal edges
    targets: np.ndarray  # (a,) its targets' indices into target_node


def sample_parts(batch: GraphBatch, sample: int) -> SampleParts:
    """Sample `sample`'s nodes, its present step's spatial edges, its temporal edges and its
    targets; a ValueError where the batch has no such sample."""
    if not 0 <= sample < batch.n_samples:
        raise ValueError(f"sample {sample} is not in a batch of {batch.n_samples}")
    first, last = int(batch.node_ptr[sample]), int(batch.node_ptr[sample + 1])
    present = int(batch.node_step[first:last].max())
    none = np.zeros((2, 0), np.int64)  # a build without the type: none drawn
    spatial, temporal = (
        batch.edges[name].index if name in batch.edges else none for name in ("spatial", "temporal")
    )
    source = spatial[0]
    mine = (source >= first) & (source < last)
    spatial = spatial[:, mine & (batch.node_step[source] == present)]
    temporal = temporal[:, (temporal[0] >= first) & (temporal[0] < last)]
    targets = np.flatnonzero(batch.node_sample[batch.target_node] == sample)
    return SampleParts(np.arange(first, last), present, spatial, temporal, targets)


def spatial_counts(batch: GraphBatch, parts: SampleParts) -> tuple[int, int]:
    """The directed spatial edges of the present step: (ego-neighbour, neighbour-neighbour)."""
    source, destination = parts.spatial
    is_ego = batch.node_is_ego[source] | batch.node_is_ego[destination]
    return int(is_ego.sum()), int((~is_ego).sum())


def plotted(xy: np.ndarray) -> np.ndarray:
    """Positions (..., 2) of the sample frame, (x, y), as plotted: (y, -x), along the road, then
    to the left of travel."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.stack([xy[..., 1], -xy[..., 0]], axis=-1)


def node_xy(batch: GraphBatch, nodes: np.ndarray) -> np.ndarray:
    """(n, 2) the nodes' positions as plotted."""
    return plotted(batch.node_features[nodes, :2])


def track_nodes(batch: GraphBatch, parts: SampleParts, node: int) -> np.ndarray:
    """The sample's nodes of `node`'s track (its history), oldest first."""
    mine = parts.nodes[batch.node_track[parts.nodes] == batch.node_track[node]]
    return mine[np.argsort(batch.node_step[mine], kind="stable")]


def paths(start: np.ndarray, future: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(a, 1+K, 2) lines from each present position through its future positions; NaN at masked
    steps, so that a line breaks where the vehicle is not recorded."""
    future = np.where(mask[..., None], future, np.nan) if mask is not None else future
    return np.concatenate([start[:, None, :], future], axis=1)
