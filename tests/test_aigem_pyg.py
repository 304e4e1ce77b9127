"""PyTorch Geometric's view: per-sample HeteroData that PyG's own DataLoader batches correctly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_aigem_batch import same_batches
from torch_geometric.loader import DataLoader as PygLoader

from aigem.config import ModelConfig
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem
from aigem.model.pyg import SPATIAL, TEMPORAL, GraphPygDataset, to_hetero_data, to_model_batch
from ngsim_graphs.build import open_build

PYG_LACKS = ("target_state", "cv_step", "plan")  # of Collate's batch (to_model_batch)


def _pyg_and_ours(build: Path, split: str, ids: list[int], history_steps: int | None):
    """PyG's batch of samples `ids` (in that order), our Collate batch of the same samples, and
    the induced graphs of our batch's order (grouped by recording)."""
    pyg = GraphPygDataset(build, split, history_steps=history_steps)
    (batch,) = list(PygLoader(pyg[ids], batch_size=len(ids), shuffle=False))
    ours = GraphDataset(build, split, history_steps=history_steps)
    graphs = ours.__getitems__(ids)
    return batch, Collate(ours.scaler)(graphs), graphs[0]


@pytest.mark.parametrize("history_steps", [None, 5])
def test_pyg_batch_equals_our_batch(tiny_build: Path, history_steps: int | None) -> None:
    ids = list(range(6))  # one recording: our batch keeps this order
    batch, ours, graphs = _pyg_and_ours(tiny_build, "val", ids, history_steps)
    node = batch["vehicle"]
    assert torch.equal(node.x, ours.x)
    assert torch.equal(node.batch, ours.node_sample)
    assert torch.equal(batch.sample_id, torch.tensor(ids))
    assert torch.equal(node.step, torch.from_numpy(graphs.node_step.astype(np.int64)))
    assert torch.equal(node.is_ego, torch.from_numpy(graphs.node_is_ego))
    assert torch.equal(node.track_id, torch.from_numpy(graphs.node_track.astype(np.int64)))
    assert int(node.is_ego.sum()) == len(ids) * int(node.step.unique().numel())  # an ego a step
    for edge_type, key in ((SPATIAL, "spatial"), (TEMPORAL, "temporal")):
        assert torch.equal(batch[edge_type].edge_index, ours.edges[key].index), edge_type
        assert torch.equal(batch[edge_type].edge_attr, ours.edges[key].attr), edge_type
    # The targets: the mask picks exactly our target nodes, in our order, with our ground truth.
    target = torch.nonzero(node.is_target).squeeze(1)
    assert len(target) > len(ids) and torch.equal(target, ours.target_node)
    assert torch.equal(node.y[target], ours.target_xy)
    assert torch.equal(node.y_mask[target], ours.target_mask)
    assert not node.y_mask[~node.is_target].any() and not node.y[~node.is_target].any()
    # A target of a later sample points at a node of that sample (the bug of offset-less indices).
    assert torch.equal(node.batch[target], ours.target_sample)
    assert int(ours.target_sample.max()) == len(ids) - 1
    model_batch = to_model_batch(batch)
    same_batches(model_batch, ours, but=PYG_LACKS)
    model = AiGem(ModelConfig()).eval()
    with torch.no_grad():
        assert torch.equal(model(model_batch, 5), model(ours, 5))


def test_pyg_batch_across_recordings_in_our_order(two_recording_build: Path) -> None:
    """Our batches come grouped by recording; in that order PyG's batch is ours, node for node."""
    recording = open_build(two_recording_build).sample_arrays("train")["recording_index"]
    first, second = np.flatnonzero(recording == 0), np.flatnonzero(recording == 1)
    asked = [int(second[1]), int(first[1]), int(second[0]), int(first[0])]
    grouped = [int(first[1]), int(first[0]), int(second[1]), int(second[0])]
    batch, _, _ = _pyg_and_ours(two_recording_build, "train", grouped, None)
    ours = GraphDataset(two_recording_build, "train")
    expected = Collate(ours.scaler)(ours.__getitems__(asked))
    same_batches(to_model_batch(batch), expected, but=PYG_LACKS)


def test_one_sample_per_hetero_data(tiny_build: Path) -> None:
    dataset = GraphDataset(tiny_build, "val")
    data = to_hetero_data(dataset[3], dataset.scaler, sample_id=3)
    assert data.sample_id.tolist() == [3]
    same_batches(to_model_batch(data), Collate(dataset.scaler)([dataset[3]]), but=PYG_LACKS)
    assert set(data.edge_types) == {SPATIAL, TEMPORAL}
    assert GraphPygDataset(tiny_build, "val").len() == len(dataset)
    with pytest.raises(ValueError, match="one sample's graph expected, got 2"):
        to_hetero_data(dataset.__getitems__([0, 1])[0], dataset.scaler)


def test_the_dataset_says_its_build_split_and_size_and_summarizes_without_tabulate(
    tiny_build: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = GraphPygDataset(tiny_build, "val")
    assert repr(dataset) == (
        f"GraphPygDataset(build={str(tiny_build)!r}, split='val', samples={len(dataset)})"
    )
    assert dataset.root == str(tiny_build)  # PyG's "???" without one
    assert sorted(p.name for p in tiny_build.iterdir()) == sorted(  # no raw/, no processed/
        ["arrays", "manifest.json", "samples", "tracks"]
    )
    summary = dataset.get_summary()
    assert summary.num_graphs == len(dataset)
    dataset.print_summary()  # with or without the package tabulate
    printed = capsys.readouterr().out
    assert printed.startswith(f"GraphPygDataset (#graphs={len(dataset)}):")
    assert "(vehicle, spatial, vehicle)" in printed and "median" in printed


def test_plain_summary_columns_by_hand() -> None:
    from torch_geometric.data.summary import Stats

    from aigem.model.pyg import PlainSummary, _columns

    stats = Stats(mean=2.0, std=1.0, min=1.0, quantile25=1.5, median=2.0, quantile75=2.5, max=3.0)
    assert _columns({"#nodes": stats})[:3] == [
        "            #nodes",
        "      mean     2.0",
        "       std     1.0",
    ]
    text = PlainSummary("X", 2, stats, stats).format()
    assert text.splitlines()[0] == "X (#graphs=2):"
