"""AiGem (docs/aigem.md): a GAT + linear graph encoder, a GRU decoder, an MLP output.

Shapes: M models ("members"), N nodes in a batch of graphs, A target actors, H = hidden width,
K = future steps, E edges of one type.

The parameters are those of PyTorch Geometric's `GATConv` (one per edge type of the build,
`ModelConfig.edge_types`, and layer, named by the type: `encoder.0.spatial.lin.weight`; with
`edge_dim=1`, `add_self_loops=False`), `nn.Linear`, `nn.GRUCell` and the output MLP, so the
parameter count and the checkpoints' keys are theirs. `GATParameters` holds a GATConv's parameters
under its names, initialised as it initialises them (a seed gives the same model), without
importing PyG, whose import takes longer than PyTorch's (it loads torch._dynamo); the tests hold
the forward to PyG's `GATConv.forward` on these parameters.

The forward pass is written once, for M models at a time: `forward_members(params, ...)` takes
the parameters stacked along a leading member dimension under AiGem's own names
(`params["decoder.weight_ih"]` is (M, 3H, H)). A model alone is M = 1 (`AiGem.forward` passes its
own parameters with a member dimension of one); the models of a multi-horizon fit are M = 5
(`aigem.training.ensemble`). Each operator then runs once for all members: linear layers are batched
matrix products, the attention is computed over one graph of M copies of the batch's graph
(member m's nodes offset by m times the layer's sizes) through `aigem.model.plan.aggregate`, and the
GRU cell and the MLP are batched matrix products. What the members share (the batch, its plan)
is read once. The encoder computes `GATConv.forward` (the two agree to float32 rounding) on the
nodes of the batch's `aigem.model.plan.Plan`:

- The edge-feature attention term `att_edge . lin_edge(e)` is linear in the edge feature e, so it
  is computed as e @ (lin_edge.weight^T att_edge): one number per edge and head instead of an
  (E, H) projection; likewise h . att = z . (lin.weight^T att).
- The attention sums the sources' inputs and projects the sum, sum_j alpha_ij W z_j =
  W sum_j alpha_ij z_j (GATConv's `lin` has no bias): the product runs over the destinations
  only, and the first layer sums the nodes' few input features, not H.
- Dropout masks are drawn from the global generator, one mask for all members (the members of a
  fit start every epoch from one seed, and a model trained alone draws the same masks): on the
  CPU `F.dropout` is `x * empty_like(x).bernoulli_(1 - p).div_(1 - p)`, which this draws.
- The decoder is causal, so member m decodes only its own `steps[m]` (ascending): the members
  still decoding are a suffix of them, and member m's positions after its steps are zeros.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from aigem.config import ModelConfig
from aigem.model.batch import Batch
from aigem.model.plan import aggregate, make_plan, segment_softmax

Params = dict[str, torch.Tensor]  # AiGem's parameter name -> its (M, ...) stack over members
NEGATIVE_SLOPE = 0.2  # GATConv's default, which AiGem keeps


def _linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """x (M, n, in), or (n, in) shared by the members; weight (M, out, in); bias (M, out) or None
    -> (M, n, out)."""
    if x.dim() == 2:
        x = x.expand(weight.shape[0], *x.shape)
    if bias is None:
        return torch.bmm(x, weight.transpose(1, 2))
    return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))


def _dropout(x: torch.Tensor, p: float, training: bool) -> torch.Tensor:
    """`F.dropout` of x (M, ...) with one mask of x.shape[1:] for every member, drawn from the
    global generator as the CPU's `F.dropout` draws it."""
    if not training or p == 0 or x.numel() == 0:
        return x
    if p == 1:
        return x * 0.0
    mask = torch.empty(x.shape[1:], dtype=x.dtype, device=x.device).bernoulli_(1 - p)
    return x * mask.div_(1 - p)


def _block_diagonal(crow, col, dst, members: int, n_src: int) -> tuple[torch.Tensor, ...]:  # noqa: ANN001
    """One graph of M copies of a layer's graph (n_dst destinations, n_src sources): copy m's
    destinations and sources offset by m n_dst and m n_src, its edges after copy m - 1's (the
    edge count, and so the last row pointer, is known on the host). Returns its CSR rows, its
    columns, each edge's row, and each edge's destination as a source (offset by m n_src)."""
    if members == 1:
        return crow, col, dst, dst
    edges_, n_dst = col.numel(), crow.numel() - 1
    member = torch.arange(members, device=col.device).unsqueeze(1)  # (M, 1)
    last = crow.new_full((1,), members * edges_)
    big_crow = torch.cat([(crow[:-1] + member * edges_).flatten(), last])
    big_col = (col + member * n_src).flatten()
    return big_crow, big_col, (dst + member * n_dst).flatten(), (dst + member * n_src).flatten()


# ------------------------------------------------------------------------------------------------
# The encoder


def _gat(p: Params, conv: str, config: ModelConfig, z, crow, col, attr, dst, training: bool):  # noqa: ANN001, ANN201
    """GATConv `conv` (a parameter prefix) of each member without its bias at the first n_dst
    nodes: z (M, n_src, F) or shared (n_src, F) -> (M, n_dst, C); the edges as CSR rows
    (destinations) over the n_src sources, dst[e] edge e's row. The attention sums the sources'
    inputs, projected after: sum_j alpha_ij W z_j = W sum_j alpha_ij z_j."""
    weight = p[f"{conv}.lin.weight"]  # (M, heads C, F)
    (members, _, features), heads, channels = weight.shape, config.heads, config.hidden
    n_src, n_dst = z.shape[-2], crow.numel() - 1
    big_crow, big_col, big_dst, dst_as_src = _block_diagonal(crow, col, dst, members, n_src)
    # W z . att = z . (W^T att) per head: one product with 2 heads columns
    weight = weight.view(members, heads, channels, features)
    att = torch.cat([p[f"{conv}.att_src"], p[f"{conv}.att_dst"]], 1)  # (M, 2, heads, C)
    att = att.view(members, 2 * heads, channels, 1)
    scores = _linear(z, (weight.repeat(1, 2, 1, 1) * att).sum(2), None)  # (M, n_src, 2 heads)
    scores = scores.view(members * n_src, 2 * heads)
    scores = scores[:, :heads].index_select(0, big_col) + scores[:, heads:].index_select(
        0, dst_as_src
    )  # (M E, heads)
    edge_weight = p[f"{conv}.lin_edge.weight"].view(members, heads, channels, 1)  # edge_dim 1
    att = p[f"{conv}.att_edge"].view(members, heads, channels, 1)
    edge_att = (edge_weight * att).sum(2).transpose(1, 2)  # (M, 1, heads)
    scores = scores + (attr.to(z.dtype) * edge_att).view(-1, heads)  # an outer product
    alpha = F.leaky_relu(scores, NEGATIVE_SLOPE)
    alpha = segment_softmax(alpha, big_crow, big_dst)
    alpha = _dropout(alpha.view(members, -1, heads), config.dropout, training).view(-1, heads)
    sources = z.expand(members, n_src, features).reshape(members * n_src, features)
    per_head = []
    for k in range(heads):  # the sources' inputs summed by head k's weights, then projected
        summed = aggregate(alpha[:, k].contiguous(), sources, big_crow, big_col, big_dst)
        per_head.append(_linear(summed.view(members, n_dst, features), weight[:, k], None))
    return per_head[0] if heads == 1 else torch.stack(per_head, 1).mean(1)


def _encoder_layer(
    p: Params, config: ModelConfig, index: int, z, n_dst: int, adjacency, training: bool
) -> torch.Tensor:  # noqa: ANN001
    """Z_l = sum over the edge types of GAT_type(Z, E_type) + Linear(Z) of each member:
    z (M, n_src, F), or (n_src, F) shared -> (M, n_dst, H) at the first n_dst nodes."""
    total = None
    for edge_type, edge_adjacency in zip(config.edge_types, adjacency, strict=True):
        conv = f"encoder.{index}.{edge_type}"
        gat = _gat(p, conv, config, z, *edge_adjacency.prefix(n_dst), training)
        gat = gat + p[f"{conv}.bias"].unsqueeze(1)
        total = gat if total is None else total + gat
    own = z[:n_dst] if z.dim() == 2 else z[:, :n_dst]
    linear = f"encoder.{index}.linear"
    return total + _linear(own, p[f"{linear}.weight"], p[f"{linear}.bias"])  # the reference's order


def encode_members(p: Params, config: ModelConfig, batch: Batch, training: bool) -> torch.Tensor:
    """(M, A, H) present embeddings of the batch's targets after L layers, on the batch's plan
    (`Batch.plan`, made here if it has none for L layers)."""
    layers = config.layers
    plan = batch.plan
    if plan is None or plan.layers != layers:
        edge_list = batch.edge_inputs(config.edge_types)
        plan = make_plan(batch.x.shape[0], batch.target_node, edge_list, layers)
    z = batch.x if plan.order is None else batch.x.index_select(0, plan.order)  # shared
    for index in range(layers):
        z = _encoder_layer(p, config, index, z, plan.sizes[index + 1], plan.adjacency, training)
        if index < layers - 1:
            z = _dropout(torch.relu(z), config.dropout, training)
    return z.index_select(1, plan.outputs)


# ------------------------------------------------------------------------------------------------
# The decoder


def _gru(x, hidden, w_ih, w_hh, b_ih, b_hh) -> torch.Tensor:  # noqa: ANN001
    """`nn.GRUCell` of each member, in ATen's order of operations: (M, A, H) -> (M, A, H)."""
    i_r, i_z, i_n = torch.baddbmm(b_ih, x, w_ih).chunk(3, 2)
    h_r, h_z, h_n = torch.baddbmm(b_hh, hidden, w_hh).chunk(3, 2)
    reset = torch.sigmoid(h_r + i_r)
    update = torch.sigmoid(h_z + i_z)
    new = torch.tanh(i_n + h_n * reset)
    return (hidden - new) * update + new


def _decoder_weights(p: Params) -> list[torch.Tensor]:
    """The GRU's and the MLP's weights, transposed for batched products, biases (M, 1, out)."""
    names = ("decoder.weight_ih", "decoder.weight_hh", "output.0.weight", "output.2.weight")
    weights = [p[name].transpose(1, 2) for name in names]
    names = ("decoder.bias_ih", "decoder.bias_hh", "output.0.bias", "output.2.bias")
    return weights + [p[name].unsqueeze(1) for name in names]


def decode_members(
    p: Params,
    config: ModelConfig,
    z: torch.Tensor,
    start_xy: torch.Tensor,
    steps: Sequence[int],
    cv_step: torch.Tensor | None = None,
) -> torch.Tensor:
    """(M, A, H) present embeddings, (A, 2) present positions -> (M, A, K, 2) positions,
    K = max(steps); member m's after its `steps[m]` (ascending) are zeros.

    GRU inputs: z at step 1, z + g_1 at step 2, g_{k-1} + g_{k-2} after; h_0 = 0.
    Y_k = Y_{k-1} + MLP([g_k, Y_{k-1}]), Y_0 the present position. With `cv_step` (A, 2),
    constant velocity's displacement over one step (`config.cv_residual`), Y_k = Y_{k-1} +
    cv_step + MLP(...).
    """
    weights = _decoder_weights(p)
    hidden, before_g, previous_g = torch.zeros_like(z), torch.zeros_like(z), z
    position = start_xy.expand(len(steps), *start_xy.shape)
    first, segments, outputs = 0, [], []  # members [first:] still decode
    for step in range(steps[-1]):
        done = sum(s <= step for s in steps) - first
        if done:  # the members [first:first + done] have decoded all their steps
            segments.append(F.pad(torch.stack(outputs, 2), (0, 0, 0, 0, 0, 0, first, 0)))
            first, outputs = first + done, []
            hidden, before_g = hidden[done:], before_g[done:]
            previous_g, position = previous_g[done:], position[done:]
            weights = [w[done:] for w in weights]
        w_ih, w_hh, w_1, w_2, b_ih, b_hh, b_1, b_2 = weights
        gru_in = z if step == 0 else previous_g + before_g
        hidden = _gru(gru_in, hidden, w_ih, w_hh, b_ih, b_hh)  # g_k, (M', A, H)
        before_g, previous_g = previous_g, hidden
        mlp_in = torch.cat([hidden, position], -1) if config.concat_position else hidden
        mlp_hidden = torch.relu(torch.baddbmm(b_1, mlp_in, w_1))
        position = position + torch.baddbmm(b_2, mlp_hidden, w_2)
        if cv_step is not None:
            position = position + cv_step
        outputs.append(position)
    segments.append(F.pad(torch.stack(outputs, 2), (0, 0, 0, 0, 0, 0, first, 0)))
    return segments[0] if len(segments) == 1 else torch.cat(segments, 2)


Decode = Callable[..., torch.Tensor]  # decode_members, or it compiled


def forward_members(
    p: Params,
    config: ModelConfig,
    batch: Batch,
    steps: Sequence[int],
    training: bool,
    decode: Decode = decode_members,
) -> torch.Tensor:
    """(M, A, K, 2) scaled predicted positions of the batch's targets by each member, K =
    max(steps); `steps` ascending, one per member."""
    if list(steps) != sorted(steps) or not steps or steps[0] < 1:
        raise ValueError(f"the members' steps must be ascending and positive, not {list(steps)}")
    cv_step = batch.cv_step if config.cv_residual else None
    if config.cv_residual and cv_step is None:
        raise ValueError("a model with cv_residual needs the batch's cv_step")
    z = encode_members(p, config, batch, training)
    start_xy = batch.x.index_select(0, batch.target_node)[:, :2]
    return decode(p, config, z, start_xy, tuple(steps), cv_step)


# ------------------------------------------------------------------------------------------------
# The model: its parameters, and the forward of one member


class _Weight(nn.Module):
    """A bias-free linear layer's weight (out, in): the `lin` and `lin_edge` of a GATConv."""

    def __init__(self, out_features: int, in_features: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(out_features, in_features))


def _glorot(parameter: nn.Parameter) -> None:
    """PyG's glorot: uniform in +-sqrt(6 / (size(-2) + size(-1)))."""
    bound = math.sqrt(6.0 / (parameter.size(-2) + parameter.size(-1)))
    with torch.no_grad():
        parameter.uniform_(-bound, bound)


class GATParameters(nn.Module):
    """The parameters of PyG's `GATConv(in_features, hidden, heads, concat=False, edge_dim=1,
    add_self_loops=False)`, in its order and under its names (att_src, att_dst, att_edge, bias,
    lin.weight, lin_edge.weight), drawn from the global generator as it draws them: each of its
    two Linears on its construction, then its `reset_parameters` (the Linears again, att_src,
    att_dst, att_edge; the bias zeros). The forward is `_gat`'s."""

    def __init__(self, in_features: int, config: ModelConfig) -> None:
        super().__init__()
        heads, channels = config.heads, config.hidden
        self.att_src = nn.Parameter(torch.empty(1, heads, channels))
        self.att_dst = nn.Parameter(torch.empty(1, heads, channels))
        self.att_edge = nn.Parameter(torch.empty(1, heads, channels))
        self.bias = nn.Parameter(torch.empty(channels))  # concat=False: one per channel
        self.lin = _Weight(heads * channels, in_features)
        self.lin_edge = _Weight(heads * channels, 1)  # edge_dim=1
        linears = [self.lin.weight, self.lin_edge.weight]
        for parameter in [*linears, *linears, self.att_src, self.att_dst, self.att_edge]:
            _glorot(parameter)
        nn.init.zeros_(self.bias)


class EncoderLayer(nn.Module):
    """One GAT per edge type (an attribute named by the type, so the checkpoints' keys are
    `spatial.*`, `temporal.*`) and the linear term; `forward_members` computes the layer."""

    def __init__(self, in_features: int, config: ModelConfig) -> None:
        super().__init__()
        self.edge_names = config.edge_types
        for name in self.edge_names:  # registered in order: the parameters' order and init
            self.add_module(name, GATParameters(in_features, config))
        self.linear = nn.Linear(in_features, config.hidden)

    def convs(self) -> list[GATParameters]:
        """The GAT of each edge type, in `ModelConfig.edge_types` order."""
        return [getattr(self, name) for name in self.edge_names]


class AiGem(nn.Module):
    """Predicts K future positions of each target actor from its graph's present-step embedding."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.decode_fn: Decode = decode_members  # compile_decoder replaces it
        widths = [config.node_features] + [config.hidden] * config.layers
        self.encoder = nn.ModuleList(EncoderLayer(w, config) for w in widths[:-1])
        self.decoder = nn.GRUCell(config.hidden, config.hidden)
        mlp_in = config.hidden + (2 if config.concat_position else 0)
        self.output = nn.Sequential(
            nn.Linear(mlp_in, config.mlp_hidden), nn.ReLU(), nn.Linear(config.mlp_hidden, 2)
        )

    def member_params(self) -> Params:
        """The parameters with a member dimension of one (views: gradients reach them)."""
        return {name: p.unsqueeze(0) for name, p in self.named_parameters()}

    def compile_decoder(self) -> None:
        """Run the decoder through `torch.compile` (shapes dynamic in A). Its 25 steps are some
        2,000 operators in eager mode, forward and backward; compiled, a few dozen fused kernels
        and the matrix products. It pays on a GPU stepping eagerly (a captured step replays them
        at no cost, aigem.training.engine); on the CPU compiling takes a minute and the step is no
        faster (bench/bench_train.py)."""
        self.decode_fn = torch.compile(decode_members, dynamic=True)

    def encode(self, batch: Batch) -> torch.Tensor:
        """(A, H) present embeddings of the batch's targets."""
        return encode_members(self.member_params(), self.config, batch, self.training)[0]

    def decode(
        self,
        z_target: torch.Tensor,
        start_xy: torch.Tensor,
        steps: int,
        cv_step: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(A, H) present embeddings, (A, 2) present positions -> (A, steps, 2) positions
        (`decode_members`); `cv_step` is read with `config.cv_residual` only."""
        if self.config.cv_residual and cv_step is None:
            raise ValueError("a model with cv_residual needs the batch's cv_step")
        cv_step = cv_step if self.config.cv_residual else None
        p = self.member_params()
        return self.decode_fn(p, self.config, z_target.unsqueeze(0), start_xy, (steps,), cv_step)[0]

    def forward(self, batch: Batch, steps: int | None = None) -> torch.Tensor:
        """Scaled predicted positions (A, steps, 2) of the batch's targets."""
        steps = steps or self.config.future_steps
        p = self.member_params()
        return forward_members(p, self.config, batch, (steps,), self.training, self.decode_fn)[0]


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
