"""A split on the device and its static batches (aigem.training.resident): the loader's graphs, padded to
a capacity, and a padded step that is the unpadded one (loss, gradients, parameters after Adam)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from aigem.config import ModelConfig
from aigem.model import plan as aigem_plan
from aigem.model.batch import Batch, Edges
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem
from aigem.training import capacity, ensemble, loading
from aigem.training.capacity import Capacity
from aigem.training.loading import load_split
from aigem.training.resident import ResidentSplit

LAYERS = ModelConfig().layers
STEPS = (5, 25)  # the members of the ensembles stepped here


@pytest.fixture(scope="module")
def data(tiny_build: Path) -> tuple[GraphDataset, ResidentSplit]:
    dataset = GraphDataset(tiny_build, "train", history_steps=LAYERS + 1)
    return dataset, load_split(dataset, LAYERS)


def _ids(dataset: GraphDataset, count: int, seed: int) -> np.ndarray:
    """`count` random samples in the loader's order (by recording)."""
    picked = np.random.default_rng(seed).choice(len(dataset), count, replace=False)
    return dataset.batch_order(picked)


def _padded(split: ResidentSplit, ids: np.ndarray, size: int) -> torch.Tensor:
    return torch.tensor(list(ids) + [split.empty_id] * (size - len(ids)))


def _exact(split: ResidentSplit, ids: np.ndarray) -> Capacity:
    """The capacity a batch of `ids` meets exactly."""
    return Capacity(len(ids), tuple(int(v) for v in split.counts[ids].sum(0)), split.layers)


def test_a_static_batch_holds_the_loaders_graphs(data: tuple[GraphDataset, ResidentSplit]) -> None:
    dataset, split = data
    ids = _ids(dataset, 6, seed=1)
    loader = Collate(dataset.scaler, layers=LAYERS)(dataset.__getitems__(ids))
    base = capacity.base_capacity(split.counts, 8, LAYERS)
    static = split.batch(_padded(split, ids, 8), base)
    targets = len(loader.target_node)
    assert static.target_node.shape == (base.targets,) and targets < base.targets
    assert static.graphs == 8 and static.edges == {} and static.node_sample is None
    for key in ("target_xy", "target_mask", "target_state", "cv_step"):
        assert torch.equal(getattr(static, key)[:targets], getattr(loader, key)), key
        assert not getattr(static, key)[targets:].any(), key  # padding: nothing
    assert torch.equal(static.target_sample[:targets], loader.target_sample)
    assert bool((static.target_sample[targets:] == -1).all())
    plan = static.plan
    assert plan.order is None and plan.sizes == sorted(plan.sizes, reverse=True)
    assert plan.sizes[-1] == base.targets + 1  # the targets and their segment's sink
    model = AiGem(ModelConfig()).eval()
    for sparse in (True, False):
        aigem_plan.CPU_SPARSE = sparse
        try:
            with torch.no_grad():
                padded, plain = model(static, 25)[:targets], model(loader, 25)
        finally:
            aigem_plan.CPU_SPARSE = True
        torch.testing.assert_close(padded, plain, rtol=1e-5, atol=1e-5)


def test_edges_come_in_the_order_of_their_destinations(
    data: tuple[GraphDataset, ResidentSplit],
) -> None:
    """A CSR order: each layer's edges a prefix of each type's, padding edges at their
    segment's sink (the last slot of its destinations' segment), rows pointing into them."""
    dataset, split = data
    static = split.batch(
        _padded(split, _ids(dataset, 5, 2), 8), capacity.base_capacity(split.counts, 8, LAYERS)
    )
    plan = static.plan
    for adjacency in plan.adjacency:
        assert bool((adjacency.row.diff() >= 0).all())
        assert torch.equal(
            adjacency.crow, torch.searchsorted(adjacency.row, torch.arange(plan.sizes[1] + 1))
        )
        padding = adjacency.attr[:, 0] == 0
        assert torch.equal(adjacency.col[padding], adjacency.row[padding])  # sink to sink
        for layer in range(1, LAYERS + 1):
            end = adjacency.ends[plan.sizes[layer]]
            assert bool((adjacency.row[:end] < plan.sizes[layer]).all())
            assert bool((adjacency.col[:end] < plan.sizes[layer - 1]).all())


def _double(split: ResidentSplit) -> ResidentSplit:
    """The split's floating values in float64 (Adam's rounding is then far below any defect)."""
    edges = tuple(replace(table, attr=table.attr.double()) for table in split.edges)
    targets = split.targets.map(lambda v: v.double() if v.is_floating_point() else v)
    return replace(split, x=split.x.double(), edges=edges, targets=targets, layouts={})


def _steps(batches: list[Batch], scaler) -> list[tuple]:  # noqa: ANN001
    """Three Adam steps of a two-member ensemble (float64, dropout 0, clipping): each step's
    losses, gradients and the parameters after it."""
    torch.manual_seed(0)
    models = [AiGem(ModelConfig(dropout=0.0)).double() for _ in STEPS]
    stacked = ensemble.stack(models, STEPS)
    optimizers = [torch.optim.Adam(m.parameters(), lr=1e-2) for m in models]
    optimizer = ensemble.stack_optimizer(stacked, optimizers)
    out = []
    for batch in batches:
        optimizer.zero_grad(set_to_none=True)
        losses = stacked.member_losses(stacked(batch), batch, scaler)
        losses.sum().backward()
        stacked.clip_gradients(0.5)
        grads = [p.grad.clone() for p in stacked.parameters()]
        optimizer.step()
        out.append((losses.detach(), grads, [p.detach().clone() for p in stacked.parameters()]))
    return out


def _assert_same_steps(padded: list[tuple], plain: list[tuple]) -> None:
    for (losses, grads, params), (losses_, grads_, params_) in zip(padded, plain, strict=True):
        torch.testing.assert_close(losses, losses_, rtol=1e-12, atol=0.0)
        for a, b in zip(grads + params, grads_ + params_, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("layout", ["base", "exact", "tier-2"])
def test_a_padded_step_is_the_unpadded_step(
    data: tuple[GraphDataset, ResidentSplit], layout: str
) -> None:
    dataset, split = data
    split = _double(split)
    batch_ids = [_ids(dataset, 5, seed) for seed in (3, 4, 5)]
    base = capacity.base_capacity(split.counts, 8, LAYERS)
    static = []
    for ids in batch_ids:
        cap = {"base": base, "exact": _exact(split, ids), "tier-2": capacity.tier(base, 2)}[layout]
        static.append(split.batch(_padded(split, ids, cap.samples), cap))
    collate = Collate(dataset.scaler, layers=LAYERS)
    plain = [collate(dataset.__getitems__(ids)).to(dtype=torch.float64) for ids in batch_ids]
    _assert_same_steps(_steps(static, dataset.scaler), _steps(plain, dataset.scaler))


# ------------------------------------------------------------------------------------------------
# Graphs made by hand: a graph of one node, a batch with no actor-actor edge


def _hand_batch() -> Batch:
    """Three samples. Sample 0: one node, its only target, no edge. Sample 1, two steps: the ego
    (1) and an actor (2), then the ego (3) and actors 4 and 5 (the targets); spatial edges ego
    <-> actor only, temporal 1 -> 3, 2 -> 4. Sample 2: the ego alone, no target: nothing kept."""
    generator = torch.Generator().manual_seed(2)
    floats = lambda *shape: torch.rand(*shape, generator=generator, dtype=torch.float64)  # noqa: E731
    targets = 3
    return Batch(
        x=floats(7, 4) * 2 - 1,
        target_node=torch.tensor([0, 4, 5]),
        target_sample=torch.tensor([0, 1, 1]),
        target_xy=floats(targets, 25, 2) * 30,
        target_mask=floats(targets, 25) > 0.2,
        edges={  # as Collate names them
            "spatial": Edges(torch.tensor([[1, 2, 3, 4, 3, 5], [2, 1, 4, 3, 5, 3]]), floats(6, 1)),
            "temporal": Edges(
                torch.tensor([[1, 2], [3, 4]]), torch.full((2, 1), 0.2, dtype=torch.float64)
            ),
        },
        node_sample=torch.tensor([0, 1, 1, 1, 1, 1, 2]),
        target_state=floats(targets, 4),
        cv_step=floats(targets, 2) * 0.01,
        graphs=3,
    )


@pytest.mark.parametrize("exact", [False, True], ids=["padded", "met-exactly"])
def test_a_graph_of_one_node_and_no_actor_actor_edge(
    data: tuple[GraphDataset, ResidentSplit], exact: bool
) -> None:
    hand = _hand_batch()
    split = loading._join([loading._chunk(hand, np.arange(3), LAYERS)], LAYERS, 3, 2)
    assert split.counts[:, 0].tolist() == [1, 2, 0]  # the targets: one, two, none
    assert split.counts[2].sum() == 0  # nothing of sample 2 is read by any layer
    ids = np.arange(3)
    cap = _exact(split, ids) if exact else capacity.base_capacity(split.counts, 3, LAYERS)
    static = split.batch(torch.from_numpy(ids), cap)
    scaler = data[0].scaler
    _assert_same_steps(_steps([static] * 3, scaler), _steps([hand] * 3, scaler))
