"""A run's predictions for chosen samples, beside constant velocity's, in metres: for pictures.

The graphs are returned whole (every history step, metres, as the build stores them) for
drawing; the model reads the same samples' last `history_steps_read` steps, scaled with the run's
scaler, as in `aigem.evaluation.evaluate`. Both batches hold the same targets in the same order (the
actor nodes of the present step, by sample and track id), which is checked, not assumed.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from aigem.config import horizon_steps
from aigem.devices import pick_device
from aigem.model.data import Collate, GraphDataset, run_scaler, xy_to_metres
from aigem.runs.baseline import constant_velocity
from aigem.runs.checkpoints import load_model
from aigem.runs.records import BEST, read_group
from aigem.runs.refusals import check_build, resolve_build
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.schema import Split

MODEL_LABEL = "AiGem"
BASELINE_LABEL = "constant velocity"


def predicting_run(run_dir: Path | str) -> Path:
    """The run directory of the run's model that predicts: its longest-horizon member (RUN/h5s
    of RUN/h1s..h5s; a run of one model, its folder)."""
    return read_group(Path(run_dir)).longest


def same_targets(a: GraphBatch, b: GraphBatch) -> bool:
    """Whether two batches of the same samples hold the same targets in the same order (their
    sample and track)."""
    return np.array_equal(a.node_sample[a.target_node], b.node_sample[b.target_node]) and (
        np.array_equal(a.node_track[a.target_node], b.node_track[b.target_node])
    )


def predict_samples(
    run_dir: str | os.PathLike[str],
    build_dir: str | os.PathLike[str] | None,
    split: Split | str,
    sample_ids: np.ndarray | Sequence[int],
    device_choice: str = "cpu",
) -> tuple[GraphBatch, dict[str, np.ndarray]]:
    """The graphs of samples `sample_ids` of `split` (metres, every history step) and
    {"AiGem": (T, K, 2), "constant velocity": (T, K, 2)} predicted positions in metres, in the
    sample frame, aligned with the graphs' T targets; K: the run's horizon in steps.

    `build_dir` must be the run's own build (None: the one it records), as `aigem evaluate`
    requires without --other-build.
    """
    run_dir = predicting_run(Path(run_dir))
    build_dir = None if build_dir is None else Path(build_dir)
    device = pick_device(device_choice)
    model, info = load_model(run_dir, device)
    build_dir = resolve_build(info, build_dir)
    refusal = "its predictions are made on its own build only"
    check_build(info, build_dir, run_dir, model.config, other_build=False, refusal=refusal)
    scaler = run_scaler(info.build.scaler, run_dir / BEST)
    dataset = GraphDataset(build_dir, split, model.config.history_steps_read, scaler)
    ids = np.asarray(sample_ids, dtype=np.int64)
    graphs = dataset.build.graphs(dataset.split, ids)
    read = dataset.build.graphs(dataset.split, ids, dataset.first_step)  # what the model reads
    if not same_targets(graphs, read):
        raise RuntimeError("the model's batch holds other targets than the drawn graphs")
    batch = Collate(scaler, layers=model.config.layers)([read])
    steps = horizon_steps(info.train.horizon_s, dataset.config.time_step_s)
    with torch.no_grad():
        predicted = xy_to_metres(scaler, model(batch.to(device), steps)).cpu().numpy()
    if not np.isfinite(predicted).all():
        raise NgsimInputError(run_dir / BEST, "its predictions are not finite (NaN or infinite)")
    present = graphs.node_features[graphs.target_node]  # (T, 4)
    return graphs, {
        MODEL_LABEL: predicted.astype(np.float64),
        BASELINE_LABEL: constant_velocity(present, steps, dataset.config.time_step_s),
    }
