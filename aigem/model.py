"""AiGem (docs/aigem.md): a GAT + linear graph encoder, a GRU decoder, an MLP output.

Shapes: N nodes in a batch of graphs, A target actors, H = hidden width, K = future steps,
E edges of one type.

The parameters are those of PyTorch Geometric's `GATConv` (one per edge type of
`ngsim_graphs.edges.EDGE_TYPES` and layer, named by the type: `encoder.0.spatial.lin.weight`; with
`edge_dim=1`, `add_self_loops=False`), `nn.Linear`, `nn.GRUCell` and the output MLP, so the
parameter count and the checkpoints' keys are theirs. The encoder computes the same function as
`GATConv.forward` (`EncoderLayer.reference` keeps the plain PyG form; the two agree to float32
rounding), arranged for speed on the CPU:

- Only the target actors' present-step embeddings are used downstream, so `forward` runs layer l
  only on the nodes that layer l + 1 (or the decoder) reads: the (L - l)-hop in-neighbourhood of
  the targets. On the full-scale build that is a third of the nodes at the input, a sixteenth at
  the last layer and a sixth of the edge work for L = 4. Nodes are reordered so that every layer's
  input and output sets are prefixes of one node order, and edges are sorted by (destination,
  source) once per batch: every layer's adjacency is then a prefix of one CSR matrix. The result
  at the targets is the same (`encode` still computes every node).
- On the CPU the attention-weighted aggregation is a CSR sparse-dense product (`_AttentionSpMM`),
  with a sampled dense-dense product for the gradient of the attention weights: no (E, H)
  message tensor is materialised. PyG's gather -> multiply -> scatter allocates several per
  layer, forward and backward, and on the CPU those large allocations dominated the step.
- The edge-feature attention term `att_edge . lin_edge(e)` is linear in the edge feature e, so it
  is computed as e @ (lin_edge.weight^T att_edge): one number per edge and head instead of an
  (E, H) projection.

- The plan of a batch (node order, layer sizes, CSR rows and per-layer edge counts) can be made
  beforehand, on the host: `aigem.data.Collate(layers=L)` makes it in the DataLoader's workers,
  and a step given it reads no number back from the device (`make_plan` made in the step must read
  the sizes, which on a GPU waits for the device).

The decoder is PyTorch's GRUCell and the MLP, step by step, exactly as specified;
`compile_decoder` runs it through `torch.compile` (for GPUs, where its ~2,000 operators a step
are as many kernel launches).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn
from torch_geometric.nn import GATConv

from aigem.config import ModelConfig
from ngsim_graphs import edges


def edge_inputs(batch: dict) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(edge_index (2, E), edge_attr (E, 1)) of each edge type, in EDGE_TYPES order, from a
    batch's "<name>_edges" and "<name>_attr" (`aigem.data.Collate`)."""
    return [(batch[f"{e.name}_edges"], batch[f"{e.name}_attr"]) for e in edges.EDGE_TYPES]


# ------------------------------------------------------------------------------------------------
# The plan: pruned, relabelled, destination-sorted adjacency shared by all layers.


@dataclass(frozen=True)
class _Adjacency:
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

    def to(self, device: torch.device, non_blocking: bool = False) -> _Adjacency:
        move = lambda t: t.to(device, non_blocking=non_blocking)  # noqa: E731
        return _Adjacency(
            move(self.crow), move(self.col), move(self.row), move(self.attr), self.ends
        )

    def pin_memory(self) -> _Adjacency:
        pin = lambda t: t.pin_memory()  # noqa: E731
        return _Adjacency(pin(self.crow), pin(self.col), pin(self.row), pin(self.attr), self.ends)


@dataclass(frozen=True)
class Plan:
    """Which nodes each layer computes: layer l (1..L) reads nodes [0, sizes[l-1]) and writes
    nodes [0, sizes[l]); node i of the plan is node order[i] of the batch.

    Its sizes and edge counts are host integers, so a model step that is given a plan made
    beforehand (by `aigem.data.Collate`, in the DataLoader's workers) never waits for the device.
    """

    order: torch.Tensor  # (sizes[0],) batch node ids in plan order
    sizes: list[int]  # L + 1 prefix lengths, non-increasing
    adjacency: list[_Adjacency]  # one per edge type
    outputs: torch.Tensor | None  # (A,) plan positions of the outputs asked for (None: all)

    @property
    def layers(self) -> int:
        return len(self.sizes) - 1

    def to(self, device: torch.device, non_blocking: bool = False) -> Plan:
        move = lambda t: None if t is None else t.to(device, non_blocking=non_blocking)  # noqa: E731
        adjacency = [a.to(device, non_blocking) for a in self.adjacency]
        return Plan(move(self.order), self.sizes, adjacency, move(self.outputs))

    def pin_memory(self) -> Plan:
        """For the DataLoader's pin_memory (then copies to a GPU need not wait)."""
        pin = lambda t: None if t is None else t.pin_memory()  # noqa: E731
        adjacency = [a.pin_memory() for a in self.adjacency]
        return Plan(pin(self.order), self.sizes, adjacency, pin(self.outputs))


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
        # level[v]: the last layer whose output at v is needed (-1: never read). L at the outputs
        # and max(level[w] - 1) over the edges v -> w; L in-place relaxations reach the fixpoint.
        if outputs is None:
            level = torch.full((num_nodes,), layers, dtype=torch.int32, device=device)
        else:
            level = torch.full((num_nodes,), -1, dtype=torch.int32, device=device)
            level[outputs] = layers
            buffers = [torch.empty(e.shape[1], dtype=torch.int32, device=device) for e, _ in edges]
            for _ in range(layers):
                for (edge_index, _), buffer in zip(edges, buffers, strict=False):
                    torch.index_select(level, 0, edge_index[1], out=buffer).sub_(1)
                    level.scatter_reduce_(0, edge_index[0], buffer, "amax")
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
                _Adjacency(crow, src.index_select(0, sort), dst.index_select(0, sort), attr, ends)
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
    accelerators run well. aigem.ensemble aggregates its members through it (and
    `segment_softmax`) over one block-diagonal graph.
    """
    if x.device.type == "cpu" and CPU_SPARSE:
        return _AttentionSpMM.apply(values, x, crow, col)
    return _gather_scatter(values, x, crow.numel() - 1, col, dst)


def _gather_scatter(values, x, n_dst: int, col, dst) -> torch.Tensor:  # noqa: ANN001
    """`aggregate` as PyG computes it: (E, C) messages values[e] * x[col[e]], summed at dst[e]."""
    messages = values.unsqueeze(-1) * x.index_select(0, col)  # (E, C)
    return x.new_zeros(n_dst, x.shape[1]).index_add_(0, dst, messages)


def segment_softmax(scores: torch.Tensor, dst: torch.Tensor, n_dst: int) -> torch.Tensor:
    """PyG's `softmax(scores, dst)`: softmax of (E, heads) scores over each destination's edges."""
    index = dst[:, None].expand_as(scores)
    size = (n_dst, scores.shape[1])
    top = scores.new_zeros(size)
    top = top.scatter_reduce_(0, index, scores.detach(), "amax", include_self=False)
    out = (scores - top.index_select(0, dst)).exp()
    total = out.new_zeros(size).scatter_add_(0, index, out) + 1e-16
    return out / total.index_select(0, dst)


def _gat(conv: GATConv, h: torch.Tensor, crow, col, attr, dst) -> torch.Tensor:  # noqa: ANN001
    """`conv(z, edges, attr)` without its bias at the first n_dst nodes, given h = conv.lin(z)
    (n_src, heads * C) and the edges as CSR rows (destinations) over the n_src sources; dst[e] is
    edge e's row."""
    heads, channels = conv.heads, conv.out_channels
    n_dst = crow.numel() - 1
    hv = h.view(-1, heads, channels)
    if heads == 1:  # (h * att).sum(-1) as a matrix-vector product
        score_src = h @ conv.att_src.view(channels, 1)  # (n_src, 1)
        score_dst = h[:n_dst] @ conv.att_dst.view(channels, 1)  # (n_dst, 1)
    else:
        score_src = (hv * conv.att_src).sum(-1)  # (n_src, heads)
        score_dst = (hv[:n_dst] * conv.att_dst).sum(-1)  # (n_dst, heads)
    scores = score_src.index_select(0, col) + score_dst.index_select(0, dst)  # (E, heads)
    if conv.lin_edge is not None:
        # att_edge . lin_edge(e) per head = e @ (lin_edge.weight^T att_edge): a (D, heads) matrix
        weight = conv.lin_edge.weight.view(heads, channels, -1)
        edge_att = (weight * conv.att_edge.view(heads, channels, 1)).sum(1).t()
        scores = scores + attr.to(h.dtype) @ edge_att
    alpha = F.leaky_relu(scores, conv.negative_slope)
    alpha = segment_softmax(alpha, dst, n_dst)
    alpha = F.dropout(alpha, p=conv.dropout, training=conv.training)
    if heads == 1:
        return aggregate(alpha[:, 0].contiguous(), h, crow, col, dst)
    per_head = [
        aggregate(alpha[:, k].contiguous(), hv[:, k].contiguous(), crow, col, dst)
        for k in range(heads)
    ]
    return torch.cat(per_head, 1) if conv.concat else torch.stack(per_head, 1).mean(1)


class EncoderLayer(nn.Module):
    """Z_l = sum over the edge types of GAT_type(Z, E_type) + Linear(Z): one GAT per edge type
    (an attribute named by the type, so the checkpoints' keys are `spatial.*`, `temporal.*`)."""

    def __init__(self, in_features: int, config: ModelConfig) -> None:
        super().__init__()
        self.edge_names = tuple(edge.name for edge in edges.EDGE_TYPES)
        for name in self.edge_names:  # registered in order: the parameters' order and init
            conv = GATConv(
                in_features,
                config.hidden,
                heads=config.heads,
                concat=False,
                edge_dim=1,
                add_self_loops=False,
                dropout=config.dropout,
            )
            self.add_module(name, conv)
        self.linear = nn.Linear(in_features, config.hidden)

    def convs(self) -> list[GATConv]:
        """The GAT of each edge type, in EDGE_TYPES order."""
        return [getattr(self, name) for name in self.edge_names]

    def forward(self, z, n_dst: int, adjacency: list[_Adjacency]) -> torch.Tensor:  # noqa: ANN001
        """(n_src, F) inputs -> (n_dst, H) outputs at the first n_dst nodes (see `Plan`);
        `adjacency`: one per edge type."""
        total = None
        for conv, edge_adjacency in zip(self.convs(), adjacency, strict=True):
            gat = _gat(conv, conv.lin(z), *edge_adjacency.prefix(n_dst))
            gat = gat + conv.bias if conv.bias is not None else gat
            total = gat if total is None else total + gat
        return total + self.linear(z[:n_dst])  # in the reference's order

    def reference(self, z, edge_list: list[tuple[torch.Tensor, torch.Tensor]]):  # noqa: ANN001, ANN201
        """The same layer on all N nodes through PyG's `GATConv.forward` (for checks);
        `edge_list`: (edge_index, edge_attr) per edge type."""
        total = None
        for conv, (edge_index, attr) in zip(self.convs(), edge_list, strict=True):
            gat = conv(z, edge_index, attr)
            total = gat if total is None else total + gat
        return total + self.linear(z)  # (N, H)


class AiGem(nn.Module):
    """Predicts K future positions of each target actor from its graph's present-step embedding."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self._compiled_decode = None  # set by compile_decoder
        widths = [config.node_features] + [config.hidden] * config.layers
        self.encoder = nn.ModuleList(EncoderLayer(w, config) for w in widths[:-1])
        self.dropout = nn.Dropout(config.dropout)
        self.decoder = nn.GRUCell(config.hidden, config.hidden)
        mlp_in = config.hidden + (2 if config.concat_position else 0)
        self.output = nn.Sequential(
            nn.Linear(mlp_in, config.mlp_hidden), nn.ReLU(), nn.Linear(config.mlp_hidden, 2)
        )

    def _encode(self, x, edge_list, outputs, plan=None):  # noqa: ANN001, ANN202
        """(len(outputs), H) embeddings of the batch nodes `outputs` (None: all, in batch order).
        `edge_list`: `edge_inputs` of the batch; `plan`: the plan of these edges and outputs for
        this many layers, made beforehand."""
        if plan is None:
            plan = make_plan(x.shape[0], outputs, edge_list, len(self.encoder))
        z = x.index_select(0, plan.order)
        for index, layer in enumerate(self.encoder):
            z = layer(z, plan.sizes[index + 1], plan.adjacency)
            if index < len(self.encoder) - 1:
                z = self.dropout(torch.relu(z))
        if plan.outputs is None:  # every node: back to batch order
            return z.new_empty(z.shape).index_copy_(0, plan.order, z)
        return z.index_select(0, plan.outputs)

    def encode(self, x, edge_list):  # noqa: ANN001, ANN201
        """(N, F) scaled node features -> (N, H) embeddings after L layers; `edge_list`:
        (edge_index, edge_attr) per edge type (`edge_inputs`)."""
        return self._encode(x, edge_list, None)

    def compile_decoder(self) -> None:
        """Run the decoder through `torch.compile` (shapes dynamic in A; one compilation per
        horizon, for training and for evaluation). Its 25 steps are some 2,000 operators in
        eager mode, forward and backward; compiled, a few dozen fused kernels and the matrix
        products. It pays on a GPU, where each operator is a kernel launch; on the CPU compiling
        takes about a minute and the step is no faster (bench/bench_train.py)."""
        self._compiled_decode = torch.compile(self._decode, dynamic=True)

    def decode(
        self,
        z_target: torch.Tensor,
        start_xy: torch.Tensor,
        steps: int,
        cv_step: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(A, H) present embeddings, (A, 2) present positions -> (A, steps, 2) positions.

        GRU inputs: z at step 1, z + g_1 at step 2, g_{k-1} + g_{k-2} after; h_0 = 0.
        Y_k = Y_{k-1} + MLP([g_k, Y_{k-1}]), Y_0 the present position. With
        `config.cv_residual`, Y_k = Y_{k-1} + cv_step + MLP(...): `cv_step` (A, 2) is constant
        velocity's displacement over one step (`aigem.data.Collate.cv_step`).
        """
        if self.config.cv_residual:
            if cv_step is None:
                raise ValueError("a model with cv_residual needs the batch's cv_step")
        else:
            cv_step = None
        return (self._compiled_decode or self._decode)(z_target, start_xy, steps, cv_step)

    def _decode(
        self,
        z_target: torch.Tensor,
        start_xy: torch.Tensor,
        steps: int,
        cv_step: torch.Tensor | None = None,
    ) -> torch.Tensor:
        hidden = torch.zeros_like(z_target)
        previous_g, before_g = (
            z_target,
            torch.zeros_like(z_target),
        )  # so that step 1 sees z, step 2 z + g_1
        position, outputs = start_xy, []
        for step in range(steps):
            gru_in = z_target if step == 0 else previous_g + before_g
            hidden = self.decoder(gru_in, hidden)  # g_k, (A, H)
            before_g, previous_g = previous_g, hidden
            mlp_in = (
                torch.cat([hidden, position], dim=-1) if self.config.concat_position else hidden
            )
            position = position + self.output(mlp_in)  # (A, 2)
            if cv_step is not None:
                position = position + cv_step
            outputs.append(position)
        return torch.stack(outputs, dim=1)  # (A, steps, 2)

    def forward(self, batch: dict[str, torch.Tensor], steps: int | None = None) -> torch.Tensor:
        """Scaled predicted positions (A, steps, 2) of the batch's targets."""
        target = batch["target_node"]
        plan = batch.get("plan")
        if plan is not None and plan.layers != len(self.encoder):
            plan = None  # made for another model
        z_target = self._encode(batch["x"], edge_inputs(batch), target, plan)
        steps = steps or self.config.future_steps
        return self.decode(z_target, batch["x"][target, :2], steps, batch.get("cv_step"))


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
