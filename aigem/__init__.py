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
    "AiGem": "aigem.model.network",
    "count_parameters": "aigem.model.network",
    "ModelConfig": "aigem.config",
    "TrainConfig": "aigem.config",
    "GraphDataset": "aigem.model.data",
    "Collate": "aigem.model.data",
    "xy_to_metres": "aigem.model.data",
    "GraphPygDataset": "aigem.model.pyg",
    "to_hetero_data": "aigem.model.pyg",
    "to_model_batch": "aigem.model.pyg",
    "masked_mse_m2": "aigem.model.loss",
    "fit": "aigem.training.fit",
    "fit_horizons": "aigem.training.fit",
    "load_model": "aigem.runs.checkpoints",
    "evaluate": "aigem.evaluation.evaluate",
    "constant_velocity": "aigem.runs.baseline",
    "predict_samples": "aigem.evaluation.prediction",
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
    from aigem.config import ModelConfig, TrainConfig
    from aigem.evaluation.evaluate import evaluate
    from aigem.evaluation.prediction import predict_samples
    from aigem.model.data import Collate, GraphDataset, xy_to_metres
    from aigem.model.loss import masked_mse_m2
    from aigem.model.network import AiGem, count_parameters
    from aigem.model.pyg import GraphPygDataset, to_hetero_data, to_model_batch
    from aigem.runs.baseline import constant_velocity
    from aigem.runs.checkpoints import load_model
    from aigem.training.fit import fit, fit_horizons


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    """The public names (__all__), not this module's own imports (importlib, typing's names)."""
    return sorted(__all__)
