"""AiGem: agent-interaction graph embedding for trajectory prediction (model, data, training).

The names a researcher needs, importable from the package itself:

    from aigem import AiGem, Collate, GraphDataset, ModelConfig, load_model, predict_samples

They are imported on first use (PEP 562): PyTorch takes seconds to import, and `aigem --help`
should not wait for it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ngsim_graphs.version import __version__  # one distribution, one version

_EXPORTS = {
    "AiGem": "aigem.model",
    "count_parameters": "aigem.model",
    "ModelConfig": "aigem.config",
    "TrainConfig": "aigem.config",
    "GraphDataset": "aigem.data",
    "Collate": "aigem.data",
    "xy_to_metres": "aigem.data",
    "GraphPygDataset": "aigem.pyg",
    "to_hetero_data": "aigem.pyg",
    "to_model_batch": "aigem.pyg",
    "masked_mse_m2": "aigem.loss",
    "fit": "aigem.training",
    "fit_horizons": "aigem.training",
    "load_model": "aigem.checkpoints",
    "evaluate": "aigem.evaluation",
    "constant_velocity": "aigem.baseline",
    "predict_samples": "aigem.prediction",
}
__all__ = [
    "__version__",
    "AiGem",
    "count_parameters",
    "ModelConfig",
    "TrainConfig",
    "GraphDataset",
    "Collate",
    "xy_to_metres",
    "GraphPygDataset",
    "to_hetero_data",
    "to_model_batch",
    "masked_mse_m2",
    "fit",
    "fit_horizons",
    "load_model",
    "evaluate",
    "constant_velocity",
    "predict_samples",
]

if TYPE_CHECKING:
    from aigem.baseline import constant_velocity
    from aigem.checkpoints import load_model
    from aigem.config import ModelConfig, TrainConfig
    from aigem.data import Collate, GraphDataset, xy_to_metres
    from aigem.evaluation import evaluate
    from aigem.loss import masked_mse_m2
    from aigem.model import AiGem, count_parameters
    from aigem.prediction import predict_samples
    from aigem.pyg import GraphPygDataset, to_hetero_data, to_model_batch
    from aigem.training import fit, fit_horizons


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    """The public names (__all__), not this module's own imports (importlib, typing's names)."""
    return sorted(__all__)
