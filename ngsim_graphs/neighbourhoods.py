"""What every sample's graph holds, counted without inducing it (SPEC section 3).

A sample's graph is, step by step, the neighbourhood of its ego's row: the rows within d_sense
of it (the nodes), the proximity pairs among them (the actor-actor edges) and the tracks still
near at the next step (the temporal edges). So each grid row that is some ego's history row is
looked at once, and a sample's counts and its share of the scaler's ranges are sums, minima and
maxima over its K_H ego rows. Under the cs-lstm protocol a row is in up to K_H samples'
histories; `induce_graphs` would see it that many times.

Every decision is `induce_graphs`' own: the same distance formula with the same arguments against
the same thresholds, the same pair search along y. The counts and ranges are therefore exactly
what the induced graphs give (tests/test_neighbourhoods.py compares them on random scenes).
Minima and maxima of positions in the sample frame follow from those in the world frame because
subtracting the ego's position rounds monotonically: min(x_i - o) == min(x_i) - o in float64.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import polars as pl

from ngsim_graphs.config import BuildConfig
from ngsim_graphs.graphs import SEARCH_MARGIN_M, NonFiniteStateError, concat_ranges
from ngsim_graphs.grid import RecordingArrays, pair_search_key
from ngsim_graphs.scaling import FEATURES, SCALED, MinMaxScaler
from ngsim_graphs.schema import Protocol

ROWS_PER_CHUNK = 1_024  # ego rows looked at together: their pair candidates stay ~25 MB
SAMPLES_PER_CHUNK = 65_536  # samples summed up together (cs-lstm: a million in a recording)


@dataclass(frozen=True)
class Neighbourhoods:
    """What the graph of each given ego row holds at its step (U ego rows, sorted).

    low and high are the minima and maxima of SCALED: x, y (world frame), heading and speed over
    the nodes, the ego included; distance over the spatial edges (inf and -inf without any).
    """

    rows: np.ndarray  # (U,) int64 every ego row of the samples, ascending
    nodes: np.ndarray  # (U,) int64 rows within d_sense of the ego, the ego included
    actor_pairs: np.ndarray  # (U,) int64 proximity pairs of two of those rows, neither the ego
    kept: np.ndarray  # (U,) int64 tracks of those rows still within d_sense at the next step
    full_future: np.ndarray  # (U,) int64 of those rows but the ego, tracks with all K_F steps after
    ego_full_future: np.ndarray  # (U,) bool the ego's track has all K_F steps after
    low: np.ndarray  # (U, 5) float64 in SCALED order
    high: np.ndarray  # (U, 5) float64 in SCALED order


def history_rows(
    rec: RecordingArrays, ego_track: np.ndarray, start_step: np.ndarray, config: BuildConfig
) -> np.ndarray:
    """(B, K_H) int32 row of each sample's ego at each history step; -1 where it has none.

    The ego must be present at the present step, and under the aigem protocol at every step (the
    same checks, and messages, as `induce_graphs`)."""
    k_h = config.history_steps
    rows = np.empty((len(ego_track), k_h), np.int32)
    for part in _sample_chunks(len(ego_track)):
        steps = (start_step[part, None] + np.arange(k_h)).reshape(-1)
        rows[part] = rec.row_at(np.repeat(ego_track[part], k_h), steps).reshape(-1, k_h)
    if not (rows[:, -1] >= 0).all():
        raise ValueError("an ego track is not present at the present step of its window")
    if config.protocol is Protocol.AIGEM and not (rows >= 0).all():
        raise ValueError("an ego track is not present at every history step of its window")
    return rows


def _sample_chunks(n_samples: int) -> list[slice]:
    """Samples SAMPLES_PER_CHUNK at a time: (chunk, K_H) temporaries stay small."""
    return [slice(i, i + SAMPLES_PER_CHUNK) for i in range(0, n_samples, SAMPLES_PER_CHUNK)]


def _distance(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """graphs._distance of rows a and b, in that order: sqrt(dx * dx + dy * dy), float64."""
    dx, dy = xy[a, 0] - xy[b, 0], xy[a, 1] - xy[b, 1]
    return np.sqrt(dx * dx + dy * dy)


def _window(
    keys: np.ndarray, rec: RecordingArrays, egos: np.ndarray, step: np.ndarray, d_sense_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index): the entries of `keys` (pair_search_key order) within d_sense and a margin
    of each ego along y, at its step, as `induce_graphs` searches them."""
    ego_y = rec.node_state[egos, 1]
    reach = d_sense_m + SEARCH_MARGIN_M
    lo = np.searchsorted(keys, pair_search_key(step, ego_y - reach), "left")
    hi = np.searchsorted(keys, pair_search_key(step, ego_y + reach), "right")
    return concat_ranges(lo, hi)


def _reduce(ufunc: np.ufunc, values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """ufunc over each run of `values` that starts at `starts` (ascending, no run empty)."""
    return ufunc.reduceat(values, starts) if len(starts) else values[:0]


def _runs(
    ufunc: np.ufunc, values: np.ndarray, lengths: np.ndarray, empty: float, dtype=np.float64
) -> np.ndarray:
    """ufunc over consecutive runs of `values` of the given lengths; `empty` for an empty run."""
    out = np.full(len(lengths), empty, dtype=dtype)
    filled = lengths > 0
    out[filled] = _reduce(ufunc, values, (np.cumsum(lengths) - lengths)[filled])
    return out


@dataclass(frozen=True)
class _Near:
    """The rows near each ego row of a chunk, the ego included (runs by ego, in row order)."""

    owner: np.ndarray  # (C,) index of the ego row in the chunk
    row: np.ndarray  # (C,) int64
    distance: np.ndarray  # (C,) float64 to the ego


def _near_rows(rec: RecordingArrays, by_y: tuple, egos: np.ndarray, step: np.ndarray, d_sense_m):
    """The rows within d_sense of each ego row, found along y in the rows sorted by (step, y)."""
    order, keys = by_y
    owner, index = _window(keys, rec, egos, step, d_sense_m)
    rows = order[index]
    distance = _distance(rec.node_state, rows, egos[owner])
    near = distance <= d_sense_m  # finite: `rows_by_y` checked every position
    return _Near(owner[near], rows[near], distance[near])


def _actor_pairs(
    rec: RecordingArrays,
    near: _Near,
    actor: np.ndarray,
    egos: np.ndarray,
    step: np.ndarray,
    d_sense_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count, minimum and maximum distance of the proximity pairs among each ego row's actors
    (`actor`: which near rows are not the ego).

    The pairs searched as `induce_graphs` searches them, kept where both are actors. Which rows
    are actors is a small (ego, row of its step) table: a lookup, not a distance, per pair."""
    width = int(np.diff(rec.step_ptr).max()) if rec.n_steps else 0
    # Row r of ego i's step is entry i * width + r - (first row of the step) of `is_actor`.
    offset = np.arange(len(egos)) * width - rec.step_ptr[step]
    is_actor = np.zeros(len(egos) * width, bool)
    is_actor[offset[near.owner[actor]] + near.row[actor]] = True
    owner, index = _window(rec.pair_key, rec, egos, step, d_sense_m)
    pairs = np.take(rec.pair_rows, index, axis=0)  # (C, 2); faster than fancy indexing
    pair_offset = offset[owner]
    keep = is_actor[pairs[:, 0] + pair_offset] & is_actor[pairs[:, 1] + pair_offset]
    distance = rec.pair_dist[index]  # float32: its minimum and maximum are exact as float64
    lengths = np.bincount(owner, minlength=len(egos))  # pairs searched per ego, in runs
    return (
        _runs(np.add, keep.astype(np.int32), lengths, 0, np.int64),
        _runs(np.minimum, np.where(keep, distance, np.inf), lengths, np.inf),
        _runs(np.maximum, np.where(keep, distance, -np.inf), lengths, -np.inf),
    )


def _chunk(
    rec: RecordingArrays, by_y: tuple, egos: np.ndarray, row_step: np.ndarray, config: BuildConfig
) -> tuple[np.ndarray, ...]:
    """The Neighbourhoods fields (but rows) of one chunk of ego rows."""
    d_sense = config.d_sense_m
    near = _near_rows(rec, by_y, egos, row_step, d_sense)
    nodes = np.bincount(near.owner, minlength=len(egos))  # every ego is near itself: no 0
    starts = np.cumsum(nodes) - nodes
    actor = near.row != egos[near.owner]

    # Temporal edges: a near track's row at the next step, near the ego's row at the next step.
    next_row = rec.row_at(rec.node_track[near.row], row_step[near.owner] + 1)
    ego_next = rec.row_at(rec.node_track[egos], row_step + 1)
    both = (next_row >= 0) & (ego_next[near.owner] >= 0)
    still = np.zeros(len(near.row), bool)
    still[both] = _distance(rec.node_state, next_row[both], ego_next[near.owner][both]) <= d_sense
    kept = np.bincount(near.owner[still], minlength=len(egos))

    first, count = rec.track_steps(rec.node_track[near.row])
    full = first + count - 1 >= row_step[near.owner] + config.future_steps
    full_future = np.bincount(near.owner[full & actor], minlength=len(egos))
    ego_first, ego_count = rec.track_steps(rec.node_track[egos])
    ego_full = ego_first + ego_count - 1 >= row_step + config.future_steps

    state = np.take(rec.node_state, near.row, axis=0)
    low = np.empty((len(egos), len(SCALED)))
    high = np.empty((len(egos), len(SCALED)))
    low[:, : len(FEATURES)] = _reduce(np.minimum, state, starts)
    high[:, : len(FEATURES)] = _reduce(np.maximum, state, starts)
    ego_low = _reduce(np.minimum, np.where(actor, near.distance, np.inf), starts)
    ego_high = _reduce(np.maximum, np.where(actor, near.distance, -np.inf), starts)
    actor_pairs, pair_low, pair_high = _actor_pairs(rec, near, actor, egos, row_step, d_sense)
    low[:, -1] = np.minimum(ego_low, pair_low)
    high[:, -1] = np.maximum(ego_high, pair_high)
    return nodes, actor_pairs, kept, full_future, ego_full, low, high


def ego_rows(history: np.ndarray, n_rows: int) -> np.ndarray:
    """Every row of (B, K_H) `history_rows` once, ascending (int64)."""
    used = np.zeros(n_rows, bool)
    for part in _sample_chunks(len(history)):
        rows = history[part]
        used[rows[rows >= 0]] = True
    return np.flatnonzero(used)


def rows_by_y(
    rec: RecordingArrays, first: int = 0, end: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(order, keys): the grid rows of steps [first, end) (all steps by default) sorted by
    (step, y), and their pair_search_key: the search along y of the neighbours of each ego row
    of those steps."""
    end = rec.n_steps if end is None else end
    lo, hi = int(rec.step_ptr[first]), int(rec.step_ptr[end])
    position = rec.node_state[lo:hi, :2]
    if not np.isfinite(position).all():  # such a row would fall out of every search
        raise NonFiniteStateError("positions that are not finite")
    steps = np.repeat(np.arange(first, end), np.diff(rec.step_ptr[first : end + 1]))
    keys = pair_search_key(steps, position[:, 1])
    order = np.argsort(keys, kind="stable")
    return lo + order, keys[order]


def neighbourhoods(
    rec: RecordingArrays, history: np.ndarray, config: BuildConfig
) -> Neighbourhoods:
    """The neighbourhood of every ego row of (B, K_H) `history_rows`, each looked at once, with
    all of the recording's pairs in `rec` (a build takes a range of steps at a time: tasks)."""
    by_y = rows_by_y(rec)
    return neighbourhoods_of_rows(rec, ego_rows(history, len(rec.node_track)), by_y, config)


def neighbourhoods_of_rows(
    rec: RecordingArrays, rows: np.ndarray, by_y: tuple[np.ndarray, np.ndarray], config: BuildConfig
) -> Neighbourhoods:
    """The neighbourhoods of the given ego `rows` (ascending), ROWS_PER_CHUNK at a time.

    `rec` needs the pairs of the rows' steps only (`grid.with_pairs` of a range of steps);
    `by_y` is `rows_by_y(rec)`."""
    row_step = np.searchsorted(rec.step_ptr, rows, "right") - 1
    n = len(rows)
    hood = Neighbourhoods(
        rows=rows,
        nodes=np.empty(n, np.int64),
        actor_pairs=np.empty(n, np.int64),
        kept=np.empty(n, np.int64),
        full_future=np.empty(n, np.int64),
        ego_full_future=np.empty(n, bool),
        low=np.empty((n, len(SCALED))),
        high=np.empty((n, len(SCALED))),
    )

    def fill(part: slice) -> None:
        values = _chunk(rec, by_y, rows[part], row_step[part], config)
        for name, value in zip(_FIELDS, values, strict=True):
            getattr(hood, name)[part] = value

    # numpy lets go of the GIL in its loops over large arrays: chunks run in parallel on as many
    # threads as Polars may use in this process (a build worker's share of the cores).
    parts = [slice(i, i + ROWS_PER_CHUNK) for i in range(0, n, ROWS_PER_CHUNK)]
    with ThreadPoolExecutor(max(1, min(pl.thread_pool_size(), len(parts)))) as threads:
        list(threads.map(fill, parts))
    return hood


_FIELDS = ("nodes", "actor_pairs", "kept", "full_future", "ego_full_future", "low", "high")


def _positions(hood: Neighbourhoods, history: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(held, at): which history rows `hood` holds (present rows of its range of steps), and
    their index in hood.rows (0 where not held)."""
    if len(hood.rows) == 0:
        return np.zeros(history.shape, bool), np.zeros(history.shape, np.int64)
    at = np.minimum(np.searchsorted(hood.rows, history), len(hood.rows) - 1)
    held = (history >= 0) & (hood.rows[at] == history)
    return held, np.where(held, at, 0)


def row_bounds(history: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, last): each sample's lowest and highest present row of (B, K_H) `history_rows`
    (its present row is the last): the ranges of steps whose neighbourhoods it needs."""
    first = np.empty(len(history), history.dtype)
    for part in _sample_chunks(len(history)):
        rows = history[part]
        first[part] = np.where(rows >= 0, rows, np.iinfo(history.dtype).max).min(axis=1)
    return first, history[:, -1].copy()


def sample_counts(hood: Neighbourhoods, history: np.ndarray, config: BuildConfig) -> np.ndarray:
    """(B, 5) int64 per sample, in schema.COUNT_COLUMNS order: nodes, spatial edges, temporal
    edges, targets, targets with a full future, from its (B, K_H) `history_rows`.

    Only the rows `hood` holds count (the targets: if it holds the present row): the counts of
    the neighbourhoods of consecutive ranges of steps add up to those of all at once."""
    counts = np.empty((len(history), 5), np.int64)
    for part in _sample_chunks(len(history)):
        counts[part] = _counts(hood, history[part], config)
    return counts


def _counts(hood: Neighbourhoods, history: np.ndarray, config: BuildConfig) -> np.ndarray:
    present, at = _positions(hood, history)
    if len(hood.rows) == 0:
        return np.zeros((len(history), 5), np.int64)
    nodes = np.where(present, hood.nodes[at], 0)
    spatial = 2 * (nodes - present) + 2 * np.where(present, hood.actor_pairs[at], 0)
    temporal = np.where(present, hood.kept[at], 0)[:, :-1]  # from each step to the next
    now, held = at[:, -1], present[:, -1]
    if config.protocol is Protocol.CS_LSTM:
        targets = held.astype(np.int64)
        full = (hood.ego_full_future[now] & held).astype(np.int64)
    else:
        ego = int(config.ego_is_target)
        targets = np.where(held, hood.nodes[now] - 1 + ego, 0)
        full = np.where(held, hood.full_future[now] + ego * hood.ego_full_future[now], 0)
    return np.stack(
        [nodes.sum(axis=1), spatial.sum(axis=1), temporal.sum(axis=1), targets, full], axis=1
    )


def train_ranges(
    rec: RecordingArrays, hood: Neighbourhoods, history: np.ndarray, is_train: np.ndarray
) -> MinMaxScaler:
    """The minima and maxima of SCALED over the graphs of the train samples (`is_train`, (B,)
    bool) as a scaler: x and y in each sample's frame, with its present ego at (0, 0).

    Only the rows `hood` holds count: the scalers of the neighbourhoods of consecutive ranges of
    steps, joined, are that of all at once (a minimum of minima; the ego's frame is a
    subtraction, which rounds monotonically)."""
    if len(hood.rows) == 0:
        return MinMaxScaler.empty()
    low, high = dict.fromkeys(SCALED, np.inf), dict.fromkeys(SCALED, -np.inf)
    used = np.zeros(len(hood.rows), bool)
    train = np.flatnonzero(is_train)
    for part in _sample_chunks(len(train)):
        rows = history[train[part]]
        present, at = _positions(hood, rows)
        origin = np.take(rec.node_state, rows[:, -1], axis=0)
        for i, name in enumerate(SCALED[:2]):
            sample_low = np.where(present, hood.low[at, i], np.inf).min(axis=1)
            sample_high = np.where(present, hood.high[at, i], -np.inf).max(axis=1)
            low[name] = min(low[name], (sample_low - origin[:, i]).min())
            high[name] = max(high[name], (sample_high - origin[:, i]).max())
        used[at[present]] = True
    for i, name in enumerate(SCALED[2:], start=2):
        low[name] = hood.low[used, i].min(initial=np.inf)
        high[name] = hood.high[used, i].max(initial=-np.inf)
    return MinMaxScaler(
        {n: float(v) for n, v in low.items()}, {n: float(v) for n, v in high.items()}
    )
