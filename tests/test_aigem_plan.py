"""The plan of a batch (aigem.plan): made beforehand or in the step, the same; the CSR product
of the CPU and the gather-scatter of accelerators, the same."""

from __future__ import annotations

import torch

from aigem.config import ModelConfig
from aigem.model import AiGem
from aigem.plan import make_plan


def test_cpu_sparse_aggregation_equals_the_accelerator_gather_scatter() -> None:
    """The CSR product used on the CPU and the gather-scatter used on GPUs: same values and
    gradients, including destinations without edges and sources that no edge reads."""
    from aigem.plan import _AttentionSpMM, _gather_scatter

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
    from aigem.data import Collate, GraphDataset

    dataset = GraphDataset(tiny_build, "train", history_steps=5)
    ids = list(range(min(8, len(dataset))))
    for layers in (2, 4):
        planned = Collate(dataset.scaler, layers=layers)(dataset.__getitems__(ids))
        plain = {k: v for k, v in planned.items() if k != "plan"}
        plan = planned["plan"]
        edges = [
            (plain["spatial_edges"], plain["spatial_attr"]),
            (plain["temporal_edges"], plain["temporal_attr"]),
        ]
        again = make_plan(len(plain["x"]), plain["target_node"], edges, layers)
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
