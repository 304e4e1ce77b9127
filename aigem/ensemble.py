"""Several AiGem models of one ModelConfig trained as one (docs/aigem.md): an ensemble.

The M members' parameters are stacked along a leading member dimension under AiGem's own names
(`params["decoder.weight_ih"]` is (M, 3H, H)), so that a step runs each operator once for all
members instead of once per member: linear layers are batched matrix products, the attention
scores and the segment softmax are computed per member over the shared edges, the aggregation is
one block-diagonal sparse product (member m's rows and columns offset by m times the layer's
sizes) through `aigem.model.aggregate`, and the GRU cell and the MLP are batched matrix products.
What the members share (the batch, its plan, the edges) is read once.

Member m computes what `AiGem.forward(batch, steps[m])` computes, to float rounding:

- `forward` returns (M, A, K, 2) for K = max(steps); member m's positions after its own steps
  are zeros, not predictions. The decoder is causal, so a member decodes only its own steps: the
  steps are ascending and the members still decoding are a suffix of them.
- `member_losses` is each member's `masked_mse_m2` over its own steps; their sum's gradient in a
  member's parameters is that member's own loss gradient, and Adam, elementwise, steps the
  stacked parameters as M Adams would step each member's.
- Dropout: each member draws its masks from its own stream, a `torch.Generator` set to the state
  the global generator would have for it, in the order and shapes of AiGem's `F.dropout` calls. On
  the CPU `F.dropout` is `x * empty_like(x).bernoulli_(1 - p).div_(1 - p)` (tests check it), so
  the masks are the ones the member trained alone would draw. On CUDA, where `F.dropout` is a
  fused kernel with its own use of the generator, the masks still come from each member's own
  stream, but they are other (equally random) masks than the member alone would draw. Members
  whose streams are in the same state draw once and share the masks (a fit's horizons start every
  epoch from one seed, and their encoders draw the same shapes).

`stack` and `unstack` move the members' parameters and their Adam states in and out (through the
optimisers' public `state_dict`); the checkpoints stay each member's own.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch_geometric.nn import GATConv

from aigem.config import ModelConfig
from aigem.data import xy_to_metres
from aigem.model import AiGem, aggregate, edge_inputs, make_plan, segment_softmax
from ngsim_graphs.scaling import MinMaxScaler

Params = dict[str, torch.Tensor]


def _linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """x (M, n, in), or (n, in) shared by the members; weight (M, out, in); bias (M, out) or None
    -> (M, n, out)."""
    if x.dim() == 2:
        x = x.expand(weight.shape[0], *x.shape)
    if bias is None:
        return torch.bmm(x, weight.transpose(1, 2))
    return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))


def _block_diagonal(crow, col, dst, members: int, n_src: int) -> tuple[torch.Tensor, ...]:  # noqa: ANN001
    """One graph of M copies of a layer's graph (n_dst destinations, n_src sources): copy m's
    destinations and sources offset by m n_dst and m n_src, its edges after copy m - 1's (the
    edge count, and so the last row pointer, is known on the host). Returns its CSR rows, its
    columns, each edge's row, and each edge's destination as a source (offset by m n_src)."""
    edges, n_dst = col.numel(), crow.numel() - 1
    member = torch.arange(members, device=col.device).unsqueeze(1)  # (M, 1)
    last = crow.new_full((1,), members * edges)
    big_crow = torch.cat([(crow[:-1] + member * edges).flatten(), last])
    big_col = (col + member * n_src).flatten()
    return big_crow, big_col, (dst + member * n_dst).flatten(), (dst + member * n_src).flatten()


class Ensemble:
    """M AiGem models of one ModelConfig with stacked parameters; `steps[m]`: member m's future
    steps (ascending). `streams`: each member's dropout stream as a generator state (None: the
    global generator's state now, for every member)."""

    def __init__(
        self,
        params: Params,
        config: ModelConfig,
        steps: Sequence[int],
        streams: Sequence[torch.Tensor] | None = None,
    ) -> None:
        if list(steps) != sorted(steps) or not steps:
            raise ValueError(f"an ensemble's members' steps must be ascending, not {list(steps)}")
        self.params, self.config, self.steps = params, config, tuple(steps)
        self.training = True
        with torch.device("meta"):  # the convs' settings, the parameters' names and order;
            template = AiGem(config)  # on no memory, drawing nothing from the global stream
        conv: GATConv = template.encoder[0].convs()[0]
        self.negative_slope = conv.negative_slope
        self.edge_names = template.encoder[0].edge_names
        self.names = [name for name, _ in template.named_parameters()]
        if any(name.endswith(".lin.bias") for name in params):  # PyG's GATConv.lin has none
            raise ValueError(
                "a GATConv's lin with a bias: the ensemble's scores z . (W^T a) omit it"
            )
        if sorted(self.names) != sorted(params):
            raise ValueError("the stacked parameters are not AiGem's")
        device = next(iter(params.values())).device
        if streams is None:  # the global generator's state, for every member
            cuda = device.type == "cuda"
            state = torch.cuda.get_rng_state(device) if cuda else torch.get_rng_state()
            streams = [state] * len(steps)
        self._set_streams(streams, device)
        arange = torch.arange(max(steps), device=device)
        scored = arange < torch.tensor(steps, device=device).unsqueeze(1)  # (M, K)
        self.scored = scored.unsqueeze(1)  # (M, 1, K): which steps count in each member's loss

    @property
    def members(self) -> int:
        return len(self.steps)

    def parameters(self) -> list[torch.Tensor]:
        """The stacked parameters in AiGem's order (an optimiser's parameter order)."""
        return [self.params[name] for name in self.names]

    def train(self, mode: bool = True) -> Ensemble:
        self.training = mode
        return self

    def eval(self) -> Ensemble:
        return self.train(False)

    # ---------------------------------------------------------------------------------------------
    # Dropout streams

    def _set_streams(self, states: Sequence[torch.Tensor], device: torch.device) -> None:
        """One generator per distinct state; `_stream_of[m]`: member m's."""
        distinct: list[torch.Tensor] = []
        index = []
        for state in states:
            found = [i for i, known in enumerate(distinct) if torch.equal(known, state)]
            if not found:
                distinct.append(state)
            index.append(found[0] if found else len(distinct) - 1)
        self._generators = []
        for state in distinct:
            generator = torch.Generator(device)
            generator.set_state(state)
            self._generators.append(generator)
        self._stream_of = index
        self._stream_index = torch.tensor(index, device=device)

    def streams(self) -> list[torch.Tensor]:
        """Each member's dropout stream as a generator state, as it is now."""
        states = [generator.get_state() for generator in self._generators]
        return [states[i] for i in self._stream_of]

    def _dropout(self, x: torch.Tensor, dim: int = 0) -> torch.Tensor:
        """`F.dropout(x.select(dim, m), p, training)` of each member m, its mask drawn from its
        stream; `dim`: x's member dimension."""
        p = self.config.dropout
        if not self.training or p == 0 or x.numel() == 0:
            return x
        if p == 1:
            return x * 0.0
        shape = x.shape[:dim] + x.shape[dim + 1 :]
        masks = [
            torch.empty(shape, dtype=x.dtype, device=x.device)
            .bernoulli_(1 - p, generator=generator)
            .div_(1 - p)
            for generator in self._generators
        ]
        if len(masks) == 1:
            return x * masks[0].unsqueeze(dim)  # every member's mask
        return x * torch.stack(masks, dim).index_select(dim, self._stream_index)

    # ---------------------------------------------------------------------------------------------
    # Encoder

    def _gat(self, conv: str, z: torch.Tensor, h: torch.Tensor, crow, col, attr, dst):  # noqa: ANN001, ANN201
        """`aigem.model._gat` of each member: z (M, n_src, F) or shared (n_src, F), h its
        (M, n_src, heads C) projection -> (M, n_dst, C). The members' edges are those of one
        graph of M copies of the layer's graph (`_block_diagonal`), so the attention is
        `aigem.model`'s own over that graph."""
        p, (members, n_src) = self.params, h.shape[:2]
        heads, channels, n_dst = self.config.heads, self.config.hidden, crow.numel() - 1
        big_crow, big_col, big_dst, dst_as_src = _block_diagonal(crow, col, dst, members, n_src)
        # h . att = z . (lin.weight^T att) per head: one product with 2 heads columns, not two
        # matrix-vector products over h (which batched are slow on the CPU)
        weight = p[f"{conv}.lin.weight"].view(members, heads, channels, -1)
        att = torch.cat([p[f"{conv}.att_src"], p[f"{conv}.att_dst"]], 1)  # (M, 2, heads, C)
        att = att.view(members, 2 * heads, channels, 1)
        scores = _linear(z, (weight.repeat(1, 2, 1, 1) * att).sum(2), None)  # (M, n_src, 2 heads)
        scores = scores.view(members * n_src, 2 * heads)
        scores = scores[:, :heads].index_select(0, big_col) + scores[:, heads:].index_select(
            0, dst_as_src
        )  # (M E, heads)
        if f"{conv}.lin_edge.weight" in p:
            weight = p[f"{conv}.lin_edge.weight"].view(members, heads, channels, -1)
            att = p[f"{conv}.att_edge"].view(members, heads, channels, 1)
            edge_att = (weight * att).sum(2).transpose(1, 2)  # (M, D, heads)
            if edge_att.shape[1] == 1:  # AiGem's edge_dim: an outer product, not a matmul
                edge_scores = attr.to(h.dtype) * edge_att
            else:
                edge_scores = torch.matmul(attr.to(h.dtype), edge_att)
            scores = scores + edge_scores.view(-1, heads)
        alpha = F.leaky_relu(scores, self.negative_slope)
        alpha = segment_softmax(alpha, big_dst, members * n_dst)
        alpha = self._dropout(alpha.view(members, -1, heads)).view(-1, heads)
        x = h.view(members * n_src, heads, channels)
        per_head = [
            aggregate(alpha[:, k].contiguous(), x[:, k], big_crow, big_col, big_dst)
            for k in range(heads)
        ]
        out = per_head[0] if heads == 1 else torch.stack(per_head, 1).mean(1)
        return out.view(members, n_dst, channels)

    def _layer(self, index: int, z: torch.Tensor, n_dst: int, adjacency: list) -> torch.Tensor:
        """`EncoderLayer.forward` of each member: z (M, n_src, F), or (n_src, F) shared ->
        (M, n_dst, H)."""
        p, total = self.params, None
        for name, edge_adjacency in zip(self.edge_names, adjacency, strict=True):
            conv = f"encoder.{index}.{name}"
            h = _linear(z, p[f"{conv}.lin.weight"], None)  # no bias: Ensemble.__init__
            gat = self._gat(conv, z, h, *edge_adjacency.prefix(n_dst))
            gat = gat + p[f"{conv}.bias"].unsqueeze(1)
            total = gat if total is None else total + gat
        own = z[:n_dst] if z.dim() == 2 else z[:, :n_dst]
        linear = f"encoder.{index}.linear"
        return total + _linear(own, p[f"{linear}.weight"], p[f"{linear}.bias"])

    def _encode(self, batch: dict) -> torch.Tensor:
        """(M, A, H) present embeddings of the batch's targets."""
        layers = self.config.layers
        plan = batch.get("plan")
        if plan is None or plan.layers != layers:
            plan = make_plan(batch["x"].shape[0], batch["target_node"], edge_inputs(batch), layers)
        z = batch["x"].index_select(0, plan.order)  # (n, F), shared
        for index in range(layers):
            z = self._layer(index, z, plan.sizes[index + 1], plan.adjacency)
            if index < layers - 1:
                z = self._dropout(torch.relu(z))
        return z.index_select(1, plan.outputs)

    # ---------------------------------------------------------------------------------------------
    # Decoder

    def _decoder_weights(self) -> list[torch.Tensor]:
        """The GRU's and the MLP's weights, transposed for batched products, biases (M, 1, out)."""
        p = self.params
        names = ("decoder.weight_ih", "decoder.weight_hh", "output.0.weight", "output.2.weight")
        weights = [p[name].transpose(1, 2) for name in names]
        names = ("decoder.bias_ih", "decoder.bias_hh", "output.0.bias", "output.2.bias")
        return weights + [p[name].unsqueeze(1) for name in names]

    @staticmethod
    def _gru(x, hidden, w_ih, w_hh, b_ih, b_hh) -> torch.Tensor:  # noqa: ANN001
        """`nn.GRUCell` of each member, in ATen's order of operations: (M, A, H) -> (M, A, H)."""
        i_r, i_z, i_n = torch.baddbmm(b_ih, x, w_ih).chunk(3, 2)
        h_r, h_z, h_n = torch.baddbmm(b_hh, hidden, w_hh).chunk(3, 2)
        reset = torch.sigmoid(h_r + i_r)
        update = torch.sigmoid(h_z + i_z)
        new = torch.tanh(i_n + h_n * reset)
        return (hidden - new) * update + new

    def _decode(self, z: torch.Tensor, start_xy: torch.Tensor, cv_step) -> torch.Tensor:  # noqa: ANN001
        """`AiGem._decode` of each member over its own steps: z (M, A, H), start_xy (A, 2) ->
        (M, A, K, 2), zeros after a member's steps."""
        weights = self._decoder_weights()
        hidden, before_g, previous_g = torch.zeros_like(z), torch.zeros_like(z), z
        position = start_xy.expand(self.members, *start_xy.shape)
        first, segments, outputs = 0, [], []  # members [first:] still decode
        for step in range(self.steps[-1]):
            done = sum(s <= step for s in self.steps) - first
            if done:  # the members [first:first + done] have decoded all their steps
                segments.append(F.pad(torch.stack(outputs, 2), (0, 0, 0, 0, 0, 0, first, 0)))
                first, outputs = first + done, []
                hidden, before_g = hidden[done:], before_g[done:]
                previous_g, position = previous_g[done:], position[done:]
                weights = [w[done:] for w in weights]
            w_ih, w_hh, w_1, w_2, b_ih, b_hh, b_1, b_2 = weights
            gru_in = z if step == 0 else previous_g + before_g
            hidden = self._gru(gru_in, hidden, w_ih, w_hh, b_ih, b_hh)  # g_k, (M', A, H)
            before_g, previous_g = previous_g, hidden
            mlp_in = torch.cat([hidden, position], -1) if self.config.concat_position else hidden
            mlp_hidden = torch.relu(torch.baddbmm(b_1, mlp_in, w_1))
            position = position + torch.baddbmm(b_2, mlp_hidden, w_2)
            if cv_step is not None:
                position = position + cv_step
            outputs.append(position)
        segments.append(F.pad(torch.stack(outputs, 2), (0, 0, 0, 0, 0, 0, first, 0)))
        return segments[0] if len(segments) == 1 else torch.cat(segments, 2)

    def __call__(self, batch: dict) -> torch.Tensor:
        """(M, A, K, 2) scaled predicted positions of the batch's targets, K = max(steps)."""
        cv_step = batch.get("cv_step") if self.config.cv_residual else None
        if self.config.cv_residual and cv_step is None:
            raise ValueError("a model with cv_residual needs the batch's cv_step")
        start_xy = batch["x"][batch["target_node"], :2]
        return self._decode(self._encode(batch), start_xy, cv_step)

    # ---------------------------------------------------------------------------------------------
    # Training

    def member_losses(
        self, model_out: torch.Tensor, batch: dict[str, torch.Tensor], scaler: MinMaxScaler
    ) -> torch.Tensor:
        """(M,) each member's `aigem.epochs.masked_mse_m2` over its own steps, in metres^2."""
        steps = model_out.shape[2]
        predicted = xy_to_metres(scaler, model_out)  # (M, A, K, 2)
        truth = batch["target_xy"][:, :steps]
        mask = batch["target_mask"][:, :steps].to(predicted.dtype) * self.scored  # (M, A, K)
        squared = ((predicted - truth) ** 2).sum(dim=-1) * mask
        return squared.sum((1, 2)) / mask.sum((1, 2)).clamp(min=1.0)

    def clip_gradients(self, max_norm: float | None) -> None:
        """`torch.nn.utils.clip_grad_norm_` of each member over its own gradients (None: none)."""
        if max_norm is None:
            return
        grads = [p.grad for p in self.parameters() if p.grad is not None]
        norms = torch.stack([torch.linalg.vector_norm(g.flatten(1), dim=1) for g in grads])
        total = torch.linalg.vector_norm(norms, dim=0)  # (M,)
        # clip_grad_norm_'s own 1e-6: the clipped steps are a model's alone (test_aigem_ensemble)
        scale = torch.clamp(max_norm / (total + 1e-6), max=1.0)
        for grad in grads:
            grad.mul_(scale.view(-1, *[1] * (grad.dim() - 1)))


# -------------------------------------------------------------------------------------------------
# In and out: members' parameters and Adam states


def stack(
    models: Sequence[AiGem], steps: Sequence[int], streams: Sequence[torch.Tensor] | None = None
) -> Ensemble:
    """An ensemble of copies of `models` (one ModelConfig), member m with `steps[m]` steps."""
    configs = {model.config for model in models}
    if len(configs) != 1:
        raise ValueError("an ensemble's members share one ModelConfig")
    params, _ = torch.func.stack_module_state(list(models))
    return Ensemble(params, models[0].config, steps, streams)


def unstack(ensemble: Ensemble, models: Sequence[AiGem]) -> None:
    """Copy each member's parameters back into its model (the model's own tensors, so that its
    optimiser still holds them)."""
    with torch.no_grad():
        for index, model in enumerate(models):
            for name, parameter in model.named_parameters():
                parameter.copy_(ensemble.params[name][index])


def stack_optimizer(
    ensemble: Ensemble, optimizers: Sequence[torch.optim.Optimizer]
) -> torch.optim.Optimizer:
    """One optimiser of the members' kind and settings over the ensemble's parameters, holding
    their states stacked. The members' optimisers are of one kind, have one parameter group each,
    with the same settings but for the learning rate (which the training loop sets before each
    step), and have taken the same number of steps: a step count, a 0-d state, is shared."""
    saved = [optimizer.state_dict() for optimizer in optimizers]
    groups = saved[0]["param_groups"]
    if any(len(s["param_groups"]) != 1 for s in saved):
        raise ValueError("an ensemble's members' optimisers have one parameter group each")
    if len({type(optimizer) for optimizer in optimizers}) != 1:
        raise ValueError("an ensemble's members' optimisers are of one kind")
    first = groups[0]
    for other in (s["param_groups"][0] for s in saved[1:]):
        for key in sorted((first.keys() | other.keys()) - {"params", "lr"}):
            if first.get(key) != other.get(key):
                raise ValueError(f"the members' optimisers differ in {key!r}")
    state = {}
    for index in saved[0]["state"]:
        entries = [s["state"][index] for s in saved]
        state[index] = {}
        for key, value in entries[0].items():
            values = [entry[key] for entry in entries]
            if value.dim() > 0:
                state[index][key] = torch.stack(values)
            elif all(torch.equal(value, other) for other in values):
                state[index][key] = value.clone()
            else:
                raise ValueError(f"the members' optimisers differ in {key!r}")
    optimizer = type(optimizers[0])(ensemble.parameters(), **optimizers[0].defaults)
    optimizer.load_state_dict({"state": state, "param_groups": groups})
    return optimizer


def unstack_optimizer(
    stacked: torch.optim.Optimizer, optimizers: Sequence[torch.optim.Optimizer]
) -> None:
    """Load each member's share of the ensemble's optimiser state into its own optimiser."""
    saved = stacked.state_dict()
    for member, optimizer in enumerate(optimizers):
        state = {
            index: {
                key: (value[member] if value.dim() > 0 else value).clone()
                for key, value in entry.items()
            }
            for index, entry in saved["state"].items()
        }
        optimizer.load_state_dict({"state": state, "param_groups": saved["param_groups"]})
