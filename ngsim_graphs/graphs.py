"""The graph of a sample (docs/conventions.md), induced from its recording's frame arrays.

For history steps k = 0..K_H-1 (k = K_H-1 is the present) of the window of ego track e that
starts at grid step s0:
- nodes at k: the ego, then every vehicle at step s0+k whose distance to the ego is <= d_sense,
  by ascending track id; features [x, y, heading, speed] with the ego's present position at (0, 0);
- edges: one set per edge type of the build (`BuildConfig.edge_types`; spatial within a step, temporal from a
  step to the next), each type's rule in `ngsim_graphs.edges`;
- targets: the actor nodes at the present step (and the ego, if asked), with their positions at
  the K_F future steps in the sample frame and a mask where the track has no row (it left).

Under the cs-lstm protocol the ego is the only target, and the ego need only be present at the
present step: at a history step where its track has no row the sample has no node at all (the
nodes are the vehicles near the ego, and there is no ego to be near).

A node is a track: a vehicle whose record was split at a frame gap is two tracks, never joined.
Everything is computed for a batch of samples at once with flat numpy gathers: no Python loop
over samples, steps or rows.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ngsim_graphs import edges
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.grid import RecordingArrays, concat_ranges
from ngsim_graphs.schema import Protocol


class NonFiniteStateError(ValueError):
    """A recording's arrays hold a position that is not finite: a damaged build."""


@dataclass(frozen=True)
class EdgeSet:
    """The edges of one type: [source, destination] node pairs and one attribute per edge."""

    index: np.ndarray  # (2, E) int64 [source, destination], batch-global nodes
    attribute: np.ndarray  # (E,) float64 (spatial: metres, float32 precision for actor-actor)


@dataclass(frozen=True)
class GraphBatch:
    """The graphs of B samples, concatenated. Node indices are batch-global.

    Nodes of sample b are node_ptr[b]:node_ptr[b+1], ordered by step, then ego first, then by
    track id; the sample-local index of node n is n - node_ptr[node_sample[n]]. `edges` holds
    an EdgeSet per edge type of the build, by name in `BuildConfig.edge_types` order; each comes by sample (the
    order within a sample is its rule's), so a batch equals the concatenation of its samples'
    graphs.
    """

    node_ptr: np.ndarray  # (B+1,) int64
    node_sample: np.ndarray  # (N,) int64 sample of each node, 0..B-1
    node_step: np.ndarray  # (N,) int8 history step k, 0..K_H-1
    node_track: np.ndarray  # (N,) int32
    node_is_ego: np.ndarray  # (N,) bool
    node_features: np.ndarray  # (N, 4) float64 [x_m, y_m, heading_rad, speed_mps], sample frame
    edges: Mapping[str, EdgeSet]  # by edge type name
    target_node: np.ndarray  # (T,) int64 node of each target (present step), by sample
    target_xy: np.ndarray  # (T, K_F, 2) float64 future positions, sample frame; 0 where masked
    target_mask: np.ndarray  # (T, K_F) bool: True where the position is recorded
    time_step_s: float  # the grid's time step

    def __getattr__(self, name: str) -> np.ndarray:
        """`batch.<type>_edges` (`spatial_edges`, ...): edges[type].index, (2, E) int64."""
        edge_sets = self.__dict__.get("edges", {})
        if name.endswith("_edges") and name.removesuffix("_edges") in edge_sets:
            return edge_sets[name.removesuffix("_edges")].index
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def n_samples(self) -> int:
        return len(self.node_ptr) - 1


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance of (..., 2) positions: sqrt(dx*dx + dy*dy) in float64."""
    dx, dy = a[..., 0] - b[..., 0], a[..., 1] - b[..., 1]
    return np.sqrt(dx * dx + dy * dy)


def _history_nodes(
    rec: RecordingArrays,
    ego_track: np.ndarray,
    start_step: np.ndarray,
    config: BuildConfig,
    first_step: int,
) -> tuple[np.ndarray, ...]:
    """Candidate rows of every (sample, kept step) "ss", which of them are nodes, and the egos.

    Returns ss_step (B*n_kept,) grid step of each ss, 0 where the ego is absent (cs-lstm);
    ego_rows (B*n_kept,) the ego's row at it, -1 where absent; cand_ss, cand_row, cand_dist (C,)
    the ss, row and distance to the ego (metres) of every row at the step of an ss with the ego;
    is_node (C,) bool; and B.
    """
    n_samples, n_kept = len(ego_track), config.history_steps - first_step
    kept = np.arange(first_step, config.history_steps)
    ss_step = (start_step[:, None] + kept).reshape(-1)  # sample-step -> grid step
    ego_rows = rec.row_at(np.repeat(ego_track, n_kept), ss_step)  # (B*n_kept,)
    has_ego = ego_rows >= 0
    if not has_ego.reshape(n_samples, n_kept)[:, -1].all():
        raise ValueError("an ego track is not present at the present step of its window")
    if config.protocol is Protocol.AIGEM and not has_ego.all():
        raise ValueError("an ego track is not present at every history step of its window")
    ss_step = np.where(has_ego, ss_step, 0)  # a step of the recording, whose rows are skipped
    first_row = rec.step_ptr[ss_step]
    cand_ss, cand_row = concat_ranges(
        first_row, np.where(has_ego, rec.step_ptr[ss_step + 1], first_row)
    )
    # np.take, not fancy indexing: a gather of whole rows that is several times faster.
    cand_dist = _distance(
        np.take(rec.node_state, cand_row, axis=0),
        np.take(rec.node_state, ego_rows[cand_ss], axis=0),
    )
    if not np.isfinite(cand_dist).all():  # NaN compares False: the vehicle would vanish silently
        raise NonFiniteStateError("positions that are not finite")
    is_node = cand_dist <= config.d_sense_m
    return ss_step, ego_rows, cand_ss, cand_row, cand_dist, is_node, n_samples


def induce_graphs(
    rec: RecordingArrays,
    ego_track: np.ndarray,
    start_step: np.ndarray,
    config: BuildConfig,
    first_step: int = 0,
) -> GraphBatch:
    """The graphs of samples (ego_track[b], start_step[b]) of one recording.

    `first_step` > 0 keeps only history steps first_step..K_H-1: the same nodes, edges and targets
    at those steps as the whole graph has, for a model that reads no further back (AiGem with L
    layers reads the last L + 1 steps only). Node steps stay numbered 0..K_H-1.
    """
    if not 0 <= first_step < config.history_steps:
        raise ValueError(f"first_step must be in 0..{config.history_steps - 1}, got {first_step}")
    ss_step, ego_rows, cand_ss, cand_row, cand_dist, is_node, n_samples = _history_nodes(
        rec, ego_track, start_step, config, first_step
    )
    n_kept = config.history_steps - first_step  # kept steps per sample
    cand_is_ego = cand_row == ego_rows[cand_ss]
    # Node order: by sample-step, ego first, then rows (rows of a step are by track id).
    member = np.flatnonzero(is_node)
    order = member[np.lexsort((cand_row[member], ~cand_is_ego[member], cand_ss[member]))]
    node_of_cand = np.full(len(cand_row), -1, dtype=np.int64)
    node_of_cand[order] = np.arange(len(order))
    node_ss, node_row = cand_ss[order], cand_row[order]
    node_sample = node_ss // n_kept
    origin = rec.node_state[ego_rows.reshape(n_samples, n_kept)[:, -1], :2]  # (B, 2) present ego
    features = np.take(rec.node_state, node_row, axis=0)
    features[:, :2] -= origin[node_sample]

    node_track = rec.node_track[node_row]
    node_step = (first_step + node_ss % n_kept).astype(np.int8)
    nodes = edges.Nodes(
        rec=rec,
        config=config,
        ss_step=ss_step,
        ego_rows=ego_rows,
        cand_ss=cand_ss,
        cand_is_ego=cand_is_ego,
        cand_dist=cand_dist,
        node_of_cand=node_of_cand,
        order=order,
        node_sample=node_sample,
        node_step=node_step,
        node_track=node_track,
    )
    edge_sets = {e.name: EdgeSet(*e.induce(nodes)) for e in edges.types_of(config.edge_types)}
    target_node, target_xy, target_mask = _targets(
        rec, node_sample, node_step, node_track, cand_is_ego[order], origin, start_step, config
    )
    return GraphBatch(
        node_ptr=np.searchsorted(node_sample, np.arange(n_samples + 1)).astype(np.int64),
        node_sample=node_sample,
        node_step=node_step,
        node_track=node_track,
        node_is_ego=cand_is_ego[order],
        node_features=features,
        edges=edge_sets,
        target_node=target_node,
        target_xy=target_xy,
        target_mask=target_mask,
        time_step_s=config.time_step_s,
    )


def _targets(rec, node_sample, node_step, node_track, node_is_ego, origin, start_step, config):
    """Present-step nodes to predict, their future positions in the sample frame, and masks."""
    present = node_step == config.history_steps - 1
    if config.protocol is Protocol.CS_LSTM:
        chosen = present & node_is_ego
    else:
        chosen = present if config.ego_is_target else present & ~node_is_ego
    target_node = np.flatnonzero(chosen).astype(np.int64)
    sample = node_sample[target_node]
    future = start_step[sample][:, None] + config.history_steps + np.arange(config.future_steps)
    rows = rec.row_at(np.repeat(node_track[target_node], config.future_steps), future.reshape(-1))
    rows = rows.reshape(len(target_node), config.future_steps)
    mask = rows >= 0
    xy = np.where(
        mask[..., None],
        np.take(rec.node_state, np.maximum(rows, 0), axis=0)[..., :2] - origin[sample][:, None],
        0.0,
    )
    return target_node, xy, mask


def concat_batches(batches: list[GraphBatch]) -> GraphBatch:
    """One batch of the samples of several, in order, with node indices offset."""
    if len(batches) == 1:
        return batches[0]
    node_offsets = np.cumsum([0] + [len(b.node_track) for b in batches])
    sample_offsets = np.cumsum([0] + [b.n_samples for b in batches])
    join = lambda name: np.concatenate([getattr(b, name) for b in batches])  # noqa: E731
    return GraphBatch(
        node_ptr=np.concatenate(
            [[0]] + [b.node_ptr[1:] + o for b, o in zip(batches, node_offsets, strict=False)]
        ),
        node_sample=np.concatenate(
            [b.node_sample + o for b, o in zip(batches, sample_offsets, strict=False)]
        ),
        node_step=join("node_step"),
        node_track=join("node_track"),
        node_is_ego=join("node_is_ego"),
        node_features=join("node_features"),
        edges={
            name: EdgeSet(
                np.concatenate(
                    [
                        b.edges[name].index + o
                        for b, o in zip(batches, node_offsets[:-1], strict=True)
                    ],
                    axis=1,
                ),
                np.concatenate([b.edges[name].attribute for b in batches]),
            )
            for name in batches[0].edges
        },
        target_node=np.concatenate(
            [b.target_node + o for b, o in zip(batches, node_offsets, strict=False)]
        ),
        target_xy=join("target_xy"),
        target_mask=join("target_mask"),
        time_step_s=batches[0].time_step_s,
    )
