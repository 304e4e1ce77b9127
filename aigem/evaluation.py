"""`aigem evaluate`: the best model of a run and the constant-velocity baseline on one split.

Both are scored on the same samples and targets, with the metrics of aigem.metrics (metres).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader

from aigem.data import Collate, GraphDataset
from aigem.metrics import ErrorTotals, summarize
from aigem.model import count_parameters
from aigem.runs import load_model
from aigem.training import pick_device
from ngsim_graphs.schema import Split

# The paper's table (NGSIM US-101 + I-80, metres), for comparison only.
PAPER_TABLE = {
    "AiGem (paper)": {"ade_m": 1.42, "fde_m": 2.57, "rmse_m": (0.61, 1.02, 1.27, 1.84, 1.95), "params_k": 74.5},
    "CS-LSTM (paper)": {"ade_m": 2.29, "fde_m": 3.34, "rmse_m": (0.61, 1.27, 2.09, 3.10, 4.37), "params_k": 192},
    "GSTCN (paper)": {"ade_m": 1.52, "fde_m": None, "rmse_m": (0.44, 0.83, 1.33, 2.01, 2.98), "params_k": 49.8},
}


@dataclass(frozen=True)
class Evaluation:
    split: str
    horizon_steps: int
    samples: int
    parameters: int  # of the model
    model: dict[str, dict[str, float | None]]
    constant_velocity: dict[str, dict[str, float | None]]
    build_dir: str


def constant_velocity(state: np.ndarray, steps: int, time_step_s: float) -> np.ndarray:
    """(A, 4) present [x, y, heading, speed] -> (A, steps, 2) positions at constant velocity."""
    k = np.arange(1, steps + 1)[None, :, None] * time_step_s
    velocity = state[:, 3:4] * np.stack([np.sin(state[:, 2]), np.cos(state[:, 2])], axis=1)  # (A, 2)
    return state[:, None, :2] + k * velocity[:, None, :]


def evaluate(
    run_dir: Path,
    build_dir: Path,
    split: Split | str = Split.TEST,
    device_choice: str = "auto",
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
) -> Evaluation:
    """Score the run's best model and the constant-velocity baseline on `split` of `build_dir`."""
    device = pick_device(device_choice)
    model, info = load_model(run_dir, device)
    dataset = GraphDataset(build_dir, split, history_steps=model.config.history_steps_read)
    steps = round(info["train"]["horizon_s"] / dataset.config.time_step_s)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, collate_fn=Collate(dataset.scaler))
    ours, baseline = ErrorTotals(steps), ErrorTotals(steps)
    with torch.no_grad():
        for index, batch in enumerate(loader):
            predicted = dataset.scaler.xy_to_metres(model({k: v.to(device) for k, v in batch.items()}, steps))
            truth = batch["target_xy"][:, :steps].numpy()
            mask = batch["target_mask"][:, :steps].numpy()
            state = batch["target_state"].numpy().astype(np.float64)
            ours.add(predicted.cpu().numpy(), truth, mask, state[:, 1])
            baseline.add(constant_velocity(state, steps, dataset.config.time_step_s), truth, mask, state[:, 1])
            if progress:
                progress(index + 1, len(loader))
    return Evaluation(
        split=Split(split).value,
        horizon_steps=steps,
        samples=len(dataset),
        parameters=count_parameters(model),
        model=summarize(ours, dataset.config.time_step_s),
        constant_velocity=summarize(baseline, dataset.config.time_step_s),
        build_dir=str(build_dir),
    )


def as_dict(result: Evaluation) -> dict[str, Any]:
    return {**result.__dict__, "paper": PAPER_TABLE}
