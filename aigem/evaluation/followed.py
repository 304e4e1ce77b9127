"""The target a scene picture follows (ngsim_graphs.scene_target), and what its title says of it.

final_errors_m   each drawn target's displacement error at a prediction's last step
median_targets   per sample, the target of its median AiGem final error (`show --run`)
matched_target   the drawn target of one an evaluation chose (`evaluate`'s scenes.png)
followed_words   a panel's words on its target: its vehicle and both final errors
predicted_scenes a run's predictions for chosen samples, each sample's median target
                 followed, and its words (what `ngsim-graphs show --run` draws)
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from aigem.metrics import displacement_errors_m
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.scenes import vehicle_ids

MATCH_TOLERANCE_M = 1e-3  # the drawn predictions against the evaluated ones: float rounding


def final_errors_m(
    batch: GraphBatch, predictions: Mapping[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """label -> (T,) each of the batch's targets' displacement error in metres at the
    prediction's last step (its K of (T, K, 2)), NaN where the target is not recorded then."""
    errors = {}
    for label, values in predictions.items():
        steps = np.shape(values)[1]
        mask = batch.target_mask[:, :steps]
        error_m = displacement_errors_m(np.asarray(values), batch.target_xy[:, :steps], mask)
        errors[label] = np.where(mask[:, -1], error_m[:, -1], np.nan)
    return errors


def _targets_of(batch: GraphBatch, sample: int) -> np.ndarray:
    return np.flatnonzero(batch.node_sample[batch.target_node] == sample)


def median_targets(batch: GraphBatch, error_m: np.ndarray) -> list[int]:
    """Per sample of the batch, the target (an index into its targets) of the median of the
    sample's errors `error_m` (T,), the lower of two middle ones; its first target where none
    has an error (none recorded to the last step)."""
    chosen = []
    for sample in range(batch.n_samples):
        mine = _targets_of(batch, sample)
        known = mine[np.isfinite(error_m[mine])]
        if not len(known):
            chosen.append(int(mine[0]))
            continue
        ordered = known[np.argsort(error_m[known], kind="stable")]
        chosen.append(int(ordered[(len(ordered) - 1) // 2]))
    return chosen


def matched_target(batch: GraphBatch, sample: int, error_m: np.ndarray, wanted_m: float) -> int:
    """The target of the batch's sample `sample` whose error (of `error_m`, (T,)) is
    `wanted_m`, an evaluation's number for one of its targets; a RuntimeError where none is
    within MATCH_TOLERANCE_M (the drawn predictions would not be the evaluated ones)."""
    mine = _targets_of(batch, sample)
    gaps = np.abs(np.nan_to_num(error_m[mine], nan=np.inf) - wanted_m)
    if not len(mine) or gaps.min() > MATCH_TOLERANCE_M:
        raise RuntimeError(f"no drawn target of sample {sample} has the evaluated {wanted_m} m")
    return int(mine[np.argmin(gaps)])


def followed_words(
    target: int, vehicle: int, errors_m: Mapping[str, np.ndarray], horizon_s: float
) -> str:
    """ "vehicle 1234: final error at 5 s AiGem 8.12 m, constant velocity 6.20 m" ("not
    recorded at 5 s" where the target is not)."""
    values = {label: float(error[target]) for label, error in errors_m.items()}
    if not all(np.isfinite(list(values.values()))):
        return f"vehicle {vehicle}: not recorded at {horizon_s:g} s"
    said = ", ".join(f"{label} {value:.2f} m" for label, value in values.items())
    return f"vehicle {vehicle}: final error at {horizon_s:g} s {said}"


def predicted_scenes(
    run_dir: str | os.PathLike[str],
    build_dir: str | os.PathLike[str],
    split: str,
    sample_ids: Sequence[int],
) -> tuple[GraphBatch, dict[str, np.ndarray], list[int], list[str]]:
    """The graphs of `sample_ids`, the run's and constant velocity's predictions
    (aigem.evaluation.prediction.predict_samples), each sample's followed target (its median by AiGem's
    final error, median_targets) and the words on it for the panel's title; an
    NgsimInputError where a sample holds no target."""
    from aigem.evaluation.prediction import (
        BASELINE_LABEL,
        MODEL_LABEL,
        predict_samples,
    )  # loads torch

    batch, predictions = predict_samples(run_dir, build_dir, split, sample_ids)
    empty = [int(i) for b, i in enumerate(sample_ids) if not len(_targets_of(batch, b))]
    if empty:
        raise NgsimInputError(
            Path(build_dir),
            f"{split} sample(s) {', '.join(map(str, empty))} hold no target: nothing to follow "
            "(draw them without --run)",
        )
    errors = final_errors_m(batch, predictions)
    follow = median_targets(batch, errors[MODEL_LABEL])
    tracks = batch.node_track[batch.target_node[follow]]
    vehicles = vehicle_ids(open_build(build_dir).tracks(), tracks)
    horizon_s = predictions[MODEL_LABEL].shape[1] * batch.time_step_s
    ordered = {MODEL_LABEL: errors[MODEL_LABEL], BASELINE_LABEL: errors[BASELINE_LABEL]}
    words = []
    for sample, target, track in zip(range(batch.n_samples), follow, tracks, strict=True):
        counted = int(np.isfinite(errors[MODEL_LABEL][_targets_of(batch, sample)]).sum())
        said = followed_words(target, vehicles[int(track)], ordered, horizon_s)
        words.append(f"followed: the median of {counted} targets by AiGem's final error,\n{said}")
    return batch, predictions, follow, words
