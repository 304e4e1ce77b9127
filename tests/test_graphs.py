"""The fast graph builder (`induce_graphs`) against a deliberately simple brute-force reference.

`brute_force_graph` applies the rules of docs/conventions.md (and of graphs.py's docstring) to one
window with plain Python loops over a grid-node table: no RecordingArrays, no sweep, no CSR
index. The fast path must give the same nodes in the same order, the same edge sets and the
same targets, on a hand-computed scene and on many random scenes that include vehicles at
exactly the thresholds (and one float64 step beyond them), tracks that start or end inside a
window, and a vehicle whose record is two tracks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.graphs import GraphBatch, concat_batches, induce_graphs
from ngsim_graphs.grid import grid_nodes, recording_arrays

ACTOR_DISTANCE_TOL_M = 1e-5  # actor-actor distances are stored as float32
GRID_COLUMNS = (s.STEP, s.TRACK_ID, s.VEHICLE_ID, s.X_M, s.Y_M, s.HEADING_RAD, s.SPEED_MPS)


@dataclass(frozen=True)
class SampleGraph:
    """One sample's graph with sample-local node indices, in comparable plain-Python form."""

    nodes: list[tuple[int, int, bool, tuple[float, float, float, float]]]  # (k, track, is_ego, z)
    spatial: list[tuple[int, int, float]]  # (source, destination, distance_m), sorted
    temporal: list[tuple[int, int]]  # (node at k, node at k+1), sorted
    targets: list[tuple[int, int, tuple[bool, ...], tuple[tuple[float, float] | None, ...]]]
    # (node, track, mask, xy where mask else None), by node


def _distance(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    dx, dy = a[0] - b[0], a[1] - b[1]
    return math.sqrt(dx * dx + dy * dy)


def brute_force_graph(
    tracks: pl.DataFrame, ego_track: int, start_step: int, config: BuildConfig
) -> SampleGraph:
    """The graph of the window of `ego_track` starting at grid step `start_step`, by the rules.

    `tracks` is a grid-node table: step, track_id, vehicle_id, x_m, y_m, heading_rad, speed_mps,
    one row per track and step (world frame, metres).
    """
    k_h, k_f = config.history_steps, config.future_steps
    present = start_step + k_h - 1
    window = tracks.filter(pl.col(s.STEP).is_between(start_step, present + k_f))
    state: dict[tuple[int, int], tuple[float, float, float, float]] = {}
    tracks_at: dict[int, list[int]] = {}
    for step, track, _vehicle, x, y, heading, speed in window.select(GRID_COLUMNS).iter_rows():
        state[(track, step)] = (x, y, heading, speed)
        tracks_at.setdefault(step, []).append(track)
    for step in range(start_step, present + k_f + 1):
        assert (ego_track, step) in state, "the ego must be present at every step of its window"
    ox, oy = state[(ego_track, present)][:2]

    nodes, index, spatial = [], {}, []
    for k in range(k_h):
        step = start_step + k
        ego = state[(ego_track, step)]
        actors = []
        for track in sorted(tracks_at[step]):
            if track != ego_track and _distance(state[(track, step)], ego) <= config.d_sense_m:
                actors.append(track)
        for track in [ego_track, *actors]:
            x, y, heading, speed = state[(track, step)]
            index[(k, track)] = len(nodes)
            nodes.append((k, track, track == ego_track, (x - ox, y - oy, heading, speed)))
        e = index[(k, ego_track)]
        for track in actors:
            d = _distance(state[(track, step)], ego)
            spatial += [(e, index[(k, track)], d), (index[(k, track)], e, d)]
        for i, a in enumerate(actors):
            for b in actors[i + 1 :]:
                d = _distance(state[(a, step)], state[(b, step)])
                if d <= config.d_min_m:
                    spatial += [
                        (index[(k, a)], index[(k, b)], d),
                        (index[(k, b)], index[(k, a)], d),
                    ]

    temporal = sorted(
        (n, index[(k + 1, track)]) for (k, track), n in index.items() if (k + 1, track) in index
    )
    targets = []
    for (k, track), n in sorted(index.items(), key=lambda item: item[1]):
        if k != k_h - 1 or (track == ego_track and not config.ego_is_target):
            continue
        future = [state.get((track, present + f)) for f in range(1, k_f + 1)]
        mask = tuple(p is not None for p in future)
        xy = tuple(None if p is None else (p[0] - ox, p[1] - oy) for p in future)
        targets.append((n, track, mask, xy))
    return SampleGraph(nodes, sorted(spatial), temporal, targets)


def fast_graphs(batch: GraphBatch) -> list[SampleGraph]:
    """Every sample of a GraphBatch in SampleGraph form (after checking batch-level invariants)."""
    n_nodes = len(batch.node_track)
    assert batch.node_ptr[0] == 0 and batch.node_ptr[-1] == n_nodes
    assert np.array_equal(
        batch.node_sample, np.repeat(np.arange(batch.n_samples), np.diff(batch.node_ptr))
    )
    src, dst = batch.edges["spatial"].index
    assert np.array_equal(batch.node_sample[src], batch.node_sample[dst]), (
        "an edge joins two samples"
    )
    assert np.array_equal(
        batch.node_sample[batch.edges["temporal"].index[0]],
        batch.node_sample[batch.edges["temporal"].index[1]],
    )
    assert len(batch.edges["spatial"].attribute) == batch.edges["spatial"].index.shape[1]
    assert batch.target_xy.shape == (*batch.target_mask.shape, 2)
    assert not batch.target_xy[~batch.target_mask].any(), "masked target positions must be 0"
    assert np.all(np.diff(batch.target_node) > 0), "targets come by node, so by sample"
    by_sample = lambda nodes: np.split(
        np.argsort(batch.node_sample[nodes], kind="stable"),
        np.cumsum(np.bincount(batch.node_sample[nodes], minlength=batch.n_samples))[:-1],
    )
    spatial_by, temporal_by = by_sample(src), by_sample(batch.edges["temporal"].index[0])
    step, track = batch.node_step.tolist(), batch.node_track.tolist()
    is_ego, features = batch.node_is_ego.tolist(), batch.node_features.tolist()
    src_l, dst_l, dist_l = src.tolist(), dst.tolist(), batch.edges["spatial"].attribute.tolist()
    t_src, t_dst = batch.edges["temporal"].index.tolist()
    target_node, mask_l, xy_l = (
        batch.target_node.tolist(),
        batch.target_mask.tolist(),
        batch.target_xy.tolist(),
    )
    target_by = np.searchsorted(batch.target_node, batch.node_ptr).tolist()
    graphs = []
    for b in range(batch.n_samples):
        lo, hi = int(batch.node_ptr[b]), int(batch.node_ptr[b + 1])
        nodes = [(step[n], track[n], is_ego[n], tuple(features[n])) for n in range(lo, hi)]
        spatial = sorted((src_l[e] - lo, dst_l[e] - lo, dist_l[e]) for e in spatial_by[b].tolist())
        temporal = sorted((t_src[e] - lo, t_dst[e] - lo) for e in temporal_by[b].tolist())
        targets = []
        for t in range(target_by[b], target_by[b + 1]):
            mask = tuple(mask_l[t])
            xy = tuple(tuple(p) if m else None for p, m in zip(xy_l[t], mask, strict=True))
            targets.append((target_node[t] - lo, track[target_node[t]], mask, xy))
        graphs.append(SampleGraph(nodes, spatial, temporal, targets))
    return graphs


def assert_same_graph(fast: SampleGraph, brute: SampleGraph) -> None:
    """Nodes, targets and temporal edges identical; spatial edge sets identical, distances close."""
    assert fast.nodes == brute.nodes
    assert fast.temporal == brute.temporal
    assert len(set(fast.temporal)) == len(fast.temporal)
    assert fast.targets == brute.targets
    fast_edges = {(a, b): d for a, b, d in fast.spatial}
    brute_edges = {(a, b): d for a, b, d in brute.spatial}
    assert len(fast_edges) == len(fast.spatial), "duplicate spatial edges"
    assert all(a != b for a, b in fast_edges), "self loop"
    assert set(fast_edges) == set(brute_edges)
    ego_nodes = {n for n, node in enumerate(brute.nodes) if node[2]}
    for edge, d in brute_edges.items():
        if ego_nodes & set(edge):
            assert fast_edges[edge] == d, edge  # ego-actor: float64, the same formula
        else:
            assert abs(fast_edges[edge] - d) <= ACTOR_DISTANCE_TOL_M, (edge, fast_edges[edge], d)


def grid_table(rows: list[tuple]) -> pl.DataFrame:
    """A grid-node table from (step, track, vehicle, x, y, heading, speed) tuples."""
    return pl.DataFrame(rows, schema=s.GRID_NODE_SCHEMA, orient="row")


def fast_path(
    table: pl.DataFrame,
    egos: list[int],
    starts: list[int],
    config: BuildConfig,
    first_step: int = 0,
) -> GraphBatch:
    """grid_nodes -> recording_arrays -> induce_graphs, from a tracks-like table.

    The grid-node table goes back to times in seconds (and a shuffled row order) first, so that
    grid_nodes' own step computation and sort are part of what is checked.
    """
    tracks = (
        table.with_columns((pl.col(s.STEP) * config.time_step_s).alias(s.TIME_S))
        .drop(s.STEP)
        .sample(fraction=1.0, shuffle=True, seed=7)
    )
    nodes = grid_nodes(tracks, config.time_step_s)
    rec = recording_arrays(nodes, config.d_min_m)
    return induce_graphs(
        rec, np.array(egos, dtype=np.int32), np.array(starts, dtype=np.int64), config, first_step
    )


def restrict_steps(graph: SampleGraph, first_step: int) -> SampleGraph:
    """The graph without its nodes before history step `first_step` (and their edges)."""
    kept = [n for n, node in enumerate(graph.nodes) if node[0] >= first_step]
    new = {old: i for i, old in enumerate(kept)}
    return SampleGraph(
        nodes=[graph.nodes[n] for n in kept],
        spatial=[(new[a], new[b], d) for a, b, d in graph.spatial if a in new and b in new],
        temporal=[(new[a], new[b]) for a, b in graph.temporal if a in new and b in new],
        targets=[(new[n], track, mask, xy) for n, track, mask, xy in graph.targets],
    )


# --- a scene computed by hand ------------------------------------------------------------------

TINY = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2)


def tiny_scene() -> pl.DataFrame:
    """Steps 0..3; track 0 (vehicle 10) is the ego, driving (0, 0), (0, 10), (0, 20), (0, 30).

    Track 1 (vehicle 11): (30, 40) at step 0, 50 m from the ego; (30, 50) at step 1, 50 m again
    (3-4-5); (30, 60) at step 2, then gone. Track 2 (vehicle 12): (0, -51) at step 0 (51 m: not a
    node), then (0, -30), (0, -20), (0, -10). Track 3 (vehicle 16) is at (0, 20) at step 0 only: a
    node at k = 0 without a temporal edge. Track 4 (vehicle
    14): (15, 30), (15, 40), (15, 50) at steps 1..3: 25 m from the ego and 25 m from track 1 at
    step 1 (both exactly d_min). Track 5 (vehicle 15) is 100 m away, never a node. Heading is
    0.1 * track, speed 10 * track + step.
    """
    positions = {
        0: {0: (0.0, 0.0), 1: (0.0, 10.0), 2: (0.0, 20.0), 3: (0.0, 30.0)},
        1: {0: (30.0, 40.0), 1: (30.0, 50.0), 2: (30.0, 60.0)},
        2: {0: (0.0, -51.0), 1: (0.0, -30.0), 2: (0.0, -20.0), 3: (0.0, -10.0)},
        3: {0: (0.0, 20.0)},
        4: {1: (15.0, 30.0), 2: (15.0, 40.0), 3: (15.0, 50.0)},
        5: {st: (100.0, 10.0 * st) for st in range(4)},
    }
    vehicle = {0: 10, 1: 11, 2: 12, 3: 16, 4: 14, 5: 15}
    rows = [
        (step, track, vehicle[track], x, y, 0.1 * track, 10.0 * track + step)
        for track, by_step in positions.items()
        for step, (x, y) in by_step.items()
    ]
    return grid_table(rows)


def expected_tiny(ego_is_target: bool) -> SampleGraph:
    d1 = math.sqrt(30.0**2 + 40.0**2)  # 50.0
    nodes = [
        (0, 0, True, (0.0, -10.0, 0.0, 0.0)),
        (0, 1, False, (30.0, 30.0, 0.1, 10.0)),
        (0, 3, False, (0.0, 10.0, 0.30000000000000004, 30.0)),
        (1, 0, True, (0.0, 0.0, 0.0, 1.0)),
        (1, 1, False, (30.0, 40.0, 0.1, 11.0)),
        (1, 2, False, (0.0, -40.0, 0.2, 21.0)),
        (1, 4, False, (15.0, 20.0, 0.4, 41.0)),
    ]
    spatial = sorted([
        (0, 1, d1), (1, 0, d1), (0, 2, 20.0), (2, 0, 20.0),
        (3, 4, d1), (4, 3, d1), (3, 5, 40.0), (5, 3, 40.0), (3, 6, 25.0), (6, 3, 25.0),
        (4, 6, 25.0), (6, 4, 25.0),
    ])  # fmt: skip
    temporal = [(0, 3), (1, 4)]
    targets = [
        (4, 1, (True, False), ((30.0, 50.0), None)),
        (5, 2, (True, True), ((0.0, -30.0), (0.0, -20.0))),
        (6, 4, (True, True), ((15.0, 30.0), (15.0, 40.0))),
    ]
    if ego_is_target:
        targets.insert(0, (3, 0, (True, True), ((0.0, 10.0), (0.0, 20.0))))
    return SampleGraph(nodes, spatial, temporal, targets)


@pytest.mark.parametrize("ego_is_target", [False, True])
def test_tiny_scene_by_hand(ego_is_target: bool) -> None:
    config = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2, ego_is_target=ego_is_target)
    expected = expected_tiny(ego_is_target)
    assert brute_force_graph(tiny_scene(), 0, 0, config) == expected
    (fast,) = fast_graphs(fast_path(tiny_scene(), [0], [0], config))
    assert_same_graph(fast, expected)
    batch = fast_path(tiny_scene(), [0], [0], config)
    assert batch.time_step_s == 0.2
    assert (
        batch.edges["spatial"].attribute.dtype == np.float64
        and batch.node_features.dtype == np.float64
    )


def test_tiny_scene_d_min_zero_keeps_only_ego_edges() -> None:
    config = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2, d_min_m=0.0)
    (fast,) = fast_graphs(fast_path(tiny_scene(), [0], [0], config))
    ego_nodes = {0, 3}
    assert fast.spatial == [e for e in expected_tiny(False).spatial if ego_nodes & {e[0], e[1]}]


@pytest.mark.parametrize("start_step", [0, 1000])
def test_actor_edges_of_a_vehicle_rounded_onto_d_sense(start_step: int) -> None:
    # fl(ego_y - 50) = v exactly, and vehicle A one float64 step below v: fl(ego_y - y_a) = 50.0,
    # so A is a node at exactly d_sense, and the lower vehicle of its pair with B (5 m ahead).
    # At step 1000, v is chosen so that step * 1e5 + v is a rounding tie that goes up.
    v = 10.0 + 3 * 2.0**-27
    ego_y, y_a = v + 50.0, float(np.nextafter(v, -math.inf))
    assert ego_y - 50.0 == v and _distance((0.0, ego_y), (0.0, y_a)) == 50.0
    rows = []
    for step in range(start_step, start_step + 3):
        rows += [(step, 0, 1, 0.0, ego_y, 0.0, 1.0), (step, 1, 2, 0.0, y_a, 0.0, 1.0)]
        rows += [(step, 2, 3, 0.0, y_a + 5.0, 0.0, 1.0)]
    table = grid_table(rows)
    config = BuildConfig(history_steps=2, future_steps=1, stride_s=0.2)
    brute = brute_force_graph(table, 0, start_step, config)
    assert [(a, b) for a, b, _ in brute.spatial if a in (1, 2) and b in (1, 2)] == [(1, 2), (2, 1)]
    (fast,) = fast_graphs(fast_path(table, [0], [start_step], config))
    assert_same_graph(fast, brute)


def test_induce_graphs_rejects_an_ego_missing_from_its_window() -> None:
    with pytest.raises(ValueError, match="ego track is not present"):
        fast_path(tiny_scene(), [4], [0], TINY)  # track 4 starts at step 1


# --- random scenes -----------------------------------------------------------------------------

SCENE_CONFIGS = (
    BuildConfig(),
    BuildConfig(d_min_m=0.0, ego_is_target=True),
    BuildConfig(d_min_m=50.0, stride_s=0.2),
    BuildConfig(ego_is_target=True, stride_s=1.0),
    BuildConfig(history_steps=5, future_steps=4, stride_s=0.6, d_sense_m=30.0, d_min_m=12.5),
)
N_SCENES = 50
MAX_WINDOWS = 16  # windows checked per scene (stride 1 gives ~150): a random, sorted subset
Q = 1024.0  # positions are multiples of 1/Q: sums and differences are exact in float64


def _quantise(v: np.ndarray) -> np.ndarray:
    return np.round(v * Q) / Q


def _just_beyond(
    anchor: tuple[float, float], x: float, y: float, d: float, axis: int
) -> tuple[float, float]:
    """Move (x, y) away from `anchor` along `axis` by float64 steps until it is > d from it."""
    point = [x, y]
    while _distance(tuple(point), anchor) <= d:
        direction = math.copysign(1.0, point[axis] - anchor[axis])
        moved = float(np.nextafter(point[axis], direction * math.inf))
        # Near 0 the float64 step underflows when squared: jump to a tiny but squarable offset.
        point[axis] = (
            moved if abs(moved - anchor[axis]) > 1e-100 else anchor[axis] + direction * 1e-100
        )
    return point[0], point[1]


def random_scene(rng: np.random.Generator, config: BuildConfig) -> pl.DataFrame:
    """A grid-node table of 3-12 random tracks on 1-3 lanes over 60-90 steps, plus companions.

    A main track lives long enough for windows; companions ride along it at fixed offsets for part
    of its life: exactly d_sense from it (straight ahead and on a 3-4-5 diagonal), one float64
    step beyond d_sense, one swinging in and out of d_sense, three vehicles exactly d_min apart
    (and one a float64 step beyond), and one vehicle recorded as two tracks with a gap.
    """
    n_steps = int(rng.integers(60, 91))
    n_lanes = int(rng.integers(1, 4))
    d_s, d_m = config.d_sense_m, config.d_min_m
    tracks: list[tuple[int, dict[int, tuple[float, float]]]] = []  # (vehicle, step -> position)

    def drive(first: int, last: int, y0: float, speed: float) -> dict[int, tuple[float, float]]:
        lane = int(rng.integers(0, n_lanes))
        drift = rng.normal(0.0, 0.05) if rng.random() < 0.3 else 0.0  # a slow lane change
        steps = np.arange(first, last + 1)
        x = _quantise(1.8 + 3.6 * lane + drift * (steps - first))
        y = _quantise(y0 + speed * 0.2 * steps + rng.normal(0.0, 0.05, len(steps)))
        return {int(st): (float(a), float(b)) for st, a, b in zip(steps, x, y, strict=True)}

    main_len = int(rng.integers(config.window_steps, n_steps + 1))
    main_first = int(rng.integers(0, n_steps - main_len + 1))
    main = drive(main_first, main_first + main_len - 1, rng.uniform(-20, 20), rng.uniform(10, 20))
    tracks.append((0, main))
    for _ in range(int(rng.integers(3, 13)) - 1):
        first = max(0, int(rng.integers(-30, n_steps - 3)))
        last = min(n_steps - 1, first + int(rng.integers(3, n_steps)))
        tracks.append((0, drive(first, last, rng.uniform(-80, 80), rng.uniform(3, 30))))

    main_steps = sorted(main)

    def companion(
        offset: Callable, life: tuple[int, int] | None = None
    ) -> dict[int, tuple[float, float]]:
        if life is None:
            a = int(rng.integers(0, len(main_steps)))
            life = (a, min(len(main_steps), a + int(rng.integers(8, 60))))
        return {st: offset(main[st], st) for st in main_steps[life[0] : life[1]]}

    tracks.append((0, companion(lambda p, st: (p[0], p[1] + d_s))))
    tracks.append((0, companion(lambda p, st: (p[0] - d_s * 3 / 5, p[1] - d_s * 4 / 5))))
    tracks.append((0, companion(lambda p, st: _just_beyond(p, p[0], p[1] - d_s, d_s, axis=1))))
    tracks.append(
        (
            0,
            companion(
                lambda p, st: _just_beyond(p, p[0] + d_s * 3 / 5, p[1] + d_s * 4 / 5, d_s, axis=0)
            ),
        )
    )
    tracks.append(
        (0, companion(lambda p, st: (p[0], p[1] + d_s + float(_quantise(3.0 * math.cos(st))))))
    )
    life = (int(rng.integers(0, 10)), len(main_steps))
    anchor = lambda p: (p[0], p[1] - d_m / 2)
    tracks.append((0, companion(lambda p, st: anchor(p), life)))
    tracks.append((0, companion(lambda p, st: (anchor(p)[0], anchor(p)[1] + d_m), life)))
    tracks.append(
        (0, companion(lambda p, st: (anchor(p)[0] + d_m * 3 / 5, anchor(p)[1] + d_m * 4 / 5), life))
    )
    tracks.append(
        (
            0,
            companion(
                lambda p, st: _just_beyond(anchor(p), p[0], p[1] + d_m / 2, d_m, axis=1), life
            ),
        )
    )
    # One vehicle, two tracks: recorded for a while, lost for 1-3 steps, recorded again.
    split_at = int(rng.integers(3, 12))
    gap = int(rng.integers(1, 4))
    twin = lambda p, st: (p[0] + 3.5, p[1] + 6.0)
    end = min(len(main_steps), split_at + gap + int(rng.integers(10, 50)))
    tracks.append((-1, companion(twin, (0, split_at))))
    tracks.append((-1, companion(twin, (split_at + gap, end))))

    tracks = [(v, p) for v, p in tracks if p]
    first_id = int(rng.integers(0, 500))
    ids = rng.permutation(len(tracks)) + first_id
    vehicles = rng.permutation(len(tracks)) + 1
    twin_vehicle = int(vehicles[len(tracks) - 1])
    rows = []
    for (marker, positions), track_id, vehicle in zip(tracks, ids, vehicles, strict=True):
        vehicle = twin_vehicle if marker == -1 else int(vehicle)
        heading, speed = rng.normal(0, 0.1), rng.uniform(0, 30)
        for st, (x, y) in positions.items():
            rows.append((st, int(track_id), vehicle, x, y, heading + 0.01 * st, speed + 0.1 * st))
    return grid_table(rows)


def all_windows(table: pl.DataFrame, config: BuildConfig) -> tuple[list[int], list[int]]:
    """(ego track, start step) of every window, enumerated directly from the table."""
    egos, starts = [], []
    per_track = table.group_by(s.TRACK_ID).agg(
        pl.col(s.STEP).min().alias("first"), pl.len().alias("n")
    )
    for track, first, n in per_track.sort(s.TRACK_ID).iter_rows():
        for start in range(first, first + n - config.window_steps + 1, config.stride_steps):
            egos.append(track)
            starts.append(start)
    return egos, starts


def test_random_scenes_match_the_brute_force() -> None:
    rng = np.random.default_rng(2024)
    exact_sense = exact_min = checked = masked = twins_seen = reentries = 0
    for scene in range(N_SCENES):
        config = SCENE_CONFIGS[scene % len(SCENE_CONFIGS)]
        table = random_scene(rng, config)
        egos, starts = all_windows(table, config)
        assert egos
        if len(egos) > MAX_WINDOWS:
            pick = np.sort(rng.choice(len(egos), MAX_WINDOWS, replace=False))
            egos, starts = [egos[i] for i in pick], [starts[i] for i in pick]
        brute = [
            brute_force_graph(table, e, st, config) for e, st in zip(egos, starts, strict=True)
        ]
        fast = fast_graphs(fast_path(table, egos, starts, config))
        half = len(egos) // 2 or 1
        parts = [fast_path(table, egos[:half], starts[:half], config)]
        if half < len(egos):
            parts.append(fast_path(table, egos[half:], starts[half:], config))
        joined = fast_graphs(concat_batches(parts))
        assert len(fast) == len(joined) == len(brute)
        for f, j, b in zip(fast, joined, brute, strict=True):
            assert_same_graph(f, b)
            assert_same_graph(j, b)
        checked += len(brute)
        vehicle_of = dict(
            zip(table[s.TRACK_ID].to_list(), table[s.VEHICLE_ID].to_list(), strict=True)
        )
        for g in brute:
            ego_edges = [d for a, _, d in g.spatial if g.nodes[a][2]]
            exact_sense += ego_edges.count(config.d_sense_m)
            exact_min += sum(
                d == config.d_min_m for a, b, d in g.spatial if not (g.nodes[a][2] or g.nodes[b][2])
            )
            masked += sum(not all(t[2]) for t in g.targets)
            node_tracks = {n[1] for n in g.nodes}
            steps_of = {t: [n[0] for n in g.nodes if n[1] == t] for t in node_tracks}
            reentries += sum(
                ks[-1] - ks[0] + 1 > len(ks) for ks in steps_of.values()
            )  # left, came back
            twins_seen += len(node_tracks) > len({vehicle_of[t] for t in node_tracks})
    assert checked > 300
    assert (
        exact_sense > 50 and exact_min > 50 and masked > 50 and twins_seen > 10 and reentries > 20
    )


def test_graphs_cut_to_the_last_steps_are_the_whole_graphs_restricted() -> None:
    rng = np.random.default_rng(31)
    checked = 0
    for scene in range(6):
        config = SCENE_CONFIGS[scene % len(SCENE_CONFIGS)]
        table = random_scene(rng, config)
        egos, starts = all_windows(table, config)
        egos, starts = egos[:MAX_WINDOWS], starts[:MAX_WINDOWS]
        whole = fast_graphs(fast_path(table, egos, starts, config))
        for first_step in (1, config.history_steps // 2, config.history_steps - 1):
            cut = fast_graphs(fast_path(table, egos, starts, config, first_step))
            for c, w in zip(cut, whole, strict=True):
                assert c == restrict_steps(w, first_step)
                assert min(node[0] for node in c.nodes) == first_step
                checked += 1
    assert checked > 100
    for beyond in (-1, config.history_steps):
        with pytest.raises(ValueError, match="first_step"):
            fast_path(table, egos, starts, config, beyond)


def test_random_scene_thresholds_are_exact() -> None:
    """The generator really puts vehicles at exactly d_sense / d_min and just beyond them."""
    rng = np.random.default_rng(5)
    config = BuildConfig()
    table = random_scene(rng, config)
    by_step: dict[int, list[tuple[float, float]]] = {}
    for step, x, y in table.select(s.STEP, s.X_M, s.Y_M).iter_rows():
        by_step.setdefault(step, []).append((x, y))
    distances = [
        _distance(a, b)
        for points in by_step.values()
        for i, a in enumerate(points)
        for b in points[i + 1 :]
    ]
    assert 50.0 in distances and 25.0 in distances
    assert any(50.0 < d < 50.0 + 1e-12 for d in distances)
    assert any(25.0 < d < 25.0 + 1e-12 for d in distances)


def test_an_edge_type_s_index_is_also_an_attribute() -> None:
    """`batch.spatial_edges` (the README's quick start) is batch.edges["spatial"].index."""
    config = BuildConfig()
    table = tiny_scene()
    egos, starts = all_windows(table, config)
    batch = fast_path(table, egos, starts, config)
    assert batch.spatial_edges is batch.edges["spatial"].index
    assert batch.temporal_edges is batch.edges["temporal"].index
    with pytest.raises(AttributeError, match="lane_edges"):
        batch.lane_edges  # noqa: B018
