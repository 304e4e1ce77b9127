"""The edge types' one home: the registry's defaults, and a new type registered from a test that
goes through induction, counting, the scaler, Collate, the model, PyG and the export."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import torch
from test_graphs import SCENE_CONFIGS, all_windows, grid_table, random_scene
from test_neighbourhoods import arrays_of
from typer.testing import CliRunner

from aigem.config import ModelConfig
from aigem.model.data import Collate
from aigem.model.network import AiGem, count_parameters
from aigem.model.pyg import to_hetero_data, to_model_batch
from ngsim_cli.aigem import app as aigem_app
from ngsim_cli.ngsim import app as ngsim_app
from ngsim_graphs import edges
from ngsim_graphs import schema as s
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.export import export_tables, graph_tables
from ngsim_graphs.graphs import induce_graphs
from ngsim_graphs.grid import RecordingArrays
from ngsim_graphs.neighbourhoods import history_rows, neighbourhoods, sample_counts
from ngsim_graphs.scaling import SCALED, train_ranges


def test_the_default_edge_types_make_the_build_columns_and_the_scaler() -> None:
    assert list(edges.EDGE_TYPES) == ["spatial", "temporal"] == list(BuildConfig().edge_types)
    assert edges.count_columns(BuildConfig().edge_types) == (
        "n_nodes",
        "n_spatial_edges",
        "n_temporal_edges",
        "n_targets",
        "n_targets_full_future",
    )
    assert SCALED == ("x_m", "y_m", "heading_rad", "speed_mps", "distance_m")  # the manifest's
    assert export_tables() == ("nodes", "spatial_edges", "temporal_edges", "targets", "samples")


def _ego_induce(nodes: edges.Nodes) -> tuple[np.ndarray, np.ndarray]:
    """The ego -> each actor node of its step; attribute: their distance (metres)."""
    step_of = nodes.node_sample * nodes.config.history_steps + nodes.node_step  # ascending
    ego_of = np.searchsorted(step_of, step_of)  # the first node of a step is its ego
    actor = np.flatnonzero(~nodes.cand_is_ego[nodes.order])
    return np.stack([ego_of[actor], actor]), nodes.cand_dist[nodes.order][actor]


def _ego_count(near: edges.Near) -> edges.RowEdges:
    distance = near.distance
    return edges.RowEdges(
        np.bincount(near.owner[near.actor], minlength=len(near.egos)),
        edges.reduce_at(np.minimum, np.where(near.actor, distance, np.inf), near.starts),
        edges.reduce_at(np.maximum, np.where(near.actor, distance, -np.inf), near.starts),
    )


EGO = edges.EdgeType(
    name="ego",
    attribute=s.DISTANCE_M,
    scaled=True,
    steps_ahead=0,
    induce=_ego_induce,
    count=_ego_count,
)


def test_a_new_edge_type_goes_through_every_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    base_parameters = count_parameters(AiGem(ModelConfig(layers=2)))
    monkeypatch.setitem(edges.EDGE_TYPES, "ego", EGO)
    config = replace(SCENE_CONFIGS[0], edge_types=("spatial", "temporal", "ego"))
    table = random_scene(np.random.default_rng(7), config)
    egos, starts = (np.array(v, dtype=np.int64) for v in all_windows(table, config))
    rec = arrays_of(table, config)
    batch = induce_graphs(rec, egos.astype(np.int32), starts, config)

    # Induction: an ego edge per actor node, from its step's ego, at the ego's distance.
    ego_edges = batch.edges["ego"]
    actors = np.flatnonzero(~batch.node_is_ego)
    assert ego_edges.index[1].tolist() == actors.tolist() and len(actors) > 20
    source = ego_edges.index[0]
    assert batch.node_is_ego[source].all()
    assert (batch.node_step[source] == batch.node_step[actors]).all()
    assert (batch.node_sample[source] == batch.node_sample[actors]).all()
    offset = batch.node_features[actors, :2] - batch.node_features[source, :2]
    np.testing.assert_allclose(ego_edges.attribute, np.hypot(*offset.T), atol=1e-9)
    spatial_pairs = set(map(tuple, batch.edges["spatial"].index.T.tolist()))
    assert set(map(tuple, ego_edges.index.T.tolist())) <= spatial_pairs  # a part of the spatial

    # Counting without inducing: the new column, after the spatial and temporal ones.
    assert edges.count_columns(config.edge_types)[3] == "n_ego_edges"
    history = history_rows(rec, egos, starts, config)
    hood = neighbourhoods(rec, history, config)
    counts = sample_counts(hood, history, config)
    per_sample = np.bincount(batch.node_sample[source], minlength=batch.n_samples)
    assert counts[:, 3].tolist() == per_sample.tolist()
    assert (
        counts[:, 1].tolist()
        == np.bincount(
            batch.node_sample[batch.edges["spatial"].index[0]], minlength=batch.n_samples
        ).tolist()
    )
    scaler = train_ranges(rec, hood, history, np.ones(len(egos), bool))
    assert scaler.high["distance_m"] == pytest.approx(batch.edges["spatial"].attribute.max())

    # Collate and the model: a GAT of its own per layer, named by the type.
    collated = Collate(scaler, layers=2)([batch])
    assert collated.edges["ego"].index.shape == (2, len(actors))
    assert collated.edges["ego"].attr.shape == (len(actors), 1)
    model = AiGem(ModelConfig(layers=2, edge_types=config.edge_types)).eval()
    assert "encoder.1.ego.lin.weight" in model.state_dict()
    added = sum(count_parameters(layer.ego) for layer in model.encoder)
    assert count_parameters(model) == base_parameters + added and added > 0
    with torch.no_grad():
        out = model(collated, steps=3)
    assert out.shape == (len(batch.target_node), 3, 2) and torch.isfinite(out).all()

    # PyG and the export.
    one = induce_graphs(rec, egos[:1].astype(np.int32), starts[:1], config)
    data = to_hetero_data(one, scaler)
    assert data["vehicle", "ego", "vehicle"].edge_index.shape[1] == len(one.edges["ego"].attribute)
    assert torch.equal(
        to_model_batch(data).edges["ego"].index, data["vehicle", "ego", "vehicle"].edge_index
    )
    tables = graph_tables(batch, np.arange(batch.n_samples))
    assert list(tables) == ["nodes", "spatial_edges", "temporal_edges", "ego_edges", "targets"]
    assert tables["ego_edges"].height == len(actors)
    assert tables["ego_edges"][s.DISTANCE_M].sum() == pytest.approx(ego_edges.attribute.sum())


# ------------------------------------------------------------------------------------------------
# A newcomer's edge type: lane-neighbour edges, registered here and taken from build to evaluate.

LANE_WIDTH_M = 3.7  # NGSIM's lanes are 12 ft


def _adjacent_lanes(rec: RecordingArrays, rows: np.ndarray) -> np.ndarray:
    """(C, 2) rows of proximity pairs -> (C,) whether the two drive in adjacent lanes: their
    lateral offset is one lane width, give or take half of one."""
    offset = np.abs(rec.node_state[rows[:, 0], 0] - rec.node_state[rows[:, 1], 0])
    return (offset > 0.5 * LANE_WIDTH_M) & (offset <= 1.5 * LANE_WIDTH_M)


def _lane_induce(nodes: edges.Nodes) -> tuple[np.ndarray, np.ndarray]:
    """Actor <-> actor in adjacent lanes within d_min, both ways; attribute: their distance."""
    a, b, distance = edges.actor_pair_edges(nodes, _adjacent_lanes)
    return edges.by_sample(
        nodes.node_sample, np.concatenate([a, b]), np.concatenate([b, a]), np.tile(distance, 2)
    )


def _lane_count(near: edges.Near) -> edges.RowEdges:
    pairs, low, high = edges.actor_pairs(near, _adjacent_lanes)
    return edges.RowEdges(2 * pairs, low, high)


LANE = edges.EdgeType(
    name="lane",
    attribute=s.DISTANCE_M,
    scaled=True,
    steps_ahead=0,
    induce=_lane_induce,
    count=_lane_count,
)
WITH_LANE = ("spatial", "temporal", "lane")


def lane_scene() -> pl.DataFrame:
    """Steps 0..3, every vehicle 10 m further each step. Track 0, the ego, at x 0; track 1 at x 0
    (the ego's lane) 10 m ahead; track 2 one lane right (x 3.7), 12 m ahead; track 3 two lanes
    right (x 7.4), 10 m ahead; track 4 one lane right, 40 m ahead (a node: within d_sense, but 28
    m from track 2 and more from track 3: beyond d_min)."""
    start = {0: (0.0, 0.0), 1: (0.0, 10.0), 2: (3.7, 12.0), 3: (7.4, 10.0), 4: (3.7, 40.0)}
    rows = [
        (step, track, 20 + track, x, y + 10.0 * step, 0.0, 10.0)
        for track, (x, y) in start.items()
        for step in range(4)
    ]
    return grid_table(rows)


def test_lane_neighbour_edges_by_hand(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(edges.EDGE_TYPES, "lane", LANE)
    config = BuildConfig(history_steps=2, future_steps=2, stride_s=0.2, edge_types=WITH_LANE)
    rec = arrays_of(lane_scene(), config)
    egos, starts = np.array([0]), np.array([0])
    batch = induce_graphs(rec, egos.astype(np.int32), starts, config)
    assert list(batch.edges) == list(WITH_LANE)
    lane = batch.edges["lane"]
    track, step = batch.node_track, batch.node_step
    found = sorted(
        zip(step[lane.index[0]], track[lane.index[0]], track[lane.index[1]], strict=True)
    )
    # 1 <-> 2 and 2 <-> 3 at both history steps; not 1 - 3 (two lanes), 0 (the ego), 4 (far).
    assert [tuple(map(int, f)) for f in found] == [
        (k, a, b) for k in (0, 1) for a, b in ((1, 2), (2, 1), (2, 3), (3, 2))
    ]
    np.testing.assert_allclose(lane.attribute, math.hypot(3.7, 2.0), rtol=1e-6)
    history = history_rows(rec, egos, starts, config)
    counts = sample_counts(neighbourhoods(rec, history, config), history, config)
    columns = edges.count_columns(config.edge_types)
    assert columns[3] == "n_lane_edges" and counts[0, 3] == 8
    assert counts[0, 1] == len(batch.edges["spatial"].attribute)


def test_a_lane_neighbour_edge_type_goes_from_build_to_evaluate(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, tiny_build: Path
) -> None:
    """Registered in EDGE_TYPES and named by the build: the samples' count column, the stats,
    the model's GATs (its checkpoint's keys) and evaluate follow the build; evaluate refuses a
    build of the paper's two types (tiny_build: the same inputs) for the run."""
    monkeypatch.setitem(edges.EDGE_TYPES, "lane", LANE)
    build, run = tmp_path / "build", tmp_path / "run"
    raw = tiny_build.parent / "raw"  # SynthConfig(recordings=1, minutes=0.4, seed=11)
    args = ["build", str(raw), "--out", str(build), "--jobs", "1"]
    args += ["--d-sense-m", "12", "--d-min-m", "6", "--edge-types", ",".join(WITH_LANE)]
    result = CliRunner().invoke(ngsim_app, args)
    assert result.exit_code == 0, result.output
    opened = open_build(build)
    assert opened.config.edge_types == WITH_LANE
    assert json.loads((build / "manifest.json").read_text())["config"]["edge_types"] == [*WITH_LANE]
    samples = opened.samples("train")
    assert samples.columns[-3:] == ["n_lane_edges", "n_targets", "n_targets_full_future"]
    ids = np.arange(samples.height)
    graphs = opened.graphs("train", ids)
    per_sample = np.bincount(graphs.node_sample[graphs.edges["lane"].index[0]], minlength=len(ids))
    assert samples["n_lane_edges"].to_list() == per_sample.tolist() and per_sample.sum() > 0
    stats = CliRunner().invoke(ngsim_app, ["stats", str(build)])
    assert stats.exit_code == 0 and "lane edges" in stats.stdout

    fit = ["fit", str(build), "--out", str(run), "--epochs", "1", "--batch-size", "8"]
    fit += ["--horizon-s", "2", "--device", "cpu", "--workers", "0"]
    result = CliRunner().invoke(aigem_app, fit)
    assert result.exit_code == 0, result.output
    weights = torch.load(run / "best.pt", weights_only=True)["model"]
    for layer in range(ModelConfig().layers):
        assert f"encoder.{layer}.lane.lin.weight" in weights
    assert json.loads((run / "run.json").read_text())["model"]["edge_types"] == [*WITH_LANE]
    result = CliRunner().invoke(aigem_app, ["evaluate", str(run), "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert "ADE" in result.stdout
    other = ["evaluate", str(run), "--data", str(tiny_build), "--other-build", "--device", "cpu"]
    result = CliRunner().invoke(aigem_app, other)
    assert result.exit_code != 0
    assert (
        f"{tiny_build}: its graphs have edge types spatial, temporal; the run's model has a GAT "
        "for each of spatial, temporal, lane"
    ) in " ".join(result.output.split())
    # A build of an edge type this version does not know is refused on opening, in one line.
    monkeypatch.delitem(edges.EDGE_TYPES, "lane")
    with pytest.raises(NgsimInputError, match="edge_types names unknown 'lane'"):
        open_build(build)


def test_build_refuses_an_unknown_edge_type_naming_the_option(tmp_path: Path) -> None:
    args = ["build", str(tmp_path), "--out", str(tmp_path / "build"), "--edge-types", "lanes"]
    result = CliRunner().invoke(ngsim_app, args)
    assert result.exit_code == 2 and not (tmp_path / "build").exists()
    assert result.output.strip().splitlines()[-1] == (
        "error: --edge-types names unknown 'lanes': this ngsim-graphs knows spatial, temporal"
    )
