"""The memory-mapped dataset, the collate function and the HeteroData view."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from test_aigem_batch import same_batches
from torch.utils.data import DataLoader

from aigem.model.batch import Batch
from aigem.model.data import Collate, GraphDataset, xy_to_metres
from aigem.runs.baseline import constant_velocity
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import config_hash, write_manifest_json
from ngsim_graphs.scaling import MinMaxScaler


def test_batches_equal_the_induced_graphs_scaled(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "train")
    assert len(dataset) == open_build(tiny_build).manifest.splits["train"] > 4
    ids = [3, 0, 2]
    batch = Collate(dataset.scaler)(dataset.__getitems__(ids))
    one_by_one = Collate(dataset.scaler)([dataset[i] for i in ids])
    same_batches(batch, one_by_one)
    assert batch.graphs == 3 and batch.plan is None
    assert batch.edge_types == ("spatial", "temporal")  # the build's, in its order
    graphs = open_build(tiny_build).graphs("train", np.array(ids))
    ranges = json.loads((tiny_build / "manifest.json").read_text())["scaler"]
    expected_x = MinMaxScaler.from_dict(ranges).scale("x_m", graphs.node_features[:, 0])
    assert np.allclose(batch.x[:, 0].numpy(), expected_x, atol=1e-6)
    spatial, temporal = batch.edges["spatial"], batch.edges["temporal"]
    assert batch.x.dtype == torch.float32 and spatial.attr.shape == (
        graphs.edges["spatial"].index.shape[1],
        1,
    )
    assert torch.equal(spatial.index, torch.from_numpy(graphs.edges["spatial"].index))
    assert float(spatial.attr.min()) >= -1e-6 and float(temporal.attr.max()) == pytest.approx(0.2)
    assert torch.equal(batch.target_xy, torch.from_numpy(graphs.target_xy.astype(np.float32)))
    metres = xy_to_metres(dataset.scaler, batch.x[:, :2].double())
    assert np.allclose(metres.numpy(), graphs.node_features[:, :2], atol=1e-4)


def test_cv_step_is_constant_velocitys_step_in_scaled_units(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "train")
    batch = Collate(dataset.scaler)(dataset.__getitems__([0, 1, 2, 3]))
    state = batch.target_state.double().numpy()  # (A, 4) metres
    expected = constant_velocity(state, 3, 0.2)  # (A, 3, 2) metres
    start = batch.x[batch.target_node, :2].double()
    k = torch.arange(1, 4, dtype=torch.float64)[None, :, None]
    carried = start[:, None, :] + k * batch.cv_step.double()[:, None, :]
    assert batch.cv_step.shape == (len(state), 2) and len(state) > 2
    assert np.allclose(xy_to_metres(dataset.scaler, carried).numpy(), expected, atol=1e-3)
    assert float(batch.cv_step.abs().max()) > 1e-3  # the targets move


def test_a_batch_is_induced_once_per_recording_grouped_by_recording(
    two_recording_build: Path,
) -> None:
    dataset = GraphDataset(two_recording_build, "train")
    recording = open_build(two_recording_build).sample_arrays("train")["recording_index"]
    first, second = np.flatnonzero(recording == 0), np.flatnonzero(recording == 1)
    assert len(first) >= 2 and len(second) >= 2
    ids = [int(second[1]), int(first[1]), int(second[0]), int(first[0])]
    expected_order = [int(first[1]), int(first[0]), int(second[1]), int(second[0])]
    batch = Collate(dataset.scaler)(dataset.__getitems__(ids))
    one_by_one = Collate(dataset.scaler)([dataset[i] for i in expected_order])
    same_batches(batch, one_by_one)
    # batch_order names the sample of each graph of the batch, as evaluation relies on
    assert dataset.batch_order(ids).tolist() == expected_order


def test_loader_with_two_workers_gives_the_same_batches(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "train")
    collate = Collate(dataset.scaler, layers=2)
    plain = list(DataLoader(dataset, batch_size=4, collate_fn=collate))
    workers = list(DataLoader(dataset, batch_size=4, collate_fn=collate, num_workers=2))
    assert len(plain) == len(workers)
    for a, b in zip(plain, workers, strict=True):
        assert isinstance(b, Batch)
        same_batches(a, b, but=("plan",))
        plans = a.plan, b.plan
        assert plans[0].sizes == plans[1].sizes and torch.equal(plans[0].order, plans[1].order)


def test_a_given_scaler_replaces_the_builds(tiny_build: Path) -> None:
    """Evaluation on another build scales inputs as in training: with the run's scaler."""
    own = GraphDataset(tiny_build, "val")
    ranges = json.loads(json.dumps(own.scaler.to_dict()))
    ranges["x_m"]["max"] = ranges["x_m"]["max"] + 10.0  # a wider x range: smaller scaled x
    other = GraphDataset(tiny_build, "val", scaler=MinMaxScaler.from_dict(ranges))
    assert other.scaler.to_dict()["x_m"]["max"] == own.scaler.to_dict()["x_m"]["max"] + 10.0
    a, b = (Collate(d.scaler)(d.__getitems__([0, 1])) for d in (own, other))
    expected = MinMaxScaler.from_dict(ranges).scale(
        "x_m", own.__getitems__([0, 1])[0].node_features[:, 0]
    )
    assert np.allclose(b.x[:, 0].numpy(), expected, atol=1e-6)
    assert not torch.allclose(a.x[:, 0], b.x[:, 0])
    assert torch.equal(a.x[:, 1:], b.x[:, 1:])  # y, heading, speed as before


def test_an_unknown_split_is_refused_naming_the_splits(tiny_build: Path) -> None:
    with pytest.raises(ValueError) as wrong:
        GraphDataset(tiny_build, "testing")
    assert str(wrong.value) == "split 'testing': must be one of train, val, test"


def test_refuses_unfinished_builds_and_unknown_versions(tiny_build: Path, tmp_path: Path) -> None:
    with pytest.raises(NgsimInputError, match="not a build"):
        GraphDataset(tmp_path, "train")
    copy = tmp_path / "copy"
    copy.mkdir()
    manifest = json.loads((tiny_build / "manifest.json").read_text())
    (copy / "manifest.json").write_text(json.dumps({**manifest, "format_version": 99}))
    with pytest.raises(NgsimInputError, match="format version 99"):
        GraphDataset(copy, "train")
    # A newer ngsim-graphs' setting, in a manifest sealed as that version would seal it.
    config = {**manifest["config"], "new_rule": 1}
    hashed = config_hash(config, manifest["limits"])
    write_manifest_json(copy, {**manifest, "config": config, "config_hash": hashed})
    with pytest.raises(NgsimInputError, match="unknown build settings"):
        GraphDataset(copy, "train")
