"""Every edge type of a sample's graph (docs/conventions.md), each rule written once.

An edge type says which pairs of a sample's nodes it links, at which steps, and with which
attribute, twice over the same decisions:
- `induce`: the edges of a batch of samples, from the nodes `graphs.induce_graphs` found;
- `count`: per ego row, how many edges the rule gives the ego's graph from that row's step, and
  the attribute's minimum and maximum there, from the rows near it (`neighbourhoods`, which
  counts a build's samples without inducing their graphs; the scaler's ranges follow from it).

`EDGE_TYPES` knows every type by name; a build's config names the types its graphs have
(`BuildConfig.edge_types`, the paper's two by default, recorded in its manifest) and
`types_of` gives them, in that order: the batch's edge sets, the build's count columns
(`count_columns`), the statistics, the model's GAT per type (and its checkpoint keys), PyG's
relations and the export's tables follow it. Code reads `edges.EDGE_TYPES` at call time, so a
test may register a type of its own. A scaled attribute of a new name is a new quantity of the
scaler (`scaling.SCALED`, and so of the manifest).

- spatial: at each step, ego <-> each actor node, and actor <-> actor where the two are at
  most d_max apart (a proximity pair of `grid`; the build's field and manifest key `d_min_m`
  keep their name), both directions; attribute: the distance in metres.
- temporal: a track's node at step k -> the same track's node at k+1; attribute: t_s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.grid import RecordingArrays, y_bounds, y_window


@dataclass(frozen=True)
class Nodes:
    """The nodes of B samples as `induce_graphs` found them: what an edge rule reads.

    A sample-step "ss" is (sample b, kept step j), numbered b * n_kept + j. Candidates are the
    rows at the step of an ss with its ego; nodes are the candidates within d_sense of the ego,
    ordered by ss, ego first, then by track id. Node indices are batch-global.
    """

    rec: RecordingArrays
    config: BuildConfig
    ss_step: np.ndarray  # (B*n_kept,) grid step of each ss, 0 where the ego is absent
    ego_rows: np.ndarray  # (B*n_kept,) the ego's row at each ss, -1 where absent
    cand_ss: np.ndarray  # (C,) ss of each candidate, ascending
    cand_is_ego: np.ndarray  # (C,) bool
    cand_dist: np.ndarray  # (C,) float64 metres to the ego
    node_of_cand: np.ndarray  # (C,) int64 node of each candidate, -1 where none
    order: np.ndarray  # (N,) candidate of each node
    node_sample: np.ndarray  # (N,) int64
    node_step: np.ndarray  # (N,) int8 history step k
    node_track: np.ndarray  # (N,) int32


@dataclass(frozen=True)
class Near:
    """The rows near each of U ego rows (within d_sense, the ego included): runs by ego row, in
    row order; what an edge count reads."""

    rec: RecordingArrays
    config: BuildConfig
    egos: np.ndarray  # (U,) ego rows
    step: np.ndarray  # (U,) their grid steps
    owner: np.ndarray  # (C,) index of the ego row of each near row
    row: np.ndarray  # (C,) int64
    distance: np.ndarray  # (C,) float64 metres to the ego
    actor: np.ndarray  # (C,) bool: not the ego's own row

    @cached_property
    def starts(self) -> np.ndarray:
        """(U,) first entry of each ego row's run (no run is empty: the ego is near itself)."""
        lengths = np.bincount(self.owner, minlength=len(self.egos))
        return np.cumsum(lengths) - lengths

    @cached_property
    def span(self) -> tuple[int, np.ndarray]:
        """(first, steps): the rows of the ego rows' steps, first to first + len(steps) - 1
        (every near row among them), and the step of each. A fact of a row is looked up per near
        row from an array over these rows, found once per row, not once per ego row near it."""
        if len(self.egos) == 0:
            return 0, np.zeros(0, np.int64)
        low, high = int(self.step.min()), int(self.step.max())
        return int(self.rec.step_ptr[low]), self.rec.row_steps(low, high + 1)

    @cached_property
    def next_rows(self) -> np.ndarray:
        """(len(steps),) of `span`: each row's track's row at the next step, -1 where none."""
        first, steps = self.span
        tracks = self.rec.node_track[first : first + len(steps)]
        return self.rec.row_at(tracks, steps + 1)

    @cached_property
    def full_futures(self) -> np.ndarray:
        """(len(steps),) of `span`: whether each row's track has its K_F steps after it."""
        first, steps = self.span
        track_first, count = self.rec.track_steps(self.rec.node_track[first : first + len(steps)])
        return track_first + count - 1 >= steps + self.config.future_steps


@dataclass(frozen=True)
class RowEdges:
    """Per ego row: the edges a rule gives the ego's graph from that row's step, and the
    minimum and maximum of their attribute (inf and -inf without any)."""

    count: np.ndarray  # (U,) int64
    low: np.ndarray  # (U,) float64
    high: np.ndarray  # (U,) float64


@dataclass(frozen=True)
class EdgeType:
    """One edge type's rule. `steps_ahead`: 0 links nodes of one step, 1 a step to the next
    (the count of the last history step's row is then not in the graph). `scaled`: whether the
    scaler maps the attribute (named `attribute` among its quantities)."""

    name: str  # the batch's key, the model's GAT, PyG's relation; `<name>_edges` the table
    attribute: str  # the attribute's column in the export (schema)
    scaled: bool
    steps_ahead: int
    induce: Callable[[Nodes], tuple[np.ndarray, np.ndarray]]  # (2, E) int64 by sample, (E,)
    count: Callable[[Near], RowEdges]

    @property
    def table(self) -> str:
        return f"{self.name}_edges"

    @property
    def count_column(self) -> str:
        """Its column of the samples table: its edges per sample (`n_spatial_edges`)."""
        return f"n_{self.name}_edges"


def reduce_at(ufunc: np.ufunc, values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """ufunc over each run of `values` that starts at `starts` (ascending, no run empty)."""
    return ufunc.reduceat(values, starts) if len(starts) else values[:0]


def reduce_runs(
    ufunc: np.ufunc, values: np.ndarray, lengths: np.ndarray, empty: float, dtype=np.float64
) -> np.ndarray:
    """ufunc over consecutive runs of `values` of the given lengths; `empty` for an empty run."""
    out = np.full(len(lengths), empty, dtype=dtype)
    filled = lengths > 0
    out[filled] = reduce_at(ufunc, values, (np.cumsum(lengths) - lengths)[filled])
    return out


def by_sample(
    node_sample: np.ndarray, src: np.ndarray, dst: np.ndarray, attr: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Edges stably sorted by sample (a radix sort on 16-bit keys): a batch then equals its
    samples' graphs concatenated."""
    order = np.argsort(node_sample[src].astype(np.uint16), kind="stable")
    return np.stack([src[order], dst[order]]), attr[order]


# ------------------------------------------------------------------------------------------------
# spatial


PairFilter = Callable[[RecordingArrays, np.ndarray], np.ndarray]  # (rec, (C, 2) rows) -> (C,) bool


def _candidate_blocks(nodes: Nodes) -> tuple[np.ndarray, np.ndarray]:
    """(whether each sample-step has its ego, where its candidates start): the candidates of a
    sample-step occupy a contiguous block, in row order from step_ptr[step]; one without the ego
    (cs-lstm) has none, and no pairs."""
    return nodes.ego_rows >= 0, np.searchsorted(nodes.cand_ss, np.arange(len(nodes.ss_step)))


def actor_pair_edges(
    nodes: Nodes, keep: PairFilter | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(node_a, node_b, distance): the proximity pairs (`grid`: at most d_max apart) of two
    actor nodes of one sample-step, once each, in step order; `keep`: only the pairs of rows
    (C, 2) it keeps (a rule over the pairs, say lateral offsets)."""
    rec, ss_step, ego_rows, node_of_cand = (
        nodes.rec,
        nodes.ss_step,
        nodes.ego_rows,
        nodes.node_of_cand,
    )
    has_ego, block_start = _candidate_blocks(nodes)
    # Only pairs whose lower vehicle is within d_sense of the ego along y can join two nodes.
    pair_ss, pair_index = y_window(
        rec.pair_key, rec, ego_rows, ss_step, nodes.config.d_sense_m, has_ego
    )
    base = block_start - rec.step_ptr[ss_step]
    pair_rows = np.take(rec.pair_rows, pair_index, axis=0)
    node_a = node_of_cand[base[pair_ss] + pair_rows[:, 0]]
    node_b = node_of_cand[base[pair_ss] + pair_rows[:, 1]]
    ego_row = ego_rows[pair_ss]
    keep_pair = (
        (node_a >= 0) & (node_b >= 0) & (pair_rows[:, 0] != ego_row) & (pair_rows[:, 1] != ego_row)
    )
    if keep is not None:
        keep_pair &= keep(rec, pair_rows)
    distance = rec.pair_dist[pair_index[keep_pair]].astype(np.float64)
    return node_a[keep_pair], node_b[keep_pair], distance


def _spatial_induce(nodes: Nodes) -> tuple[np.ndarray, np.ndarray]:
    """Ego <-> actor edges, then actor <-> actor edges among nodes, in both directions: by
    sample, and within a sample grouped by kind (ego->actor, actor->ego, actor->actor both
    ways), each group in step order (deterministic, without a full sort)."""
    rec, ss_step, ego_rows, node_of_cand = (
        nodes.rec,
        nodes.ss_step,
        nodes.ego_rows,
        nodes.node_of_cand,
    )
    has_ego, block_start = _candidate_blocks(nodes)
    actors = nodes.order[~nodes.cand_is_ego[nodes.order]]
    in_block = np.where(has_ego, ego_rows - rec.step_ptr[ss_step], 0)
    ego_node = node_of_cand[np.minimum(block_start + in_block, len(node_of_cand) - 1)]
    ego_src = ego_node[nodes.cand_ss[actors]]
    ego_dst = node_of_cand[actors]
    node_a, node_b, pair_dist = actor_pair_edges(nodes)
    ego_dist = nodes.cand_dist[actors]
    return by_sample(
        nodes.node_sample,
        np.concatenate([ego_src, ego_dst, node_a, node_b]),
        np.concatenate([ego_dst, ego_src, node_b, node_a]),
        np.concatenate([ego_dist, ego_dist, pair_dist, pair_dist]),
    )


def actor_pairs(
    near: Near, keep: PairFilter | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count, minimum and maximum distance of the proximity pairs among each ego row's actors,
    searched as `actor_pair_edges` searches them; `keep`: only the pairs of rows it keeps.
    Which rows are actors is a small (ego, row of its step) table: a lookup, not a distance,
    per pair. The pairs an ego row searches are one run of the pair arrays: its counts are
    one sum per run, its extremes one reduction per run (in float32, the distances' own type:
    exact)."""
    rec, egos, step = near.rec, near.egos, near.step
    width = int(np.diff(rec.step_ptr).max()) if rec.n_steps else 0
    # Row r of ego i's step is entry i * width + r - (first row of the step) of `is_actor`:
    # below 2**31 for a chunk of ego rows (`budget.Budget.ego_rows_per_chunk`), so int32.
    offset = (np.arange(len(egos)) * width - rec.step_ptr[step]).astype(np.int32)
    is_actor = np.zeros(len(egos) * width, bool)
    is_actor[offset[near.owner[near.actor]] + near.row[near.actor]] = True
    lo, hi = y_bounds(rec.pair_key, rec, egos, step, near.config.d_sense_m)
    lengths = hi - lo
    ends = np.cumsum(lengths)
    starts = ends - lengths
    # Each pair an ego row searches, by its index in the pair arrays (int32 where they allow).
    kind = np.int32 if len(rec.pair_dist) < 2**31 else np.int64
    index = np.repeat((lo - starts).astype(kind), lengths)
    index += np.arange(len(index), dtype=kind)
    pairs = np.take(rec.pair_rows, index, axis=0)  # (C, 2); faster than fancy indexing
    pair_offset = np.repeat(offset, lengths)
    keep_pair = np.take(is_actor, pairs[:, 0] + pair_offset)
    keep_pair &= np.take(is_actor, pairs[:, 1] + pair_offset)
    if keep is not None:
        keep_pair &= keep(rec, pairs)
    del pairs, pair_offset
    filled = lengths > 0
    count = np.zeros(len(egos), np.int64)
    low = np.full(len(egos), np.inf)
    high = np.full(len(egos), -np.inf)
    if filled.any():
        count[filled] = np.add.reduceat(keep_pair, starts[filled], dtype=np.int64)
        # NaN for a pair not kept: fmin and fmax pass it over (NaN for a run of none kept).
        distance = np.where(keep_pair, np.take(rec.pair_dist, index), np.float32(np.nan))
        low[filled] = np.fmin.reduceat(distance, starts[filled])
        high[filled] = np.fmax.reduceat(distance, starts[filled])
    low[np.isnan(low)], high[np.isnan(high)] = np.inf, -np.inf
    return count, low, high


def _spatial_count(near: Near) -> RowEdges:
    """2 per actor (ego <-> actor) and 2 per proximity pair of two actors."""
    actors = np.bincount(near.owner[near.actor], minlength=len(near.egos))
    pairs, pair_low, pair_high = actor_pairs(near)
    ego_low = reduce_at(np.minimum, np.where(near.actor, near.distance, np.inf), near.starts)
    ego_high = reduce_at(np.maximum, np.where(near.actor, near.distance, -np.inf), near.starts)
    return RowEdges(
        2 * actors + 2 * pairs, np.minimum(ego_low, pair_low), np.maximum(ego_high, pair_high)
    )


# ------------------------------------------------------------------------------------------------
# temporal


def _temporal_induce(nodes: Nodes) -> tuple[np.ndarray, np.ndarray]:
    """Node of (sample, track) at step k -> its node at k+1, where both exist; by source.

    Only consecutive steps are joined (and spatial edges stay within a step): that is why a model
    of L layers reads the last L + 1 steps alone (`ModelConfig.history_steps_read`), which the
    dataset relies on to cut graphs. Joining further steps would need that changed too."""
    node_sample, node_track, node_step = nodes.node_sample, nodes.node_track, nodes.node_step
    by = np.lexsort((node_step, node_track, node_sample))
    same = (node_sample[by][1:] == node_sample[by][:-1]) & (
        node_track[by][1:] == node_track[by][:-1]
    )
    follows = same & (node_step[by][1:] == node_step[by][:-1] + 1)
    src, dst = by[:-1][follows], by[1:][follows]
    order = np.lexsort((dst, src))
    edges = np.stack([src[order], dst[order]]).astype(np.int64)
    return edges, np.full(edges.shape[1], nodes.config.time_step_s)


def _temporal_count(near: Near) -> RowEdges:
    """The near tracks whose row at the next step is near the ego's row at the next step."""
    rec, d_sense = near.rec, near.config.d_sense_m
    first = near.span[0]
    next_row = near.next_rows[near.row - first]
    ego_next = near.next_rows[near.egos - first][near.owner]
    both = (next_row >= 0) & (ego_next >= 0)
    still = np.zeros(len(near.row), bool)
    xy = rec.node_state
    dx = xy[next_row[both], 0] - xy[ego_next[both], 0]
    dy = xy[next_row[both], 1] - xy[ego_next[both], 1]
    still[both] = np.sqrt(dx * dx + dy * dy) <= d_sense
    count = np.bincount(near.owner[still], minlength=len(near.egos))
    time_step = near.config.time_step_s
    return RowEdges(
        count, np.where(count > 0, time_step, np.inf), np.where(count > 0, time_step, -np.inf)
    )


SPATIAL = EdgeType(
    name="spatial",
    attribute=s.DISTANCE_M,
    scaled=True,
    steps_ahead=0,
    induce=_spatial_induce,
    count=_spatial_count,
)
TEMPORAL = EdgeType(
    name="temporal",
    attribute=s.DT_S,
    scaled=False,
    steps_ahead=1,
    induce=_temporal_induce,
    count=_temporal_count,
)
EDGE_TYPES: dict[str, EdgeType] = {edge.name: edge for edge in (SPATIAL, TEMPORAL)}


def types_of(names: tuple[str, ...]) -> tuple[EdgeType, ...]:
    """The edge types of these names (a build's `BuildConfig.edge_types`), in their order;
    ValueError naming any that no edge type of `EDGE_TYPES` has."""
    unknown = [name for name in names if name not in EDGE_TYPES]
    if unknown:
        raise ValueError(
            f"edge_types names unknown {', '.join(map(repr, unknown))}: this ngsim-graphs knows "
            f"{', '.join(EDGE_TYPES)}"
        )
    return tuple(EDGE_TYPES[name] for name in names)


def scaled_attributes() -> tuple[str, ...]:
    """The edge attributes the scaler maps, once each, of every edge type EDGE_TYPES knows."""
    return tuple(dict.fromkeys(e.attribute for e in EDGE_TYPES.values() if e.scaled))


def count_columns(names: tuple[str, ...]) -> tuple[str, ...]:
    """The samples table's count columns of a build of these edge types: nodes, each edge
    type's (its `count_column`), targets, targets with a full future."""
    edge_counts = tuple(e.count_column for e in types_of(names))
    return (s.N_NODES, *edge_counts, s.N_TARGETS, s.N_FULL_TARGETS)
