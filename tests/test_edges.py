"""The edge types' one home: the registry's defaults, and a new type registered from a test that
goes through induction, counting, the scaler, Collate, the model, PyG and the export."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_graphs import SCENE_CONFIGS, all_windows, random_scene
from test_neighbourhoods import arrays_of

from aigem.config import ModelConfig
from aigem.data import Collate
from aigem.model import AiGem, count_parameters
from aigem.pyg import to_hetero_data, to_model_batch
from ngsim_graphs import edges
from ngsim_graphs import schema as s
from ngsim_graphs.export import export_tables, graph_tables
from ngsim_graphs.graphs import induce_graphs
from ngsim_graphs.neighbourhoods import history_rows, neighbourhoods, sample_counts
from ngsim_graphs.scaling import SCALED, train_ranges


def test_the_default_edge_types_make_the_build_columns_and_the_scaler() -> None:
    assert [e.name for e in edges.EDGE_TYPES] == ["spatial", "temporal"]
    assert edges.count_columns() == s.COUNT_COLUMNS
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
    count_column="n_ego_edges",
    attribute=s.DISTANCE_M,
    scaled=True,
    steps_ahead=0,
    induce=_ego_induce,
    count=_ego_count,
)


def test_a_new_edge_type_goes_through_every_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    base_parameters = count_parameters(AiGem(ModelConfig(layers=2)))
    monkeypatch.setattr(edges, "EDGE_TYPES", (*edges.EDGE_TYPES, EGO))
    config = SCENE_CONFIGS[0]
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
    assert edges.count_columns()[3] == "n_ego_edges"
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
    assert collated["ego_edges"].shape == (2, len(actors))
    assert collated["ego_attr"].shape == (len(actors), 1)
    model = AiGem(ModelConfig(layers=2)).eval()
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
        to_model_batch(data)["ego_edges"], data["vehicle", "ego", "vehicle"].edge_index
    )
    tables = graph_tables(batch, np.arange(batch.n_samples))
    assert list(tables) == ["nodes", "spatial_edges", "temporal_edges", "ego_edges", "targets"]
    assert tables["ego_edges"].height == len(actors)
    assert tables["ego_edges"][s.DISTANCE_M].sum() == pytest.approx(ego_edges.attribute.sum())
