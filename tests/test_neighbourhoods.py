"""Counts and scaler ranges from ego rows' neighbourhoods against those of the induced graphs.

The build no longer induces every sample's graph; `neighbourhoods` must give exactly what the
induced graphs hold (which tests/test_graphs.py checks against the brute force): the same counts
and the same minima and maxima, bit for bit, on a scene computed by hand and on random scenes
with vehicles at exactly the thresholds, under both protocols.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from conftest import set_budget
from test_graphs import SCENE_CONFIGS, TINY, all_windows, grid_table, random_scene, tiny_scene

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.graphs import GraphBatch, NonFiniteStateError, induce_graphs
from ngsim_graphs.grid import (
    RecordingArrays,
    grid_nodes,
    node_arrays,
    recording_arrays,
    step_pieces,
    with_pairs,
)
from ngsim_graphs.neighbourhoods import (
    ego_rows,
    history_rows,
    neighbourhoods,
    neighbourhoods_of_rows,
    row_bounds,
    rows_by_y,
    sample_counts,
)
from ngsim_graphs.scaling import MinMaxScaler, train_ranges
from ngsim_graphs.schema import Protocol


def induced_counts(batch: GraphBatch) -> np.ndarray:
    """(B, 5) nodes, spatial edges, temporal edges, targets, targets with a full future."""
    per = lambda nodes: np.bincount(batch.node_sample[nodes], minlength=batch.n_samples)  # noqa: E731
    full = batch.target_node[batch.target_mask.all(axis=1)]
    return np.stack(
        [
            np.diff(batch.node_ptr),
            per(batch.edges["spatial"].index[0]),
            per(batch.edges["temporal"].index[0]),
            per(batch.target_node),
            per(full),
        ],
        axis=1,
    )


def induced_ranges(batch: GraphBatch, is_train: np.ndarray) -> MinMaxScaler:
    """The scaler widened by the train samples' graphs, as the build once fitted it."""
    node_train = is_train[batch.node_sample]
    edge_train = node_train[batch.edges["spatial"].index[0]]
    return MinMaxScaler.empty().widened(
        batch.node_features[node_train],
        {"distance_m": batch.edges["spatial"].attribute[edge_train]},
    )


def arrays_of(table: pl.DataFrame, config: BuildConfig) -> RecordingArrays:
    tracks = table.with_columns((pl.col(s.STEP) * config.time_step_s).alias(s.TIME_S))
    nodes = grid_nodes(tracks.drop(s.STEP), config.time_step_s)
    return recording_arrays(nodes, config.d_min_m)


def counted(
    rec: RecordingArrays, egos: np.ndarray, starts: np.ndarray, is_train: np.ndarray, config
) -> tuple[np.ndarray, MinMaxScaler]:
    history = history_rows(rec, egos, starts, config)
    hood = neighbourhoods(rec, history, config)
    return sample_counts(hood, history, config), train_ranges(rec, hood, history, is_train)


@pytest.mark.parametrize("ego_is_target", [False, True])
def test_tiny_scene_by_hand(ego_is_target: bool) -> None:
    """test_graphs.expected_tiny's graph: 7 nodes, 12 spatial and 2 temporal edges; targets
    tracks 1 (leaves after one step), 2 and 4, and the ego when asked."""
    config = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2, ego_is_target=ego_is_target)
    rec = arrays_of(tiny_scene(), config)
    counts, ranges = counted(rec, np.array([0]), np.array([0]), np.array([True]), config)
    targets, full = (4, 3) if ego_is_target else (3, 2)
    assert counts.tolist() == [[7, 12, 2, targets, full]]
    # x 0..30 and y -40..40 with the ego at (0, 10) at the present; heading 0..0.4, speed 0..41;
    # distances 20 (track 3 at k = 0) to 50 (track 1, on a 3-4-5 diagonal).
    assert ranges.low == {
        "x_m": 0.0, "y_m": -40.0, "heading_rad": 0.0, "speed_mps": 0.0, "distance_m": 20.0
    }  # fmt: skip
    assert ranges.high == {
        "x_m": 30.0, "y_m": 40.0, "heading_rad": 0.4, "speed_mps": 41.0, "distance_m": 50.0
    }  # fmt: skip
    _, nothing = counted(rec, np.array([0]), np.array([0]), np.array([False]), config)
    assert nothing.to_dict() == MinMaxScaler.empty().to_dict()


def test_an_ego_alone_has_no_edge_and_no_distance_range() -> None:
    """One vehicle, nothing within d_sense (track 1 is 100 m away): one node a step, no spatial edge;
    the scaler's distances stay empty (inf, -inf), not the largest finite numbers."""
    config = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2)
    rows = [
        (step, track, 10 + track, 100.0 * track, 10.0 * step, 0.0, 10.0)
        for track in (0, 1)
        for step in range(4)
    ]
    rec = arrays_of(grid_table(rows), config)
    counts, ranges = counted(rec, np.array([0]), np.array([0]), np.array([True]), config)
    assert counts.tolist() == [[2, 0, 1, 0, 0]]  # the ego's own temporal edge
    assert ranges.low["distance_m"] == np.inf and ranges.high["distance_m"] == -np.inf
    assert ranges.low["x_m"] == 0.0 and ranges.high["y_m"] == 0.0


def test_an_ego_missing_from_its_window_is_refused() -> None:
    rec = arrays_of(tiny_scene(), TINY)
    with pytest.raises(ValueError, match="ego track is not present at every history step"):
        history_rows(rec, np.array([4]), np.array([0]), TINY)  # track 4 starts at step 1
    cslstm = BuildConfig(history_steps=2, future_steps=2, protocol=Protocol.CS_LSTM)
    assert history_rows(rec, np.array([4]), np.array([0]), cslstm)[0, 0] == -1
    with pytest.raises(ValueError, match="not present at the present step"):
        history_rows(rec, np.array([4]), np.array([-1]), cslstm)


def cslstm_windows(table: pl.DataFrame, config: BuildConfig) -> tuple[list[int], list[int]]:
    """A window at every present step of every track, its history reaching before the track."""
    egos, starts = [], []
    for track, step in table.select(s.TRACK_ID, s.STEP).sort(s.TRACK_ID, s.STEP).iter_rows():
        egos.append(track)
        starts.append(step - config.history_steps + 1)
    return egos, starts


CSLSTM_CONFIGS = (
    BuildConfig(protocol=Protocol.CS_LSTM),
    BuildConfig(protocol=Protocol.CS_LSTM, history_steps=5, future_steps=4, d_min_m=50.0),
)


@pytest.mark.parametrize("config", SCENE_CONFIGS + CSLSTM_CONFIGS)
def test_random_scenes_match_the_induced_graphs(
    config: BuildConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Tiny chunks, filled by two threads: every chunk boundary of a scene is crossed.
    set_budget(monkeypatch, ego_rows_per_chunk=7)
    set_budget(monkeypatch, samples_per_chunk=5)
    monkeypatch.setattr(pl, "thread_pool_size", lambda: 2)
    rng = np.random.default_rng(91)
    checked = shared = 0
    for _ in range(10):
        table = random_scene(rng, config)
        windows = cslstm_windows if config.protocol is Protocol.CS_LSTM else all_windows
        egos, starts = (np.array(v, dtype=np.int64) for v in windows(table, config))
        rec = arrays_of(table, config)
        is_train = rng.random(len(egos)) < 0.6
        batch = induce_graphs(rec, egos.astype(np.int32), starts, config)
        counts, ranges = counted(rec, egos, starts, is_train, config)
        assert np.array_equal(counts, induced_counts(batch))
        expected = induced_ranges(batch, is_train)
        assert ranges.low == expected.low and ranges.high == expected.high  # exactly
        checked += len(egos)
        history = history_rows(rec, egos, starts, config)
        shared += len(history[history >= 0]) - len(np.unique(history[history >= 0]))
    assert checked > 50 and counts[:, 2].sum() > 0 and counts[:, 4].sum() > 0
    if config.stride_steps < config.history_steps or config.protocol is Protocol.CS_LSTM:
        assert shared > 0, "rows in several samples' histories are looked at once"


@pytest.mark.parametrize("config", SCENE_CONFIGS[:2] + CSLSTM_CONFIGS)
def test_counts_and_ranges_of_ranges_of_steps_add_up_to_those_of_all_steps(
    config: BuildConfig,
) -> None:
    """As a build finds them: the pairs, the rows sorted by y and the neighbourhoods of one
    range of steps at a time, each range's counts added to every sample and its scaler
    joined; a sample's history often spans two ranges, and a range of one step holds a part
    of many samples."""
    rng = np.random.default_rng(23)
    spanned = 0
    for rows_per_piece in (1, 9, 60, 10_000):
        table = random_scene(rng, config)
        windows = cslstm_windows if config.protocol is Protocol.CS_LSTM else all_windows
        egos, starts = (np.array(v, dtype=np.int64) for v in windows(table, config))
        rec = arrays_of(table, config)
        is_train = rng.random(len(egos)) < 0.6
        expected_counts, expected = counted(rec, egos, starts, is_train, config)
        history = history_rows(rec, egos, starts, config)
        bare = node_arrays(
            grid_nodes(
                table.with_columns((pl.col(s.STEP) * config.time_step_s).alias(s.TIME_S)).drop(
                    s.STEP
                ),
                config.time_step_s,
            )
        )
        rows = ego_rows(history, len(bare.node_track))
        first_row, last_row = row_bounds(history)
        counts, ranges = np.zeros_like(expected_counts), MinMaxScaler.empty()
        for first, end in step_pieces(bare.step_ptr, rows_per_piece):
            lo, hi = int(bare.step_ptr[first]), int(bare.step_ptr[end])
            piece = with_pairs(bare, first, end, config.d_min_m)
            mine, by_y = rows[(rows >= lo) & (rows < hi)], rows_by_y(bare, first, end)
            hood = neighbourhoods_of_rows(piece, mine, by_y, config)
            # Every sample, touched or not, as row_bounds tells the build which to take.
            added = sample_counts(hood, history, config)
            untouched = (last_row < lo) | (first_row >= hi)
            assert not added[untouched].any()
            counts += added
            ranges = ranges.joined(train_ranges(piece, hood, history, is_train))
            spanned += int(((first_row < lo) & (last_row >= lo)).sum())
        assert np.array_equal(counts, expected_counts)
        assert ranges.low == expected.low and ranges.high == expected.high  # exactly
    assert spanned > 10 and expected_counts[:, 1].sum() > 0


def test_a_position_that_is_not_finite_is_refused() -> None:
    table = tiny_scene().with_columns(
        pl.when(pl.col(s.TRACK_ID) == 5).then(float("nan")).otherwise(pl.col(s.Y_M)).alias(s.Y_M)
    )  # track 5 is never near the ego: only a check of every position finds it
    rec = arrays_of(table, TINY)
    with pytest.raises(NonFiniteStateError, match="not finite"):
        neighbourhoods(rec, history_rows(rec, np.array([0]), np.array([0]), TINY), TINY)


def test_no_windows_no_counts() -> None:
    rec = arrays_of(tiny_scene(), TINY)
    none = np.empty(0, np.int64)
    counts, ranges = counted(rec, none, none, np.empty(0, bool), TINY)
    assert counts.shape == (0, 5)
    assert not ranges.is_fitted


def test_the_rows_of_a_range_of_steps_by_y_are_those_of_all_steps_in_the_range() -> None:
    """Global rows and keys, in the order of the whole recording's, for ranges of 1 to all steps."""
    rec = arrays_of(random_scene(np.random.default_rng(4), SCENE_CONFIGS[0]), SCENE_CONFIGS[0])
    order, keys = rows_by_y(rec)
    assert rec.n_steps > 10
    for first, end in [(0, rec.n_steps), (0, 1), (3, 4), (2, 9), (rec.n_steps - 1, rec.n_steps)]:
        lo, hi = int(rec.step_ptr[first]), int(rec.step_ptr[end])
        inside = (order >= lo) & (order < hi)
        part_order, part_keys = rows_by_y(rec, first, end)
        np.testing.assert_array_equal(part_order, order[inside])
        np.testing.assert_array_equal(part_keys, keys[inside])
        assert len(part_order) == hi - lo > 0
