"""AiGem (SPEC section 5): a GAT + linear graph encoder, a GRU decoder, an MLP output.

Shapes: N nodes in a batch of graphs, A target actors, H = hidden width, K = future steps.
"""

from __future__ import annotations

import torch
from torch import nn
from torch_geometric.nn import GATConv

from aigem.config import ModelConfig


class EncoderLayer(nn.Module):
    """Z_l = GAT_spatial(Z, E_s) + GAT_temporal(Z, E_t) + Linear(Z): one GAT per edge type, summed."""

    def __init__(self, in_features: int, config: ModelConfig) -> None:
        super().__init__()
        gat = lambda: GATConv(  # noqa: E731
            in_features, config.hidden, heads=config.heads, concat=False, edge_dim=1,
            add_self_loops=False, dropout=config.dropout,
        )  # fmt: skip
        self.spatial = gat()
        self.temporal = gat()
        self.linear = nn.Linear(in_features, config.hidden)

    def forward(self, z, spatial_edges, spatial_attr, temporal_edges, temporal_attr):  # noqa: ANN001, ANN201
        return (
            self.spatial(z, spatial_edges, spatial_attr)
            + self.temporal(z, temporal_edges, temporal_attr)
            + self.linear(z)
        )  # (N, H)


class AiGem(nn.Module):
    """Predicts K future positions of each target actor from its graph's present-step embedding."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        widths = [config.node_features] + [config.hidden] * config.layers
        self.encoder = nn.ModuleList(EncoderLayer(w, config) for w in widths[:-1])
        self.dropout = nn.Dropout(config.dropout)
        self.decoder = nn.GRUCell(config.hidden, config.hidden)
        mlp_in = config.hidden + (2 if config.concat_position else 0)
        self.output = nn.Sequential(
            nn.Linear(mlp_in, config.mlp_hidden), nn.ReLU(), nn.Linear(config.mlp_hidden, 2)
        )

    def encode(self, x, spatial_edges, spatial_attr, temporal_edges, temporal_attr):  # noqa: ANN001, ANN201
        """(N, F) scaled node features -> (N, H) embeddings after L layers."""
        z = x
        for index, layer in enumerate(self.encoder):
            z = layer(z, spatial_edges, spatial_attr, temporal_edges, temporal_attr)
            if index < len(self.encoder) - 1:
                z = self.dropout(torch.relu(z))
        return z

    def decode(self, z_target: torch.Tensor, start_xy: torch.Tensor, steps: int) -> torch.Tensor:
        """(A, H) present embeddings, (A, 2) present positions -> (A, steps, 2) positions.

        GRU inputs: z at step 1, z + g_1 at step 2, g_{k-1} + g_{k-2} after; h_0 = 0.
        Y_k = Y_{k-1} + MLP([g_k, Y_{k-1}]), Y_0 the present position.
        """
        hidden = torch.zeros_like(z_target)
        previous_g, before_g = z_target, torch.zeros_like(z_target)  # so that step 1 sees z, step 2 z + g_1
        position, outputs = start_xy, []
        for step in range(steps):
            gru_in = z_target if step == 0 else previous_g + before_g
            hidden = self.decoder(gru_in, hidden)  # g_k, (A, H)
            before_g, previous_g = previous_g, hidden
            mlp_in = torch.cat([hidden, position], dim=-1) if self.config.concat_position else hidden
            position = position + self.output(mlp_in)  # (A, 2)
            outputs.append(position)
        return torch.stack(outputs, dim=1)  # (A, steps, 2)

    def forward(self, batch: dict[str, torch.Tensor], steps: int | None = None) -> torch.Tensor:
        """Scaled predicted positions (A, steps, 2) of the batch's targets."""
        z = self.encode(
            batch["x"], batch["spatial_edges"], batch["spatial_attr"],
            batch["temporal_edges"], batch["temporal_attr"],
        )  # fmt: skip
        target = batch["target_node"]
        return self.decode(z[target], batch["x"][target, :2], steps or self.config.future_steps)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
