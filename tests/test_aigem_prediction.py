"""aigem.evaluation.prediction: a run's predictions for chosen samples, aligned with the drawn graphs'
targets, in metres; the same numbers as `aigem evaluate` scores."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aigem.config import ModelConfig, TrainConfig
from aigem.evaluation.evaluate import evaluate
from aigem.evaluation.prediction import BASELINE_LABEL, MODEL_LABEL, predict_samples, predicting_run
from aigem.model.data import Collate, GraphDataset
from aigem.runs.checkpoints import load_model
from aigem.training.fit import fit_horizons
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.pipeline import run_build

STEPS = 10  # the tiny run's 2 s horizon at 0.2 s steps


def test_shapes_and_targets(tiny_run: Path, tiny_build: Path) -> None:
    ids = np.arange(5)
    graphs, predictions = predict_samples(tiny_run, tiny_build, "val", ids)
    assert graphs.n_samples == 5 and graphs.node_step.min() == 0  # whole graphs, every step
    targets = len(graphs.target_node)
    assert targets > 0 and list(predictions) == [MODEL_LABEL, BASELINE_LABEL]
    for values in predictions.values():
        assert values.shape == (targets, STEPS, 2) and np.isfinite(values).all()


def test_collated_targets_are_the_graphs_targets(tiny_run: Path, tiny_build: Path) -> None:
    """The model's batch (last steps only, scaled) holds the drawn graphs' targets in order."""
    model, info = load_model(tiny_run)
    dataset = GraphDataset(tiny_build, "val", model.config.history_steps_read)
    assert dataset.first_step > 0  # the model reads fewer steps: two different batches
    ids = np.array([6, 0, 3, 1])  # any order
    graphs = open_build(tiny_build).graphs("val", ids)
    batch = Collate(dataset.scaler)([dataset.build.graphs("val", ids, dataset.first_step)])
    present = graphs.node_features[graphs.target_node]
    assert np.array_equal(batch.target_state.numpy(), present.astype(np.float32))
    assert np.array_equal(batch.target_xy.numpy(), graphs.target_xy.astype(np.float32))
    assert np.array_equal(batch.target_mask.numpy(), graphs.target_mask)
    assert np.array_equal(batch.target_sample.numpy(), graphs.node_sample[graphs.target_node])


def test_errors_equal_evaluate(tiny_run: Path, tiny_build: Path) -> None:
    """ADE over the whole split from these predictions is `aigem evaluate`'s, for both."""
    size = open_build(tiny_build).manifest.splits["val"]
    graphs, predictions = predict_samples(tiny_run, tiny_build, "val", np.arange(size))
    result = evaluate(tiny_run, tiny_build, "val", device_choice="cpu")
    mask = graphs.target_mask[:, :STEPS]
    for label, rows in ((MODEL_LABEL, result.model), (BASELINE_LABEL, result.constant_velocity)):
        error = np.linalg.norm(predictions[label] - graphs.target_xy[:, :STEPS], axis=-1)
        assert error[mask].mean() == pytest.approx(rows["all"]["ade_m"], rel=1e-5)


def test_a_sample_alone_is_predicted_as_in_a_batch(tiny_run: Path, tiny_build: Path) -> None:
    graphs, together = predict_samples(tiny_run, tiny_build, "val", np.arange(4))
    alone_graphs, alone = predict_samples(tiny_run, tiny_build, "val", np.array([2]))
    rows = graphs.node_sample[graphs.target_node] == 2
    assert rows.sum() == len(alone_graphs.target_node)
    for label in (MODEL_LABEL, BASELINE_LABEL):
        assert np.allclose(together[label][rows], alone[label], atol=1e-4)


def test_another_build_is_refused(tiny_run: Path, tiny_build: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    run_build([tiny_build.parent / "raw"], other, BuildConfig(d_sense_m=12.0, d_min_m=3.0))
    with pytest.raises(NgsimInputError, match="not the build that run"):
        predict_samples(tiny_run, other, "val", np.arange(2))


def test_a_multi_horizon_run_predicts_with_its_longest(tiny_build: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    train = TrainConfig(epochs=1, batch_size=8, horizon_s=1.0, seed=3)
    fit_horizons(tiny_build, run, (1.0, 0.6), ModelConfig(), train, "cpu")
    assert predicting_run(run) == run / "h1s" and predicting_run(run / "h1s") == run / "h1s"
    graphs, predictions = predict_samples(run, None, "val", np.arange(2))  # None: the run's build
    assert predictions[MODEL_LABEL].shape == (len(graphs.target_node), 5, 2)
