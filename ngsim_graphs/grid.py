"""Per-recording frame data that every sample's graph is induced from.

Two things per recording, both on the 0.2 s grid:
- the grid nodes: every track at every step, sorted by (step, track), with an index by step and
  an index by track (`RecordingArrays`, the memory-mappable form the dataset opens);
- the proximity pairs: every pair of vehicles at most d_max apart (the build's `d_min_m`), found
  once per step by a sweep along y, instead of once per sample that sees them.

Distances everywhere are `sqrt(dx * dx + dy * dy)` in float64 over world positions in metres, the
same formula in the fast path and in the tests' brute-force reference, so that a distance exactly
at a threshold is decided alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace

import numpy as np
import polars as pl

from ngsim_graphs import schema as s

STATE_COLUMNS = (s.X_M, s.Y_M, s.HEADING_RAD, s.SPEED_MPS)  # node_state's columns, in order


@dataclass(frozen=True)
class RecordingArrays:
    """One recording's grid nodes and proximity edges as flat arrays (CSR indexes).

    Rows are grid nodes sorted by (step, track). Steps run 0..S-1 (time_s / time_step_s);
    tracks run first_track_id..first_track_id+T-1 and are contiguous in steps.
    """

    step_ptr: np.ndarray  # (S+1,) int64: rows of step s are step_ptr[s]:step_ptr[s+1]
    node_track: np.ndarray  # (N,) int32 track id of each row
    node_state: np.ndarray  # (N, 4) float64 [x_m, y_m, heading_rad, speed_mps], world frame
    track_first_step: np.ndarray  # (T,) int32 first grid step of each track
    track_ptr: np.ndarray  # (T+1,) int64: rows of track t (in step order) in track_rows[...]
    track_rows: np.ndarray  # (N,) int32 row indices grouped by track, in step order
    pair_ptr: np.ndarray  # (S+1,) int64: proximity pairs of step s
    pair_rows: np.ndarray  # (P, 2) int32 rows of the two vehicles, the one with lower y first
    pair_dist: np.ndarray  # (P,) float32 distance, metres
    pair_key: np.ndarray  # (P,) float64 step * PAIR_KEY_STEP + y of the lower vehicle, ascending
    first_track_id: int

    @property
    def n_steps(self) -> int:
        return len(self.step_ptr) - 1

    def track_steps(self, track_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(first step, number of steps) of each given track id."""
        local = track_ids - self.first_track_id
        return self.track_first_step[local], np.diff(self.track_ptr)[local]

    def row_steps(self, first: int, end: int) -> np.ndarray:
        """(step_ptr[end] - step_ptr[first],) int64: the step of each row of steps [first, end)."""
        return np.repeat(np.arange(first, end), np.diff(self.step_ptr[first : end + 1]))

    def row_at(self, track_ids: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Row of each (track, step); -1 where the track has no row at that step."""
        first, count = self.track_steps(track_ids)
        offset = steps - first
        inside = (offset >= 0) & (offset < count)
        local = track_ids - self.first_track_id
        safe = np.where(inside, self.track_ptr[local] + offset, 0)
        return np.where(inside, self.track_rows[safe], -1)


# Pairs are ordered by (step, y of their lower vehicle) so that the pairs near an ego are one
# contiguous range; the key folds both into one sortable number (|y| < PAIR_KEY_STEP / 2).
PAIR_KEY_STEP = 1.0e5


def pair_search_key(step: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """The sort key of a pair whose lower vehicle is at `y_m`, at grid step `step`."""
    return step.astype(np.float64) * PAIR_KEY_STEP + y_m


SEARCH_MARGIN_M = 1e-3  # widening of the pair search along y, far above float rounding


def concat_ranges(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate the integer ranges [starts[i], ends[i]): returns (owner i, value) per element."""
    lengths = (ends - starts).astype(np.int64)
    owner = np.repeat(np.arange(len(starts)), lengths)
    first = np.cumsum(lengths) - lengths
    value = np.arange(int(lengths.sum()), dtype=np.int64) - np.repeat(first - starts, lengths)
    return owner, value


def y_window(
    keys: np.ndarray,
    rec: RecordingArrays,
    egos: np.ndarray,
    step: np.ndarray,
    reach_m: float,
    present: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index): the entries of `keys` (pair_search_key order) within `reach_m` and
    SEARCH_MARGIN_M of each ego row along y, at its step; none where `present` is False. The
    margin: a distance that rounds to exactly the reach may lie a float step beyond it along y;
    the distance check drops it."""
    lo, hi = y_bounds(keys, rec, egos, step, reach_m)
    return concat_ranges(lo, hi if present is None else np.where(present, hi, lo))


def y_bounds(
    keys: np.ndarray, rec: RecordingArrays, egos: np.ndarray, step: np.ndarray, reach_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), (U,) each: the entries lo..hi-1 of `keys` that `y_window` gives each ego row."""
    ego_y = rec.node_state[egos, 1]
    reach = reach_m + SEARCH_MARGIN_M
    lo = np.searchsorted(keys, pair_search_key(step, ego_y - reach), "left")
    hi = np.searchsorted(keys, pair_search_key(step, ego_y + reach), "right")
    return lo, hi


ARRAY_NAMES = tuple(f.name for f in fields(RecordingArrays) if f.name != "first_track_id")


def grid_nodes(tracks: pl.DataFrame, time_step_s: float) -> pl.DataFrame:
    """The tracks table as GRID_NODE_SCHEMA rows, sorted by (step, track).

    A row's step is its time on the grid, `time_s / time_step_s`, rounded to the nearest integer
    (the tracks table contract puts every row on the grid; see `ngsim_graphs.sources`).
    """
    return grid_node_rows(tracks.lazy(), time_step_s).collect().sort(s.STEP, s.TRACK_ID)


def grid_node_rows(tracks: pl.LazyFrame, time_step_s: float) -> pl.LazyFrame:
    """`grid_nodes` of a lazy tracks table, in the tracks' order: what a build streams."""
    step = (pl.col(s.TIME_S) / time_step_s).round().cast(pl.Int32).alias(s.STEP)
    columns = [step, *(pl.col(c) for c in s.GRID_NODE_SCHEMA.names() if c != s.STEP)]
    return tracks.select(columns).cast(dict(s.GRID_NODE_SCHEMA))


def nodes_in_steps(tracks: pl.LazyFrame, first: int, end: int, time_step_s: float) -> pl.DataFrame:
    """`grid_nodes` of the steps [first, end) of a lazy tracks table (sorted by (step, track)).

    The rows are first chosen by their time, a step wider on each side than the steps' times, so
    that a Parquet file's row groups of other times are not read; then by their step exactly."""
    near = pl.col(s.TIME_S).is_between((first - 1) * time_step_s, end * time_step_s)
    nodes = grid_node_rows(tracks.filter(near), time_step_s)
    chosen = nodes.filter(pl.col(s.STEP).is_between(first, end, closed="left"))
    return chosen.collect().sort(s.STEP, s.TRACK_ID)


def _pairs_by_sweep(step: np.ndarray, x: np.ndarray, y: np.ndarray, d_max_m: float):
    """All (i, j, distance) with equal step and distance <= d_max_m; rows sorted by (step, y).

    Row i is compared with row i + k for k = 1, 2, ... while it has a same-step row within
    d_max_m along y at that offset: beyond it, y only grows apart, so a row leaves the sweep at
    its first offset without one, and the work follows the pairs, not the rows times the
    longest reach."""
    first, second, dist = [], [], []
    active = np.arange(len(step) - 1, dtype=np.int64)  # rows with a row after them
    offset = 1
    while len(active):
        other = active + offset
        active = active[other < len(step)]
        other = other[: len(active)]
        near = (step[other] == step[active]) & (y[other] - y[active] <= d_max_m)
        active, other = active[near], other[near]
        if len(active) == 0:
            break
        dx, dy = x[other] - x[active], y[other] - y[active]
        d = np.sqrt(dx * dx + dy * dy)
        keep = d <= d_max_m
        first.append(active[keep].astype(np.int32))  # int32 rows: a third less memory
        second.append(first[-1] + np.int32(offset))
        dist.append(d[keep])
        offset += 1
    if not first:
        return np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0)
    return np.concatenate(first), np.concatenate(second), np.concatenate(dist)


def _lex_order(first: np.ndarray, second: np.ndarray, third: np.ndarray) -> np.ndarray:
    """The order by (first, second, third) of integer columns: three 16-bit radix passes where
    each column spans fewer than 2**16 values (a range of steps of `step_pieces`), 64-bit sorts
    otherwise."""
    if len(first) == 0:
        return np.empty(0, np.int64)
    # lexsort's last key sorts first; int64: a span of int32 values may not fit int32
    local = [column.astype(np.int64) - column.min() for column in (third, second, first)]
    if all(int(column.max()) < 2**16 for column in local):
        return np.lexsort([column.astype(np.uint16) for column in local])
    return np.lexsort(local)


def _csr_ptr(keys: np.ndarray, n_keys: int) -> np.ndarray:
    """Offsets of each key 0..n_keys-1 in an array sorted by key."""
    return np.searchsorted(keys, np.arange(n_keys + 1)).astype(np.int64)


def node_arrays(nodes: pl.DataFrame) -> RecordingArrays:
    """Index the grid nodes by step and by track; the pair arrays are left empty (`with_pairs`)."""
    step = nodes[s.STEP].to_numpy()
    track = nodes[s.TRACK_ID].to_numpy()
    n_steps = int(step.max()) + 1 if len(step) else 0
    first_track = int(track.min()) if len(track) else 0
    local_track = track - first_track
    n_tracks = int(local_track.max()) + 1 if len(track) else 0
    by_track = np.lexsort((step, local_track)).astype(np.int32)
    track_ptr = _csr_ptr(local_track[by_track], n_tracks)
    track_first_step = step[by_track[track_ptr[:-1]]] if n_tracks else np.empty(0, np.int32)
    return RecordingArrays(
        step_ptr=_csr_ptr(step, n_steps),
        **_row_arrays(nodes),
        track_first_step=track_first_step.astype(np.int32),
        track_ptr=track_ptr,
        track_rows=by_track,
        pair_ptr=np.zeros(n_steps + 1, np.int64),
        pair_rows=np.empty((0, 2), np.int32),
        pair_dist=np.empty(0, np.float32),
        pair_key=np.empty(0, np.float64),
        first_track_id=first_track,
    )


# The fields of RecordingArrays that hold a value per grid row in (step, track) order: a build
# writes them a range of steps at a time (`write_node_arrays`).
ROW_ARRAYS = ("node_track", "node_state")


def write_node_arrays(
    tracks: pl.LazyFrame,
    time_step_s: float,
    rows_per_piece: int,
    write: Callable[[dict[str, np.ndarray]], None],
) -> RecordingArrays:
    """`node_arrays` of a lazy tracks table, made a range of steps at a time (`step_pieces`):
    never every grid row at once.

    The ROW_ARRAYS of each range are given to `write`, in step order (their concatenation is
    `node_arrays`' own); the arrays returned hold them with no row, and every other index whole
    (a number or two per step, track or row). Each track must be numbered next to the last and
    have a row at every step from its first to its last, as the tracks table contract says.
    """
    nodes = grid_node_rows(tracks, time_step_s)
    counts = nodes.group_by(s.STEP).len().collect(engine="streaming")
    per_track = (
        nodes.group_by(s.TRACK_ID)
        .agg(pl.col(s.STEP).min().alias("first"), pl.col(s.STEP).max().alias("last"), pl.len())
        .sort(s.TRACK_ID)
        .collect(engine="streaming")
    )
    step, track = counts[s.STEP].to_numpy(), per_track[s.TRACK_ID].to_numpy()
    if len(step) and step.min() < 0:
        raise ValueError(f"a grid step below 0: {int(step.min())}")
    first_track = int(track[0]) if len(track) else 0
    first, steps = per_track["first"].to_numpy(), per_track["len"].to_numpy().astype(np.int64)
    if not (np.array_equal(track, first_track + np.arange(len(track)))):
        raise ValueError("the track ids of a recording are not consecutive")
    one_row_a_step = "a track has not one row at each step from its first to its last"
    if not np.array_equal(per_track["last"].to_numpy() - first + 1, steps):
        raise ValueError(one_row_a_step)
    per_step = np.zeros(int(step.max()) + 1 if len(step) else 0, np.int64)
    per_step[step] = counts["len"].to_numpy()
    step_ptr = np.concatenate([np.zeros(1, np.int64), np.cumsum(per_step)])
    track_ptr = np.concatenate([np.zeros(1, np.int64), np.cumsum(steps)])
    track_rows = np.full(int(step_ptr[-1]), -1, np.int32)
    empty = node_arrays(nodes.head(0).collect())
    write({name: getattr(empty, name) for name in ROW_ARRAYS})  # a recording without rows too
    for piece_first, piece_end in step_pieces(step_ptr, rows_per_piece):
        piece = nodes_in_steps(tracks, piece_first, piece_end, time_step_s)
        lo, hi = int(step_ptr[piece_first]), int(step_ptr[piece_end])
        if piece.height != hi - lo:  # the rows read are the rows counted
            raise ValueError(f"steps {piece_first}-{piece_end}: {piece.height} rows, not {hi - lo}")
        local = piece[s.TRACK_ID].to_numpy() - first_track
        at = track_ptr[local] + piece[s.STEP].to_numpy() - first[local]
        track_rows[at] = np.arange(lo, hi, dtype=np.int32)
        write(_row_arrays(piece))
        del piece, local, at  # before the next range is read
    if (track_rows < 0).any():  # a step twice and one missing: as many rows as steps
        raise ValueError(one_row_a_step)
    return replace(
        empty,
        step_ptr=step_ptr,
        track_first_step=first.astype(np.int32),
        track_ptr=track_ptr,
        track_rows=track_rows,
        pair_ptr=np.zeros(len(step_ptr), np.int64),
        first_track_id=first_track,
    )


def _row_arrays(nodes: pl.DataFrame) -> dict[str, np.ndarray]:
    """The ROW_ARRAYS of grid nodes sorted by (step, track)."""
    state = nodes.select(STATE_COLUMNS).to_numpy().astype(np.float64)
    return {
        "node_track": nodes[s.TRACK_ID].to_numpy().astype(np.int32),
        "node_state": np.ascontiguousarray(state),
    }


def with_pairs(rec: RecordingArrays, first: int, end: int, d_max_m: float) -> RecordingArrays:
    """`rec` with the pair arrays of the proximity pairs of steps [first, end): every pair of
    rows of a step at most `d_max_m` apart, once, the one with the lower y first (the lower track
    at equal y), sorted by (step, lower y) and, at equal keys, by their tracks (lower, higher).

    Pieces of consecutive ranges of steps (`step_pieces`), their arrays concatenated and their
    pair_ptr summed, are the pairs of all their steps at once."""
    lo, hi = int(rec.step_ptr[first]), int(rec.step_ptr[end])
    step = rec.row_steps(first, end)
    x, y = rec.node_state[lo:hi, 0], rec.node_state[lo:hi, 1]
    by_y = np.lexsort((y, step))  # (step, y, track): the rows are in (step, track) order
    i, j, distance = _pairs_by_sweep(step[by_y], x[by_y], y[by_y], d_max_m)
    low, high = by_y[i], by_y[j]  # rows from lo: i comes before j in (step, y, track) order
    del i, j  # a dense recording has ten million pairs: hold few copies at a time
    # The pairs' keys ranked among the rows' (equal keys, equal ranks; 16 bits for a range of
    # steps of `step_pieces`): a radix sort of the ranks, not a sort of the float keys.
    key = pair_search_key(step, y)
    sorted_key = key[by_y]
    rank = np.empty(hi - lo, np.uint16 if hi - lo <= 2**16 else np.int64)
    rank[by_y] = np.concatenate([[0], np.cumsum(sorted_key[1:] != sorted_key[:-1])])
    tracks = rec.node_track[lo:hi]
    track_low, track_high = tracks[low], tracks[high]
    order = _lex_order(
        rank[low], np.minimum(track_low, track_high), np.maximum(track_low, track_high)
    )
    del track_low, track_high
    low, high = low[order], high[order]
    return replace(
        rec,
        pair_ptr=_csr_ptr(step[low], rec.n_steps),
        pair_rows=np.stack([low + lo, high + lo], axis=1).astype(np.int32),
        pair_dist=distance.astype(np.float32)[order],
        pair_key=key[low],
    )


def pair_table(rec: RecordingArrays) -> pl.DataFrame:
    """The pairs of `rec`'s pair arrays as a table (PROXIMITY_SCHEMA: the lower track id first;
    sorted by step, track_a, track_b), their distances the arrays' float32 values."""
    steps = np.repeat(np.arange(rec.n_steps, dtype=np.int32), np.diff(rec.pair_ptr))
    tracks = np.take(rec.node_track, rec.pair_rows)  # (P, 2)
    columns = {
        s.STEP: steps,
        s.TRACK_A: tracks.min(axis=1),
        s.TRACK_B: tracks.max(axis=1),
        s.DISTANCE_M: np.asarray(rec.pair_dist, np.float64),
    }
    order = _lex_order(columns[s.STEP], columns[s.TRACK_A], columns[s.TRACK_B])
    return pl.DataFrame(
        {name: values[order] for name, values in columns.items()}, schema=s.PROXIMITY_SCHEMA
    )


def recording_arrays(nodes: pl.DataFrame, d_max_m: float) -> RecordingArrays:
    """Index the grid nodes by step and by track, and their proximity pairs by step, as flat
    arrays (all steps at once: a build takes them a range of steps at a time, see tasks)."""
    indexed = node_arrays(nodes)
    return with_pairs(indexed, 0, indexed.n_steps, d_max_m)


def step_pieces(step_ptr: np.ndarray, rows_per_piece: int) -> list[tuple[int, int]]:
    """Consecutive ranges of steps [first, end) that cover every step, each of about
    `rows_per_piece` grid rows (at least one step): a recording's pairs a piece at a time."""
    n_steps = len(step_ptr) - 1
    pieces, first = [], 0
    while first < n_steps:
        target = step_ptr[first] + max(1, rows_per_piece)
        end = int(np.searchsorted(step_ptr, target, "right")) - 1
        end = min(max(end, first + 1), n_steps)
        pieces.append((first, end))
        first = end
    return pieces
