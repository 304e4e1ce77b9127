"""The plan of a batch (aigem.model.plan): made beforehand or in the step, the same; the CSR product
of the CPU and the gather-scatter of accelerators, the same."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from aigem.config import ModelConfig
from aigem.model.network import AiGem
from aigem.model.plan import make_plan, segment_softmax


def test_cpu_sparse_aggregation_equals_the_accelerator_gather_scatter() -> None:
    """The CSR product used on the CPU and the gather-scatter used on GPUs: same values and
    gradients, including destinations without edges and sources that no edge reads."""
    from aigem.model.plan import _AttentionSpMM, _gather_scatter

    n_dst, n_src, channels = 7, 10, 3
    dst = torch.tensor([0, 0, 1, 3, 3, 3, 5, 6, 6])  # destinations 2 and 4 have none
    col = torch.tensor([1, 4, 0, 2, 4, 9, 3, 0, 8])  # sorted by (destination, source)
    crow = torch.cat(
        [torch.zeros(1, dtype=torch.long), torch.bincount(dst, minlength=n_dst).cumsum(0)]
    )
    results = []
    for path in ("csr", "gather"):
        values = torch.linspace(0.1, 0.9, len(col), dtype=torch.float64).requires_grad_()
        x = torch.randn(
            n_src, channels, dtype=torch.float64, generator=torch.Generator().manual_seed(6)
        )
        x.requires_grad_(True)
        if path == "csr":
            out = _AttentionSpMM.apply(values, x, crow, col)
        else:
            out = _gather_scatter(values, x, n_dst, col, dst)
        (out * torch.arange(out.numel(), dtype=torch.float64).view_as(out)).sum().backward()
        results.append((out.detach(), values.grad, x.grad))
    for a, b in zip(*results, strict=True):
        assert torch.allclose(a, b, atol=1e-12)
    assert results[0][0][2].abs().sum() == 0 and results[0][2][5].abs().sum() == 0  # no edges there
    assert torch.allclose(results[0][0][1], 0.3 * x.detach()[0])  # one edge 0 -> 1, weight 0.3


def test_a_plan_made_with_the_batch_gives_the_same_output_and_gradients(tiny_build) -> None:  # noqa: ANN001, F811
    """Collate(layers=L) plans in the loader; the step then uses that plan, bit for bit the one
    the model would have made; a plan made for another L is not used."""
    from aigem.model.data import Collate, GraphDataset

    dataset = GraphDataset(tiny_build, "train", history_steps=5)
    ids = list(range(min(8, len(dataset))))
    for layers in (2, 4):
        planned = Collate(dataset.scaler, layers=layers)(dataset.__getitems__(ids))
        plain = replace(planned, plan=None)
        plan = planned.plan
        edges = plain.edge_inputs(("spatial", "temporal"))
        again = make_plan(len(plain.x), plain.target_node, edges, layers)
        assert (
            plan.sizes == again.sizes and plan.layers == layers and plan.sizes[0] > plan.sizes[-1]
        )
        assert torch.equal(plan.order, again.order) and torch.equal(plan.outputs, again.outputs)
        for a, b in zip(plan.adjacency, again.adjacency, strict=True):
            assert a.ends == b.ends and all(
                torch.equal(x, y)
                for x, y in zip(a.prefix(plan.sizes[1]), b.prefix(plan.sizes[1]), strict=False)
            )
            # ends[n] counts the edges into the first n destinations; row expands crow
            assert a.ends[plan.sizes[-1]] == int(a.crow[plan.sizes[-1]])
            assert torch.equal(
                a.row, torch.repeat_interleave(torch.arange(plan.sizes[1]), a.crow.diff())
            )
        model = AiGem(ModelConfig(layers=4))
        results = []
        for batch in (planned, plain):
            torch.manual_seed(4)  # the same dropout masks
            out = model(batch)
            grads = torch.autograd.grad(
                out.square().sum(), list(model.parameters()), allow_unused=True
            )
            results.append((out, grads))
        assert torch.equal(results[0][0], results[1][0])
        for a, b in zip(results[0][1], results[1][1], strict=True):
            assert (a is None and b is None) or torch.equal(a, b)


@pytest.mark.parametrize("sparse", [True, False], ids=["segment-reduce", "scatter"])
def test_segment_softmax_is_pygs_softmax(sparse: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Values and gradients of PyG's softmax, over rows with no edge (first, middle and last)
    and scores far apart, on the CPU's path and on the accelerators'."""
    from torch_geometric.utils import softmax

    from aigem.model import plan as aigem_plan

    monkeypatch.setattr(aigem_plan, "CPU_SPARSE", sparse)
    dst = torch.tensor([1, 1, 1, 3, 4, 4])  # rows 0, 2 and 5 have none
    crow = torch.cat([torch.zeros(1, dtype=torch.long), torch.bincount(dst, minlength=6).cumsum(0)])
    scores = torch.tensor(
        [[0.5, -1.0], [2.0, 300.0], [-1.5, 0.0], [7.0, 1.0], [-200.0, 2.0], [1.0, 2.0]],
        dtype=torch.float64,
        requires_grad=True,
    )
    weights = torch.arange(12, dtype=torch.float64).view(6, 2)
    ours = segment_softmax(scores, crow, dst)
    theirs = softmax(scores, dst, num_nodes=6)
    torch.testing.assert_close(ours, theirs, rtol=1e-15, atol=1e-15)
    assert torch.allclose(ours[:3].sum(0), torch.ones(2, dtype=torch.float64))  # row 1's edges
    assert torch.equal(ours[3], torch.ones(2, dtype=torch.float64))  # row 3's one edge
    ours_grad = torch.autograd.grad((ours * weights).sum(), scores)[0]
    theirs_grad = torch.autograd.grad((theirs * weights).sum(), scores)[0]
    torch.testing.assert_close(ours_grad, theirs_grad, rtol=1e-12, atol=1e-12)
