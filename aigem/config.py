"""Frozen configuration dataclasses of the model and of training. Field names carry units."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class ModelConfig:
    """AiGem's shape (SPEC section 5). The default has 74,242 parameters (the paper: 74.5 K)."""

    node_features: int = 4  # [x, y, heading, speed]
    hidden: int = 64  # encoder and GRU width
    layers: int = 4  # L: GAT + linear encoder layers
    heads: int = 1  # GAT attention heads (outputs averaged, so the width stays `hidden`)
    mlp_hidden: int = 128
    dropout: float = 0.05
    concat_position: bool = True  # the output MLP sees the previous position (ablation: False)
    future_steps: int = 25  # K_F predicted steps (5 s at 0.2 s)

    @property
    def history_steps_read(self) -> int:
        """History steps that reach the present-step embeddings: temporal edges join consecutive
        steps, so L layers read the present and the L steps before it."""
        return self.layers + 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class TrainConfig:
    """How `aigem fit` trains."""

    horizon_s: float = 5.0  # the paper trains one model per horizon, 1..5 s
    epochs: int = 100
    batch_size: int = 32  # samples (graphs) per batch
    learning_rate: float = 1e-3
    max_minutes: float | None = None  # stop after this much training time
    patience_epochs: int | None = None  # early stop without a better validation loss
    seed: int = 0
    workers: int | None = None  # DataLoader worker processes (None: aigem.cores.default_workers)
    threads: int | None = None  # intra-op CPU threads (None: the idle usable cores, aigem.cores)

    def __post_init__(self) -> None:
        if not 0 < self.horizon_s <= 5.0:
            raise ValueError("horizon_s must be in (0, 5]")
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError("epochs and batch_size must be >= 1")
        if self.workers is not None and self.workers < 0:
            raise ValueError("workers must be >= 0")
        if self.threads is not None and self.threads < 1:
            raise ValueError("threads must be >= 1")

    def horizon_steps(self, time_step_s: float) -> int:
        """Future steps predicted and scored: 5 per second at 0.2 s."""
        return round(self.horizon_s / time_step_s)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
