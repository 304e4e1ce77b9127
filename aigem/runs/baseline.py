"""The constant-velocity baseline: its predictions, and its loss as `aigem fit` measures a model's.

Constant velocity carries each target actor on from its present position at its present speed
and heading. `constant_velocity_loss_m2` is its validation loss in the definition of fit's
`val_loss_m2` (aigem.training.epochs): the squared Euclidean error in metres^2, pooled over every valid
(target, step) of the split up to the horizon. `aigem fit` records it per run at its start
(`record_baselines`; baseline.json, aigem.runs.records) and draws it into curves.png as the line a model
has to get below.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from aigem.runs.run_log import read_baseline, write_baseline
from ngsim_graphs.build import open_build
from ngsim_graphs.schema import Split
from ngsim_graphs.splits import split_named

CHUNK_SAMPLES = 4096  # graphs induced at once: bounded memory on the largest builds


def constant_velocity(state: np.ndarray, steps: int, time_step_s: float) -> np.ndarray:
    """(A, 4) present [x, y, heading, speed] -> (A, steps, 2) positions at constant velocity."""
    k = np.arange(1, steps + 1)[None, :, None] * time_step_s
    velocity = state[:, 3:4] * np.stack(
        [np.sin(state[:, 2]), np.cos(state[:, 2])], axis=1
    )  # (A, 2)
    return state[:, None, :2] + k * velocity[:, None, :]


def constant_velocity_loss_m2(
    build_dir: Path, split: Split | str, steps: Sequence[int]
) -> dict[int, float]:
    """Constant velocity's masked MSE (metres^2) over `split` of a build, for each number of
    future steps in `steps`; NaN where no step is valid. One pass over the split's targets, the
    graphs cut to the present step (the targets and their present states are the same)."""
    build = open_build(build_dir)
    config = build.config
    longest = max(steps)
    squared = np.zeros(longest)  # summed over targets, per future step
    valid = np.zeros(longest)
    size = int(build.manifest.splits[split_named(split).value])
    for first in range(0, size, CHUNK_SAMPLES):
        ids = np.arange(first, min(first + CHUNK_SAMPLES, size))
        batch = build.graphs(split, ids, first_step=config.history_steps - 1)
        state = batch.node_features[batch.target_node]  # (A, 4)
        predicted = constant_velocity(state, longest, config.time_step_s)
        mask = batch.target_mask[:, :longest]
        error = ((predicted - batch.target_xy[:, :longest]) ** 2).sum(axis=-1)  # (A, K)
        squared += (error * mask).sum(axis=0)
        valid += mask.sum(axis=0)
    return {
        k: float(squared[:k].sum() / valid[:k].sum()) if valid[:k].sum() else float("nan")
        for k in steps
    }


def record_baselines(build_dir: Path, models: Sequence[tuple[Path, int]]) -> None:
    """Record constant velocity's validation loss in each (run directory, future steps) that has
    none yet (baseline.json, aigem.runs.records), in one pass over the validation split: a fresh run's,
    or a resumed run's of an older aigem; a resumed run keeps its own."""
    missing = [(run_dir, steps) for run_dir, steps in models if read_baseline(run_dir) is None]
    if missing:
        losses = constant_velocity_loss_m2(build_dir, Split.VAL, [steps for _, steps in missing])
        for run_dir, steps in missing:
            write_baseline(run_dir, losses[steps], steps)
