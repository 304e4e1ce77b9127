"""Per-recording frame data: grid nodes, proximity pairs (against an O(n^2) brute force) and the
flat indexes of RecordingArrays, worked out by hand on a tiny table."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from polars.testing import assert_frame_equal

from ngsim_graphs import grid
from ngsim_graphs import schema as s
from ngsim_graphs.grid import (
    ARRAY_NAMES,
    PAIR_KEY_STEP,
    ROW_ARRAYS,
    grid_nodes,
    node_arrays,
    pair_table,
    recording_arrays,
    step_pieces,
    with_pairs,
    write_node_arrays,
)


def brute_force_pairs(nodes: pl.DataFrame, d_max_m: float) -> pl.DataFrame:
    """Every pair of tracks at one step with sqrt(dx*dx + dy*dy) <= d_max_m (float64): all
    pairs of each step's rows, no sweep (PROXIMITY_SCHEMA, sorted by step, track_a, track_b)."""
    parts = [pl.DataFrame(schema=s.PROXIMITY_SCHEMA)]
    for (step,), rows in nodes.partition_by(s.STEP, as_dict=True, maintain_order=True).items():
        track, x, y = (rows[c].to_numpy() for c in (s.TRACK_ID, s.X_M, s.Y_M))
        i, j = np.triu_indices(len(track), 1)
        dx, dy = x[i] - x[j], y[i] - y[j]
        distance = np.sqrt(dx * dx + dy * dy)
        near = distance <= d_max_m
        a, b = track[i[near]], track[j[near]]
        columns = [np.full(near.sum(), step), np.minimum(a, b), np.maximum(a, b), distance[near]]
        frame = pl.DataFrame(dict(zip(s.PROXIMITY_SCHEMA.names(), columns, strict=True)))
        parts.append(frame.cast(dict(s.PROXIMITY_SCHEMA)))
    return pl.concat(parts).sort(s.STEP, s.TRACK_A, s.TRACK_B)


def pairs_of(nodes: pl.DataFrame, d_max_m: float) -> pl.DataFrame:
    """The proximity pairs of grid nodes, as a table: their recording arrays' pairs."""
    return pair_table(recording_arrays(nodes, d_max_m))


# The pair arrays hold distances in float32: a brute force's float64 distances, so rounded.
AS_STORED = pl.col(s.DISTANCE_M).cast(pl.Float32).cast(pl.Float64)


def grid_table(rows: list[tuple]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema=s.GRID_NODE_SCHEMA, orient="row").sort(s.STEP, s.TRACK_ID)


def random_nodes(rng: np.random.Generator, d_max_m: float) -> pl.DataFrame:
    """30 steps of 0-40 vehicles on 4 lanes over 300 m, positions multiples of 1/1024 m, with
    pairs placed exactly d_max_m apart (straight and 3-4-5) and one float64 step beyond, and
    vehicles side by side at equal y."""
    rows = []
    for step in range(30):
        n = int(rng.integers(0, 41))
        tracks = rng.choice(200, size=n + 6, replace=False)
        x = np.round((1.8 + 3.6 * rng.integers(0, 4, n) + rng.normal(0, 0.3, n)) * 1024) / 1024
        y = np.round(rng.uniform(0, 300, n) * 1024) / 1024
        y[: n // 4] = y[n // 4 : 2 * (n // 4)]  # side by side: equal y
        points = list(zip(x.tolist(), y.tolist(), strict=True))
        bx, by = 5.5, float(np.round(rng.uniform(0, 250) * 1024) / 1024)
        beyond = float(np.nextafter(by + d_max_m, math.inf))
        while math.sqrt((beyond - by) ** 2) <= d_max_m:
            beyond = float(np.nextafter(beyond, math.inf))
        points += [
            (bx, by), (bx, by + d_max_m), (bx + d_max_m * 3 / 5, by + d_max_m * 4 / 5),  # exactly d
            (bx - 3.6, by), (bx - 3.6, beyond), (bx + 9.0, by),  # beyond d; another lane
        ]  # fmt: skip
        for track, (px, py) in zip(tracks.tolist(), points, strict=True):
            rows.append((step, track, track + 1000, px, py, 0.0, 10.0))
    return grid_table(rows)


@pytest.mark.parametrize("d_max_m", [0.0, 12.5, 25.0, 50.0, 400.0])
def test_proximity_pairs_match_the_brute_force(d_max_m: float) -> None:
    rng = np.random.default_rng(int(d_max_m * 10) + 1)
    nodes = random_nodes(rng, d_max_m)
    expected = brute_force_pairs(nodes, d_max_m)
    got = pairs_of(nodes, d_max_m)
    assert got.schema == s.PROXIMITY_SCHEMA
    assert_frame_equal(got, expected.with_columns(AS_STORED))  # same pairs, same order
    at_threshold = expected.filter(pl.col(s.DISTANCE_M) == d_max_m).height
    assert at_threshold >= 30 * 2  # every step has its exact straight and 3-4-5 pairs


def test_proximity_pairs_by_hand() -> None:
    nodes = grid_table([
        (0, 1, 1, 0.0, 0.0, 0.0, 0.0), (0, 2, 2, 0.0, 25.0, 0.0, 0.0),
        (0, 3, 3, 15.0, 20.0, 0.0, 0.0),
        (0, 4, 4, 0.0, float(np.nextafter(50.0, 99.0)), 0.0, 0.0),
        (1, 1, 1, 0.0, 3.0, 0.0, 0.0), (1, 2, 2, 0.0, 3.0, 0.0, 0.0),
    ])  # fmt: skip
    got = pairs_of(nodes, 25.0)
    assert got.rows() == [
        (0, 1, 2, 25.0),
        (0, 1, 3, 25.0),
        (0, 2, 3, float(np.float32(math.sqrt(15.0**2 + 5.0**2)))),
        (1, 1, 2, 0.0),
    ]
    assert pairs_of(nodes, 0.0).rows() == [(1, 1, 2, 0.0)]
    assert pairs_of(nodes.clear(), 25.0).height == 0


def test_grid_nodes_steps_columns_and_order() -> None:
    tracks = pl.DataFrame({
        s.TIME_S: [1.4, 1.0, 1.2, 1.2], s.TRACK_ID: [3, 3, 3, 2], s.VEHICLE_ID: [7, 7, 7, 5],
        s.X_M: [1.0, 2.0, 3.0, 4.0], s.Y_M: [5.0, 6.0, 7.0, 8.0],
        s.HEADING_RAD: [0.1, 0.2, 0.3, 0.4],
        s.SPEED_MPS: [9.0, 8.0, 7.0, 6.0], s.LANE_ID: [1, 1, 1, 2],
    })  # fmt: skip
    nodes = grid_nodes(tracks, 0.2)
    assert nodes.schema == s.GRID_NODE_SCHEMA
    assert nodes.rows() == [
        (5, 3, 7, 2.0, 6.0, 0.2, 8.0), (6, 2, 5, 4.0, 8.0, 0.4, 6.0), (6, 3, 7, 3.0, 7.0, 0.3, 7.0),
        (7, 3, 7, 1.0, 5.0, 0.1, 9.0),
    ]  # fmt: skip


def tiny_nodes() -> pl.DataFrame:
    """Tracks 5, 6, 7 (first id 5) over steps 0..2:

    row  step track  (x, y)
     0    0    5     (0, 0)
     1    0    6     (0, 10)
     2    1    5     (0, 1)
     3    1    6     (0, 11)
     4    1    7     (3, 30)   19.24 m from track 6, 29.2 m from track 5
     5    2    6     (0, 12)
     6    2    7     (0, 31)   19 m from track 6
    """
    return grid_table([
        (0, 5, 50, 0.0, 0.0, 0.0, 1.0), (0, 6, 60, 0.0, 10.0, 0.0, 2.0),
        (1, 5, 50, 0.0, 1.0, 0.0, 3.0), (1, 6, 60, 0.0, 11.0, 0.0, 4.0),
        (1, 7, 70, 3.0, 30.0, 0.0, 5.0),
        (2, 6, 60, 0.0, 12.0, 0.0, 6.0), (2, 7, 70, 0.0, 31.0, 0.0, 7.0),
    ])  # fmt: skip


def test_recording_arrays_by_hand() -> None:
    nodes = tiny_nodes()
    rec = recording_arrays(nodes, 20.0)
    assert pair_table(rec).select(s.STEP, s.TRACK_A, s.TRACK_B).rows() == [
        (0, 5, 6),
        (1, 5, 6),
        (1, 6, 7),
        (2, 6, 7),
    ]
    assert rec.first_track_id == 5 and rec.n_steps == 3
    assert rec.step_ptr.tolist() == [0, 2, 5, 7]
    assert rec.node_track.tolist() == [5, 6, 5, 6, 7, 6, 7]
    assert rec.node_state[:, 1].tolist() == [0.0, 10.0, 1.0, 11.0, 30.0, 12.0, 31.0]
    assert rec.node_state[:, 3].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert rec.track_first_step.tolist() == [0, 0, 1]
    assert rec.track_ptr.tolist() == [0, 2, 5, 7]
    assert rec.track_rows.tolist() == [0, 2, 1, 3, 5, 4, 6]
    first, count = rec.track_steps(np.array([7, 5, 6]))
    assert first.tolist() == [1, 0, 0] and count.tolist() == [2, 2, 3]
    tracks = np.array([5, 5, 5, 6, 6, 6, 7, 7, 7])
    steps = np.array([0, 1, 2, 0, 1, 2, 0, 1, 2])
    assert rec.row_at(tracks, steps).tolist() == [0, 2, -1, 1, 3, 5, -1, 4, 6]
    assert rec.row_at(np.array([5, 6]), np.array([-1, 3])).tolist() == [-1, -1]
    # Pairs by step, lower vehicle (smaller y) first, ordered by (step, y of the lower vehicle).
    assert rec.pair_ptr.tolist() == [0, 1, 3, 4]
    assert rec.pair_rows.tolist() == [[0, 1], [2, 3], [3, 4], [5, 6]]
    assert rec.pair_dist.dtype == np.float32
    assert rec.pair_dist.tolist() == pytest.approx([10.0, 10.0, math.sqrt(9 + 19**2), 19.0])
    assert rec.pair_key.tolist() == [
        0.0,
        PAIR_KEY_STEP + 1.0,
        PAIR_KEY_STEP + 11.0,
        2 * PAIR_KEY_STEP + 12.0,
    ]


def test_recording_arrays_pairs_with_the_higher_track_lower_in_y() -> None:
    """pair_rows puts the vehicle with the smaller y first, whatever the track ids."""
    nodes = grid_table([(3, 8, 1, 0.0, 40.0, 0.0, 0.0), (3, 9, 2, 0.0, 30.0, 0.0, 0.0)])
    rec = recording_arrays(nodes, 25.0)
    assert rec.n_steps == 4 and rec.step_ptr.tolist() == [0, 0, 0, 0, 2]
    assert rec.pair_rows.tolist() == [[1, 0]]
    assert rec.pair_key.tolist() == [3 * PAIR_KEY_STEP + 30.0]
    assert rec.pair_ptr.tolist() == [0, 0, 0, 0, 1]


def test_step_pieces_by_hand() -> None:
    """Steps of 3, 0, 7, 2 and 8 rows in pieces of about 5 rows: a piece ends at the last step
    boundary within 5 rows of its start, and takes at least one step."""
    step_ptr = np.array([0, 3, 3, 10, 12, 20])
    assert step_pieces(step_ptr, 5) == [(0, 2), (2, 3), (3, 4), (4, 5)]
    assert step_pieces(step_ptr, 100) == [(0, 5)]
    assert step_pieces(np.array([0]), 5) == []


def contiguous_nodes(rng: np.random.Generator) -> pl.DataFrame:
    """60 tracks, each present over a run of consecutive steps of 40, on 300 m of road."""
    rows = []
    for track in range(60):
        first = int(rng.integers(0, 35))
        for step in range(first, first + int(rng.integers(1, 41 - first))):
            x, y = float(rng.uniform(0, 15)), float(rng.uniform(0, 300))
            rows.append((step, track, track + 1, x, y, 0.0, 10.0))
    return grid_table(rows)


@pytest.mark.parametrize("rows_per_piece", [1, 37, 400])
def test_pairs_a_piece_of_steps_at_a_time_are_the_pairs_of_all_steps(rows_per_piece: int) -> None:
    nodes = contiguous_nodes(np.random.default_rng(rows_per_piece))
    whole = recording_arrays(nodes, 25.0)
    indexed = node_arrays(nodes)
    pieces = [
        with_pairs(indexed, first, end, 25.0)
        for first, end in step_pieces(indexed.step_ptr, rows_per_piece)
    ]
    assert len(pieces) > 1 or rows_per_piece == 400
    assert whole.pair_rows.shape[0] > 100
    for name in ("pair_rows", "pair_dist", "pair_key"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(p, name) for p in pieces]), getattr(whole, name)
        )
    np.testing.assert_array_equal(sum(p.pair_ptr for p in pieces), whole.pair_ptr)


@pytest.mark.parametrize("steps", [3, 200])
def test_pairs_are_ordered_as_a_stable_sort_of_their_float_keys(steps: int) -> None:
    """with_pairs orders pairs by ranks of their lower rows' keys (16-bit ranks for a few
    steps, 64-bit beyond 65,536 rows): the order of a stable sort of the keys themselves, ties
    (vehicles side by side, a vehicle lower in several pairs) in the table's order (step,
    track_a, track_b)."""
    rng = np.random.default_rng(steps)
    rows = []
    for step in range(steps):
        y = np.round(rng.uniform(0, 400, 350) * 64) / 64  # many equal y
        x = 1.8 + 3.6 * rng.integers(0, 5, 350)
        for track, (px, py) in enumerate(zip(x.tolist(), y.tolist(), strict=True)):
            rows.append((step, track, track + 1000, px, py, 0.0, 10.0))
    nodes = grid_table(rows)
    rec = recording_arrays(nodes, 10.0)
    pairs = pair_table(rec)
    row_of = {(st, tr): i for i, (st, tr) in enumerate(nodes.select(s.STEP, s.TRACK_ID).rows())}
    y = nodes[s.Y_M].to_numpy()
    low, high = [], []
    for step, a, b in pairs.select(s.STEP, s.TRACK_A, s.TRACK_B).rows():
        ra, rb = row_of[(step, a)], row_of[(step, b)]
        low.append(ra if y[ra] <= y[rb] else rb)
        high.append(rb if y[ra] <= y[rb] else ra)
    key = pairs[s.STEP].to_numpy().astype(np.float64) * PAIR_KEY_STEP + y[low]
    order = np.argsort(key, kind="stable")
    assert (len(nodes) > 2**16) == (steps == 200) and len(np.unique(key)) < len(key) / 2
    np.testing.assert_array_equal(rec.pair_rows, np.stack([low, high], axis=1)[order])
    np.testing.assert_array_equal(rec.pair_key, key[order])


@pytest.mark.parametrize("track_span", [1_000, 100_000, 2**22, 2**32 - 100])
def test_the_pairs_table_order_is_by_step_and_tracks_in_every_range(track_span: int) -> None:
    """Three 16-bit radix passes (tracks of a range of steps) or 64-bit sorts (wider spans of
    track ids, up to all of int32's range): the one order of (step, track_a, track_b)."""
    rng = np.random.default_rng(track_span)
    step = rng.integers(10, 60, 5_000)
    track_a = rng.integers(0, track_span, 5_000) - (2**31 if track_span > 2**31 else 0)
    track_b = track_a + rng.integers(1, 50, 5_000)
    triples = np.unique(np.stack([step, track_a, track_b], axis=1), axis=0)
    shuffled = triples[rng.permutation(len(triples))]
    step, track_a, track_b = (shuffled[:, k].astype(np.int32) for k in range(3))
    order = grid._lex_order(step, track_a, track_b)
    np.testing.assert_array_equal(shuffled[order], triples)


def tracks_of(nodes: pl.DataFrame, first_track_id: int = 0) -> pl.LazyFrame:
    """A tracks table that `nodes` are the grid nodes of, its rows shuffled: nothing may rely on
    the tracks table's own order."""
    return (
        nodes.with_columns(
            (pl.col(s.STEP) * 0.2).alias(s.TIME_S), pl.col(s.TRACK_ID) + first_track_id
        )
        .drop(s.STEP)
        .sample(fraction=1.0, shuffle=True, seed=5)
        .lazy()
    )


@pytest.mark.parametrize("rows_per_piece", [1, 37, 10_000])
def test_node_arrays_written_a_range_of_steps_at_a_time_are_the_node_arrays(
    rows_per_piece: int,
) -> None:
    """The rows of each range given to `write` in step order, the indexes returned whole: the
    arrays of all grid nodes at once (track ids from 7 here), but for the rows' arrays, empty."""
    nodes = contiguous_nodes(np.random.default_rng(rows_per_piece))
    expected = node_arrays(grid_nodes(tracks_of(nodes, 7).collect(), 0.2))
    written: list[dict[str, np.ndarray]] = []
    indexed = write_node_arrays(tracks_of(nodes, 7), 0.2, rows_per_piece, written.append)
    assert len(written) == 1 + len(step_pieces(expected.step_ptr, rows_per_piece))
    assert len(written) > 3 or rows_per_piece == 10_000
    assert indexed.first_track_id == expected.first_track_id == 7
    for name in ARRAY_NAMES:
        if name in ROW_ARRAYS:
            assert len(getattr(indexed, name)) == 0
            whole = np.concatenate([part[name] for part in written])
            assert whole.dtype == getattr(expected, name).dtype
            np.testing.assert_array_equal(whole, getattr(expected, name))
        else:
            assert getattr(indexed, name).dtype == getattr(expected, name).dtype, name
            np.testing.assert_array_equal(getattr(indexed, name), getattr(expected, name))


def test_node_arrays_of_no_rows_are_written_empty() -> None:
    written: list[dict[str, np.ndarray]] = []
    empty = grid_table([])
    indexed = write_node_arrays(tracks_of(empty), 0.2, 100, written.append)
    expected = node_arrays(empty)
    assert [part["node_state"].shape for part in written] == [(0, 4)]
    for name in ARRAY_NAMES:
        if name not in ROW_ARRAYS:
            np.testing.assert_array_equal(getattr(indexed, name), getattr(expected, name))


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([(0, 0, 1, 0.0, 0.0, 0.0, 1.0), (0, 2, 3, 0.0, 9.0, 0.0, 1.0)], "not consecutive"),
        ([(0, 0, 1, 0.0, 0.0, 0.0, 1.0), (2, 0, 1, 0.0, 9.0, 0.0, 1.0)], "not one row at each"),
        ([(0, 0, 1, 0.0, 0.0, 0.0, 1.0), (0, 0, 1, 0.0, 9.0, 0.0, 1.0)], "not one row at each"),
        (
            [(0, 0, 1, 0.0, 0.0, 0.0, 1.0), (0, 0, 1, 0.0, 9.0, 0.0, 1.0)]
            + [(2, 0, 1, 0.0, 9.0, 0.0, 1.0)],
            "not one row at each",
        ),
    ],
)
def test_tracks_that_break_the_contract_are_refused(rows: list[tuple], message: str) -> None:
    """Track ids 0 and 2; a track at steps 0 and 2 only; a track twice at one step; a track
    twice at step 0 and at step 2 (as many rows as steps from its first to its last)."""
    with pytest.raises(ValueError, match=message):
        write_node_arrays(tracks_of(grid_table(rows)), 0.2, 100, lambda _: None)
