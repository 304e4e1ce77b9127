"""AiGem: agent-interaction graph embedding for trajectory prediction (model and training)."""

__version__ = "0.1.0"
