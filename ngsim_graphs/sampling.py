"""From one recording's tracks to its samples: frame arrays, ego windows, splits, graph counts.

Every sample's graph is induced once here, in small batches, to count its nodes, edges and
targets and to fit the scaler on the train split; the graphs themselves are not stored per
sample (see README: the dataset induces them from the frame arrays).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.frames import RecordingArrays, grid_nodes, proximity_pairs, recording_arrays
from ngsim_graphs.graphs import GraphBatch, induce_graphs
from ngsim_graphs.scaling import FittedRanges, update_ranges
from ngsim_graphs.schema import Split
from ngsim_graphs.splits import SPLIT, assign_splits
from ngsim_graphs.windows import ego_windows

INDUCE_BATCH = 64  # samples per induction: small batches stay in the CPU caches

N_NODES, N_SPATIAL, N_TEMPORAL = "n_nodes", "n_spatial_edges", "n_temporal_edges"
N_TARGETS, N_FULL_TARGETS = "n_targets", "n_targets_full_future"
COUNT_COLUMNS = (N_NODES, N_SPATIAL, N_TEMPORAL, N_TARGETS, N_FULL_TARGETS)


@dataclass(frozen=True)
class RecordingSamples:
    """What one recording contributes to a build."""

    pairs: pl.DataFrame  # PROXIMITY_SCHEMA
    arrays: RecordingArrays
    windows: pl.DataFrame  # ego windows with SPLIT and the COUNT_COLUMNS
    ranges: FittedRanges  # widened by this recording's train samples


def iter_graphs(rec: RecordingArrays, windows: pl.DataFrame, config: BuildConfig) -> Iterator[GraphBatch]:
    """The graphs of `windows` (EGO_TRACK_ID, START_STEP) in order, INDUCE_BATCH at a time."""
    egos, starts = windows[s.EGO_TRACK_ID].to_numpy(), windows[s.START_STEP].to_numpy()
    for first in range(0, len(egos), INDUCE_BATCH):
        part = slice(first, first + INDUCE_BATCH)
        yield induce_graphs(rec, egos[part], starts[part], config)


def graph_counts(batch: GraphBatch) -> np.ndarray:
    """(B, 5) int64: nodes, spatial edges, temporal edges, targets, targets with a full future."""
    b = batch.n_samples
    per = lambda nodes: np.bincount(batch.node_sample[nodes], minlength=b)  # noqa: E731
    full = batch.target_node[batch.target_mask.all(axis=1)]
    return np.stack(
        [np.diff(batch.node_ptr), per(batch.spatial_edges[0]), per(batch.temporal_edges[0]),
         per(batch.target_node), per(full)], axis=1,
    )  # fmt: skip


def recording_samples(
    tracks: pl.DataFrame, recording_index: int, config: BuildConfig, ranges: FittedRanges
) -> RecordingSamples:
    """Frame arrays, proximity edges and split ego windows of one recording's tracks table."""
    nodes = grid_nodes(tracks, config.frames_per_step)
    pairs = proximity_pairs(nodes, config.d_min_m)
    arrays = recording_arrays(nodes, pairs)
    max_vehicle_id = int(tracks[s.VEHICLE_ID].max()) if tracks.height else 0
    windows = assign_splits(ego_windows(nodes, config), max_vehicle_id, recording_index, config)
    train_flags = (windows[SPLIT] == Split.TRAIN.value).to_numpy()
    counts, first = [], 0
    for batch in iter_graphs(arrays, windows, config):
        is_train = train_flags[first : first + batch.n_samples]
        first += batch.n_samples
        counts.append(graph_counts(batch))
        if is_train.any():
            node_train = is_train[batch.node_sample]
            edge_train = node_train[batch.spatial_edges[0]]
            ranges = update_ranges(ranges, batch.node_features[node_train], batch.spatial_distance[edge_train])
    table = np.concatenate(counts) if counts else np.zeros((0, len(COUNT_COLUMNS)), np.int64)
    windows = windows.with_columns(
        pl.Series(name, table[:, i], dtype=pl.Int32) for i, name in enumerate(COUNT_COLUMNS)
    )
    return RecordingSamples(pairs=pairs, arrays=arrays, windows=windows, ranges=ranges)

