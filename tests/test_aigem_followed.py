"""aigem.evaluation.followed: which target a scene follows, on test_scenes' hand-made batch whose errors are
3-4-5 triangles, and on the tiny run's predictions, checked target by target."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_scenes import hand_batch

from aigem.evaluation import prediction
from aigem.evaluation.followed import (
    final_errors_m,
    followed_words,
    matched_target,
    median_targets,
    predicted_scenes,
)
from aigem.evaluation.prediction import BASELINE_LABEL, MODEL_LABEL
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.scenes import write_scenes


def hand_predictions() -> dict[str, np.ndarray]:
    """At the last of 4 steps (truth: A (3, 12), B (-3, 12), C masked): AiGem 4 m off A
    (3, 8) and 5 m off B (0, 8); constant velocity 3 m off A (3, 9), 0 m off B."""
    aigem = np.zeros((3, 4, 2))
    aigem[:, -1] = [(3.0, 8.0), (0.0, 8.0), (0.0, 0.0)]
    cv = np.zeros((3, 4, 2))
    cv[:, -1] = [(3.0, 9.0), (-3.0, 12.0), (0.0, 0.0)]
    return {MODEL_LABEL: aigem, BASELINE_LABEL: cv}


def test_final_errors_and_the_median_target_by_hand() -> None:
    batch = hand_batch()
    errors = final_errors_m(batch, hand_predictions())
    np.testing.assert_allclose(errors[MODEL_LABEL], [4.0, 5.0, np.nan])
    np.testing.assert_allclose(errors[BASELINE_LABEL], [3.0, 0.0, np.nan])
    # Sample 0: 4 and 5 m, the lower middle one; sample 1: C not recorded at the end, its first.
    assert median_targets(batch, errors[MODEL_LABEL]) == [0, 2]
    assert median_targets(batch, np.array([4.0, 1.0, np.nan])) == [1, 2]


def test_a_chosen_target_is_matched_by_its_evaluated_error() -> None:
    batch = hand_batch()
    errors = final_errors_m(batch, hand_predictions())[MODEL_LABEL]
    assert matched_target(batch, 0, errors, 5.0 + 1e-6) == 1
    assert matched_target(batch, 0, errors, 4.0) == 0
    with pytest.raises(RuntimeError, match="no drawn target of sample 0 has the evaluated 4.5 m"):
        matched_target(batch, 0, errors, 4.5)
    with pytest.raises(RuntimeError):
        matched_target(batch, 1, errors, 0.0)  # C has no final error


def test_the_words_on_a_followed_target() -> None:
    errors = final_errors_m(hand_batch(), hand_predictions())
    assert followed_words(1, 1234, errors, 0.8) == (
        "vehicle 1234: final error at 0.8 s AiGem 5.00 m, constant velocity 0.00 m"
    )
    assert followed_words(2, 7, errors, 0.8) == "vehicle 7: not recorded at 0.8 s"


def test_show_runs_scenes_follow_each_samples_median_target(
    tiny_run: Path, tiny_build: Path, tmp_path: Path
) -> None:
    ids = [0, 2, 4]
    batch, predictions, follow, words = predicted_scenes(tiny_run, tiny_build, "val", ids)
    errors = final_errors_m(batch, predictions)[MODEL_LABEL]
    for b, target in enumerate(follow):
        mine = np.flatnonzero(batch.node_sample[batch.target_node] == b)
        known = np.sort(errors[mine][np.isfinite(errors[mine])])
        assert target in mine and errors[target] == known[(len(known) - 1) // 2]
        assert words[b].startswith(f"followed: the median of {len(known)} targets")
        assert f"AiGem {errors[target]:.2f} m" in words[b]
    scenes = write_scenes(tmp_path / "p.png", batch, words, 12.0, predictions, follow=follow)
    assert [s.predicted for s in scenes] == [{MODEL_LABEL: 1, BASELINE_LABEL: 1}] * 3


def test_a_sample_without_target_is_one_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sample 1 of the hand batch, its target C taken away: nothing to follow, said so."""
    batch = hand_batch()
    alone = replace(
        batch,
        target_node=batch.target_node[:2],
        target_xy=batch.target_xy[:2],
        target_mask=batch.target_mask[:2],
    )
    predictions = {k: v[:2] for k, v in hand_predictions().items()}
    monkeypatch.setattr(prediction, "predict_samples", lambda *args: (alone, predictions))
    with pytest.raises(NgsimInputError, match="val sample\\(s\\) 8 hold no target"):
        predicted_scenes(tmp_path / "run", tmp_path / "build", "val", [7, 8])
