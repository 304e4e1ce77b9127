"""The plan of a batch for AiGem's encoder, and the attention aggregation (docs/aigem.md).

Only the target actors' present-step embeddings are used downstream, so layer l runs only on the
nodes that layer l + 1 (or the decoder) reads: the (L - l)-hop in-neighbourhood of the targets. On
the full-scale build that is a third of the nodes at the input, a sixteenth at the last layer and a
sixth of the edge work for L = 4. A `Plan` orders the nodes so that every layer's input and output
sets are prefixes of one node order, and sorts each edge type's edges by (destination, source)
once: every layer's adjacency is then a prefix of one CSR matrix.

Two kinds of batch (`aigem.model.batch.Batch`) carry a plan:
- a loader's batch (`aigem.model.data.Collate(layers=L)`, or `make_plan` in the step): the plan is made
  for the batch's own sizes, on the host beforehand, so a step given it reads no number back;
- a static batch (`aigem.training.resident`): the nodes come already in plan order, padded to fixed
  capacities (`Plan.order` is None), so every batch of one capacity has the same shapes.

On the CPU the attention-weighted aggregation is a CSR sparse-dense product (`_AttentionSpMM`),
with a sampled dense-dense product for the gradient of the attention weights: no (E, H) message
tensor is materialised. Elsewhere it is PyG's gather -> multiply -> scatter, which accelerators
run well.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

# ------------------------------------------------------------------------------------------------
# The plan: pruned, relabelled, destination-sorted adjacency shared by all layers.


@dataclass(frozen=True)
class Adjacency:
    """One edge type's CSR adjacency over the reordered nodes; rows are destinations."""

    crow: torch.Tensor  # (n_1 + 1,) row pointers over the destinations any layer computes
    col: torch.Tensor  # (E,) source of each edge, edges sorted by (destination, source)
    row: torch.Tensor  # (E,) destination of each edge (crow expanded)
    attr: torch.Tensor  # (E, D) edge features in the same order
    ends: dict[int, int]  # n_dst -> crow[n_dst] for every layer's n_dst, known on the host

    def prefix(self, n_dst: int) -> tuple[torch.Tensor, ...]:
        """The adjacency of the first n_dst destinations: (crow, col, attr, row)."""
        end = self.ends[n_dst]
        return self.crow[: n_dst + 1], self.col[:end], self.attr[:end], self.row[:end]

    def to(
        self,
        device: torch.device | str | None,
        non_blocking: bool = False,
        dtype: torch.dtype | None = None,
    ) -> Adjacency:
        """On `device`, the attributes as `dtype` (None: as they are)."""
        move = lambda t: t.to(device, non_blocking=non_blocking)  # noqa: E731
        attr = self.attr.to(device, dtype=dtype, non_blocking=non_blocking)
        return Adjacency(move(self.crow), move(self.col), move(self.row), attr, self.ends)

    def pin_memory(self) -> Adjacency:
        pin = lambda t: t.pin_memory()  # noqa: E731
        return Adjacency(pin(self.crow), pin(self.col), pin(self.row), pin(self.attr), self.ends)


@dataclass(frozen=True)
class Plan:
    """Which nodes each layer computes: layer l (1..L) reads nodes [0, sizes[l-1]) and writes
    nodes [0, sizes[l]); node i of the plan is node order[i] of the batch (order None: the
    batch's nodes are in plan order already, as a static batch's are).

    Its sizes and edge counts are host integers, so a model step that is given a plan made
    beforehand (by `aigem.model.data.Collate`, in the DataLoader's workers, or with a static batch)
    never waits for the device.
    """

    order: torch.Tensor | None  # (sizes[0],) batch node ids in plan order (None: the identity)
    sizes: list[int]  # L + 1 prefix lengths, non-increasing
    adjacency: list[Adjacency]  # one per edge type
    outputs: torch.Tensor | None  # (A,) plan positions of the outputs asked for (None: all)

    @property
    def layers(self) -> int:
        return len(self.sizes) - 1

    def to(
        self,
        device: torch.device | str | None,
        non_blocking: bool = False,
        dtype: torch.dtype | None = None,
    ) -> Plan:
        """On `device`, the edges' attributes as `dtype` (None: as they are)."""
        move = lambda t: None if t is None else t.to(device, non_blocking=non_blocking)  # noqa: E731
        adjacency = [a.to(device, non_blocking, dtype) for a in self.adjacency]
        return Plan(move(self.order), self.sizes, adjacency, move(self.outputs))

    def pin_memory(self) -> Plan:
        """For the DataLoader's pin_memory (then copies to a GPU need not wait)."""
        pin = lambda t: None if t is None else t.pin_memory()  # noqa: E731
        adjacency = [a.pin_memory() for a in self.adjacency]
        return Plan(pin(self.order), self.sizes, adjacency, pin(self.outputs))


def node_levels(
    num_nodes: int, outputs: torch.Tensor | None, edge_indices: list[torch.Tensor], layers: int
) -> torch.Tensor:
    """(N,) int32: the last layer whose output at each node is needed, -1 where none is.

    L at the outputs (every node where `outputs` is None), and max(level[w] - 1) over the edges
    v -> w of every type (`edge_indices`: (2, E) each); L in-place relaxations reach the fixpoint.
    """
    device = edge_indices[0].device
    if outputs is None:
        return torch.full((num_nodes,), layers, dtype=torch.int32, device=device)
    level = torch.full((num_nodes,), -1, dtype=torch.int32, device=device)
    level[outputs] = layers
    buffers = [torch.empty(e.shape[1], dtype=torch.int32, device=device) for e in edge_indices]
    for _ in range(layers):
        for edge_index, buffer in zip(edge_indices, buffers, strict=True):
            torch.index_select(level, 0, edge_index[1], out=buffer).sub_(1)
            level.scatter_reduce_(0, edge_index[0], buffer, "amax")
    return level


def make_plan(
    num_nodes: int,
    outputs: torch.Tensor | None,
    edges: list[tuple[torch.Tensor, torch.Tensor]],
    layers: int,
) -> Plan:
    """Plan the layers for `outputs` (batch node ids whose final embedding is needed; None: all).

    `edges`: (edge_index (2, E), edge_attr (E, D) or (E,)) per edge type. Made on the device of
    the edges; on a GPU it reads a few numbers back (the sizes), so there it is best made on the
    host beforehand.
    """
    device = edges[0][0].device
    with torch.no_grad():
        level = node_levels(num_nodes, outputs, [index for index, _ in edges], layers)
        # A stable sort by descending level makes each layer's node set a prefix.
        order = torch.argsort(-level, stable=True)
        thresholds = torch.arange(layers + 1, device=device)[:, None]
        sizes = (level[None, :] >= thresholds).sum(1).tolist()
        order = order[: sizes[0]]
        new_id = torch.full((num_nodes,), -1, dtype=torch.long, device=device)
        new_id[order] = torch.arange(sizes[0], device=device)
        adjacency = []
        for edge_index, attr in edges:
            # edges into a node that some layer computes
            keep = torch.nonzero(level.index_select(0, edge_index[1]) >= 1).squeeze(1)
            src = new_id.index_select(0, edge_index[0].index_select(0, keep))
            dst = new_id.index_select(0, edge_index[1].index_select(0, keep))
            sort = torch.argsort(dst * max(sizes[0], 1) + src)  # by (destination, source)
            crow = torch.zeros(sizes[1] + 1, dtype=torch.long, device=device)
            crow[1:] = torch.cumsum(torch.bincount(dst, minlength=sizes[1]), 0)
            attr = attr.view(-1, 1) if attr.dim() == 1 else attr
            attr = attr.index_select(0, keep.index_select(0, sort))
            ends = dict(zip(sizes[1:], crow[sizes[1:]].tolist(), strict=False))
            adjacency.append(
                Adjacency(crow, src.index_select(0, sort), dst.index_select(0, sort), attr, ends)
            )
        targets = None if outputs is None else new_id.index_select(0, outputs)
    return Plan(order, sizes, adjacency, targets)


# ------------------------------------------------------------------------------------------------
# Attention aggregation: out = A @ x for the sparse matrix A of the attention weights.


def _csr(crow, col, values, shape: tuple[int, int]) -> torch.Tensor:  # noqa: ANN001
    with warnings.catch_warnings():  # "Sparse CSR tensor support is in beta state", once
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return torch.sparse_csr_tensor(crow, col, values, shape, check_invariants=False)


class _AttentionSpMM(torch.autograd.Function):
    """out[i] = sum over the edges e = (j -> i) of values[e] * x[j], as a CSR product;
    differentiable in values (E,) and x (n_src, C)."""

    @staticmethod
    def forward(ctx, values, x, crow, col):  # noqa: ANN001, ANN205
        n_dst = crow.numel() - 1
        ctx.save_for_backward(values, x, crow, col)
        if col.numel() == 0:
            return x.new_zeros(n_dst, x.shape[1])
        return torch.sparse.mm(_csr(crow, col, values, (n_dst, x.shape[0])), x)

    @staticmethod
    def backward(ctx, grad):  # noqa: ANN001, ANN205
        values, x, crow, col = ctx.saved_tensors
        n_dst, n_src = crow.numel() - 1, x.shape[0]
        grad_values = grad_x = None
        if col.numel() == 0:
            if ctx.needs_input_grad[0]:
                grad_values = torch.zeros_like(values)
            if ctx.needs_input_grad[1]:
                grad_x = torch.zeros_like(x)
            return grad_values, grad_x, None, None
        grad = grad.contiguous()
        values = values.detach()
        if ctx.needs_input_grad[0]:  # d out[i] / d values[e] = x[j]: grad @ x^T sampled at A
            pattern = _csr(crow, col, values, (n_dst, n_src))
            grad_values = torch.sparse.sampled_addmm(pattern, grad, x.detach().t(), beta=0.0)
            grad_values = grad_values.values()
        if ctx.needs_input_grad[1]:  # A^T @ grad, with A^T as CSR: the edges sorted by source
            arange = torch.arange(n_dst, device=col.device)
            row = torch.repeat_interleave(arange, crow.diff(), output_size=col.numel())
            by_source = torch.argsort(col, stable=True)
            crow_t = torch.zeros(n_src + 1, dtype=crow.dtype, device=crow.device)
            crow_t[1:] = torch.cumsum(torch.bincount(col, minlength=n_src), 0)
            transposed = _csr(crow_t, row[by_source], values[by_source], (n_src, n_dst))
            grad_x = torch.sparse.mm(transposed, grad)
        return grad_values, grad_x, None, None


CPU_SPARSE = True  # False: the accelerators' path on the CPU too (bench/bench_train.py counts it)


def aggregate(values, x, crow, col, dst) -> torch.Tensor:  # noqa: ANN001
    """(n_dst, C): out[i] = sum over the edges e = (j -> i) of values[e] * x[j].

    On the CPU a CSR product; elsewhere PyG's own gather -> multiply -> scatter, which
    accelerators run well. aigem.training.ensemble aggregates its members through it (and
    `segment_softmax`) over one block-diagonal graph.
    """
    if x.device.type == "cpu" and CPU_SPARSE:
        return _AttentionSpMM.apply(values, x, crow, col)
    return _gather_scatter(values, x, crow.numel() - 1, col, dst)


def _gather_scatter(values, x, n_dst: int, col, dst) -> torch.Tensor:  # noqa: ANN001
    """`aggregate` as PyG computes it: (E, C) messages values[e] * x[col[e]], summed at dst[e]."""
    messages = values.unsqueeze(-1) * x.index_select(0, col)  # (E, C)
    return x.new_zeros(n_dst, x.shape[1]).index_add_(0, dst, messages)


def _row_reduce(
    values: torch.Tensor, how: str, crow: torch.Tensor, dst: torch.Tensor
) -> torch.Tensor:
    """Each destination's "max" or "sum" of (E, heads) values over its edges, the edges in CSR
    order (`crow`: the destinations' row pointers, crow[-1] = E; dst[e] edge e's row). On the CPU
    `torch.segment_reduce` over the rows (five times faster there than PyG's scatters, which the
    accelerators keep); its offsets go unchecked, so `crow` must be the CSR rows of exactly these
    edges, as a Plan's are."""
    if values.device.type == "cpu" and CPU_SPARSE:
        return torch.segment_reduce(values, how, offsets=crow, unsafe=True)
    index = dst[:, None].expand_as(values)
    zeros = values.new_zeros(crow.numel() - 1, values.shape[1])
    if how == "max":
        return zeros.scatter_reduce_(0, index, values, "amax", include_self=False)
    return zeros.scatter_add_(0, index, values)


def segment_softmax(scores: torch.Tensor, crow: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """PyG's `softmax(scores, dst)`: softmax of (E, heads) scores over each destination's edges
    (in CSR order: `_row_reduce`)."""
    top = _row_reduce(scores.detach(), "max", crow, dst)
    out = (scores - top.index_select(0, dst)).exp()
    total = _row_reduce(out, "sum", crow, dst) + 1e-16
    return out / total.index_select(0, dst)
