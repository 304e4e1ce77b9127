"""What every sample's graph holds, counted without inducing it (docs/conventions.md).

A sample's graph is, step by step, the neighbourhood of its ego's row: the rows within d_sense
of it (the nodes), and what each edge type's rule (`ngsim_graphs.edges`) gives from them. So
each grid row that is some ego's history row is looked at once, and a sample's counts and its
share of the scaler's ranges (`scaling.train_ranges`) are sums, minima and maxima over its K_H
ego rows. Under the cs-lstm protocol a row is in up to K_H samples'
histories; `induce_graphs` would see it that many times.

Every decision is `induce_graphs`' own: the same distance formula with the same arguments against
the same thresholds, the same search along y, and each edge type's count beside its induction
(`ngsim_graphs.edges`). The counts and ranges are therefore exactly what the induced graphs give
(tests/test_neighbourhoods.py compares them on random scenes). Minima and maxima of positions in
the sample frame follow from those in the world frame because subtracting the ego's position
rounds monotonically: min(x_i - o) == min(x_i) - o in float64.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ngsim_graphs import budget, edges
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.graphs import NonFiniteStateError
from ngsim_graphs.grid import STATE_COLUMNS, RecordingArrays, pair_search_key, y_window
from ngsim_graphs.schema import Protocol
from ngsim_graphs.threads import in_order


@dataclass(frozen=True)
class Neighbourhoods:
    """What the graph of each given ego row holds at its step (U ego rows, sorted).

    low and high are the minima and maxima of `ranged()`: x, y (world frame), heading and speed
    over the nodes, the ego included; each scaled edge attribute over its edges (inf and -inf
    without any).
    """

    rows: np.ndarray  # (U,) int64 every ego row of the samples, ascending
    nodes: np.ndarray  # (U,) int64 rows within d_sense of the ego, the ego included
    edges: dict[str, np.ndarray]  # by edge type: (U,) int64 its edges from the row's step
    full_future: np.ndarray  # (U,) int64 of those rows but the ego, tracks with all K_F steps after
    ego_full_future: np.ndarray  # (U,) bool the ego's track has all K_F steps after
    low: np.ndarray  # (U, len(ranged())) float64
    high: np.ndarray  # (U, len(ranged())) float64

    @cached_property
    def index_of_rows(self) -> np.ndarray:
        """(rows[-1] - rows[0] + 1,) int64: the index in `rows` of each row from rows[0] on, -1
        for a row it does not hold (a lookup: `positions` asks it for every history row)."""
        if len(self.rows) == 0:
            return np.zeros(0, np.int64)
        index = np.full(int(self.rows[-1] - self.rows[0]) + 1, -1, np.int64)
        index[self.rows - self.rows[0]] = np.arange(len(self.rows))
        return index


def ranged() -> tuple[str, ...]:
    """The quantities whose ranges a neighbourhood holds: the node state's columns, then the
    scaled edge attributes (scaling.SCALED, from the same rules)."""
    return STATE_COLUMNS + edges.scaled_attributes()


def history_rows(
    rec: RecordingArrays, ego_track: np.ndarray, start_step: np.ndarray, config: BuildConfig
) -> np.ndarray:
    """(B, K_H) int32 row of each sample's ego at each history step; -1 where it has none.

    The ego must be present at the present step, and under the aigem protocol at every step (the
    same checks, and messages, as `induce_graphs`)."""
    k_h = config.history_steps
    rows = np.empty((len(ego_track), k_h), np.int32)
    for part in sample_chunks(len(ego_track)):
        steps = (start_step[part, None] + np.arange(k_h)).reshape(-1)
        rows[part] = rec.row_at(np.repeat(ego_track[part], k_h), steps).reshape(-1, k_h)
    if not (rows[:, -1] >= 0).all():
        raise ValueError("an ego track is not present at the present step of its window")
    if config.protocol is Protocol.AIGEM and not (rows >= 0).all():
        raise ValueError("an ego track is not present at every history step of its window")
    return rows


def sample_chunks(n_samples: int) -> list[slice]:
    """Samples `budget.Budget.samples_per_chunk` at a time: (chunk, K_H) temporaries stay small."""
    size = budget.BUDGET.samples_per_chunk
    return [slice(i, i + size) for i in range(0, n_samples, size)]


def _near_rows(
    rec: RecordingArrays, by_y: tuple, egos: np.ndarray, step: np.ndarray, config: BuildConfig
) -> edges.Near:
    """The rows within d_sense of each ego row, found along y in the rows sorted by (step, y)."""
    order, keys = by_y
    owner, index = y_window(keys, rec, egos, step, config.d_sense_m)
    rows = order[index]
    xy = rec.node_state
    # graphs' distance of the row and its ego, in that order: sqrt(dx * dx + dy * dy), float64
    dx, dy = xy[rows, 0] - xy[egos[owner], 0], xy[rows, 1] - xy[egos[owner], 1]
    distance = np.sqrt(dx * dx + dy * dy)
    near = distance <= config.d_sense_m  # finite: `rows_by_y` checked every position
    owner, rows = owner[near], rows[near]
    return edges.Near(rec, config, egos, step, owner, rows, distance[near], rows != egos[owner])


def _chunk(
    rec: RecordingArrays, by_y: tuple, egos: np.ndarray, row_step: np.ndarray, config: BuildConfig
) -> dict[str, object]:
    """The Neighbourhoods fields (but rows) of one chunk of ego rows."""
    near = _near_rows(rec, by_y, egos, row_step, config)
    nodes = np.bincount(near.owner, minlength=len(egos))  # every ego is near itself: no 0
    span_first = near.span[0]
    full = near.full_futures[near.row - span_first]
    full_future = np.bincount(near.owner[full & near.actor], minlength=len(egos))
    ego_full = near.full_futures[egos - span_first]

    names = ranged()
    low = np.full((len(egos), len(names)), np.inf)
    high = np.full((len(egos), len(names)), -np.inf)
    state = np.take(rec.node_state, near.row, axis=0)
    n_state = len(STATE_COLUMNS)
    low[:, :n_state] = edges.reduce_at(np.minimum, state, near.starts)
    high[:, :n_state] = edges.reduce_at(np.maximum, state, near.starts)
    counts = {}
    for edge in edges.types_of(config.edge_types):
        row_edges = edge.count(near)
        counts[edge.name] = row_edges.count
        if edge.scaled:
            column = names.index(edge.attribute)
            low[:, column] = np.minimum(low[:, column], row_edges.low)
            high[:, column] = np.maximum(high[:, column], row_edges.high)
    return {
        "nodes": nodes,
        "edges": counts,
        "full_future": full_future,
        "ego_full_future": ego_full,
        "low": low,
        "high": high,
    }


def ego_rows(history: np.ndarray, n_rows: int) -> np.ndarray:
    """Every row of (B, K_H) `history_rows` once, ascending (int64)."""
    used = np.zeros(n_rows, bool)
    for part in sample_chunks(len(history)):
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
    steps = rec.row_steps(first, end)
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
    """The neighbourhoods of the given ego `rows` (ascending), `budget.Budget.ego_rows_per_chunk` at a time.

    `rec` needs the pairs of the rows' steps only (`grid.with_pairs` of a range of steps);
    `by_y` is `rows_by_y(rec)`."""
    row_step = np.searchsorted(rec.step_ptr, rows, "right") - 1
    n, n_ranged = len(rows), len(ranged())
    hood = Neighbourhoods(
        rows=rows,
        nodes=np.empty(n, np.int64),
        edges={name: np.empty(n, np.int64) for name in config.edge_types},
        full_future=np.empty(n, np.int64),
        ego_full_future=np.empty(n, bool),
        low=np.empty((n, n_ranged)),
        high=np.empty((n, n_ranged)),
    )

    def fill(part: slice) -> None:
        values = _chunk(rec, by_y, rows[part], row_step[part], config)
        for name, value in values["edges"].items():
            hood.edges[name][part] = value
        for name in ("nodes", "full_future", "ego_full_future", "low", "high"):
            getattr(hood, name)[part] = values[name]

    size = budget.BUDGET.ego_rows_per_chunk
    for _ in in_order(fill, [slice(i, i + size) for i in range(0, n, size)]):
        pass  # the chunks on the process's threads, each filling its own rows of `hood`
    return hood


def positions(hood: Neighbourhoods, history: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(held, at): which history rows `hood` holds (present rows of its range of steps), and
    their index in hood.rows (0 where not held)."""
    if len(hood.rows) == 0:
        return np.zeros(history.shape, bool), np.zeros(history.shape, np.int64)
    offset = history - hood.rows[0]
    index = hood.index_of_rows
    inside = (offset >= 0) & (offset < len(index))
    at = index[np.where(inside, offset, 0)]
    held = inside & (at >= 0)
    return held, np.where(held, at, 0)


def row_bounds(history: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, last): each sample's lowest and highest present row of (B, K_H) `history_rows`
    (its present row is the last): the ranges of steps whose neighbourhoods it needs."""
    first = np.empty(len(history), history.dtype)
    for part in sample_chunks(len(history)):
        rows = history[part]
        first[part] = np.where(rows >= 0, rows, np.iinfo(history.dtype).max).min(axis=1)
    return first, history[:, -1].copy()


def sample_counts(hood: Neighbourhoods, history: np.ndarray, config: BuildConfig) -> np.ndarray:
    """(B, C) int64 per sample, in `edges.count_columns(config.edge_types)` order: nodes, each edge type's edges,
    targets, targets with a full future, from its (B, K_H) `history_rows`.

    Only the rows `hood` holds count (the targets: if it holds the present row): the counts of
    the neighbourhoods of consecutive ranges of steps add up to those of all at once."""
    counts = np.empty((len(history), len(edges.count_columns(config.edge_types))), np.int64)
    for part in sample_chunks(len(history)):
        counts[part] = _counts(hood, history[part], config)
    return counts


def _counts(hood: Neighbourhoods, history: np.ndarray, config: BuildConfig) -> np.ndarray:
    present, at = positions(hood, history)
    if len(hood.rows) == 0:
        return np.zeros((len(history), len(edges.count_columns(config.edge_types))), np.int64)
    nodes = np.where(present, hood.nodes[at], 0)
    edge_counts = []
    for edge in edges.types_of(config.edge_types):
        per_step = np.where(present, hood.edges[edge.name][at], 0)
        # an edge to a step after the last history step is not in the graph
        edge_counts.append(per_step[:, : per_step.shape[1] - edge.steps_ahead].sum(axis=1))
    now, held = at[:, -1], present[:, -1]
    if config.protocol is Protocol.CS_LSTM:
        targets = held.astype(np.int64)
        full = (hood.ego_full_future[now] & held).astype(np.int64)
    else:
        ego = int(config.ego_is_target)
        targets = np.where(held, hood.nodes[now] - 1 + ego, 0)
        full = np.where(held, hood.full_future[now] + ego * hood.ego_full_future[now], 0)
    return np.stack([nodes.sum(axis=1), *edge_counts, targets, full], axis=1)
