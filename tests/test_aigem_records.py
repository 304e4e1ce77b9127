"""What a run records: configs read back from run info, settings a run lacks at their defaults,
a newer aigem's setting refused in one line; baseline.json written and read back."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from aigem.config import ModelConfig, TrainConfig
from aigem.records import (
    BASELINE,
    identity_difference,
    model_config,
    read_baseline,
    train_config,
    write_baseline,
)
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import config_hash, read_manifest


def test_settings_a_run_lacks_take_their_defaults(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    assert model_config({"model": {}}, path) == ModelConfig()
    assert model_config({"model": {"hidden": 32}}, path) == ModelConfig(hidden=32)
    assert train_config({"train": {"epochs": 3}}, path) == TrainConfig(epochs=3)


@pytest.mark.parametrize("key", ["model", "train"])
def test_a_setting_this_aigem_does_not_know_is_an_error(tmp_path: Path, key: str) -> None:
    path = tmp_path / "run.json"
    read = {"model": model_config, "train": train_config}[key]
    with pytest.raises(NgsimInputError) as error:
        read({key: {"zeta": 1, "alpha": 2}}, path)
    assert str(error.value) == (
        f"{path}: a {key} config this aigem does not know: unknown alpha, zeta "
        "(written by a newer aigem?)"
    )


def test_a_recorded_value_of_another_type_or_out_of_range_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    with pytest.raises(NgsimInputError, match="model config hidden = '64': expected a int"):
        model_config({"model": {"hidden": "64"}}, path)
    with pytest.raises(NgsimInputError, match="a train config this aigem cannot use: epochs"):
        train_config({"train": {"epochs": 0}}, path)


def test_baseline_round_trip(tmp_path: Path) -> None:
    assert read_baseline(tmp_path) is None  # a run without one (an older aigem's)
    write_baseline(tmp_path, 12.5, 25)
    assert json.loads((tmp_path / BASELINE).read_text()) == {
        "constant_velocity_val_loss_m2": 12.5,
        "steps": 25,
    }
    assert read_baseline(tmp_path) == 12.5
    (tmp_path / BASELINE).write_text('{"constant_velocity_val_loss_m2": true}')
    assert read_baseline(tmp_path) is None  # damaged: only the line is missing


def test_every_run_layout_reads_as_a_group(tiny_horizons_run: Path, tmp_path: Path) -> None:
    """read_group, the one adapter: aigem 0.1.0's run of one model is a group of one (its folder
    its member), a run of several the members its horizons.json names; a folder of neither is one
    error line."""
    from aigem.records import Group, group_of_member, planned_group, read_group

    old = Path(__file__).parent / "fixtures" / "run-0.1.0"
    assert read_group(old) == Group(old, (5.0,), (old,)) == planned_group(old, (5.0,))
    assert not read_group(old).named and read_group(old).who(old) == ""
    several = read_group(tiny_horizons_run)
    assert several.horizons_s == (1.0, 2.0) and several.named
    assert several.members == (tiny_horizons_run / "h1s", tiny_horizons_run / "h2s")
    assert several.longest == tiny_horizons_run / "h2s"
    assert several.who(several.members[0]) == "the 1 s model: "
    assert group_of_member(tiny_horizons_run / "h1s") == several
    with pytest.raises(NgsimInputError, match="not a run directory"):
        read_group(tmp_path)


def test_a_build_of_another_config_hash_names_the_settings_that_differ() -> None:
    """A run of a highD build made before the limits were the source's (its config held them,
    max_frame_id in NGSIM's 10 Hz frames), and the same build made today: its hash changes, and
    the refusal says why."""
    older = read_manifest(Path(__file__).parent / "fixtures" / "build-0.1.0" / "highd")
    run = {
        "build_config_hash": older.config_hash,
        "build_manifest_sha256": "a" * 64,
        "build_config": older.settings(),  # what the run recorded: the config with its limits
    }
    limits = replace(older.limits, max_frame_id=180_000)  # highD's own, today
    today = replace(
        older, limits=limits, config_hash=config_hash(older.config.to_dict(), limits.to_dict())
    )
    identity = {"build_config_hash": today.config_hash, "build_manifest_sha256": "b" * 64}
    assert identity_difference(run, identity, today.settings()) == (
        f"its config hash {today.config_hash[:12]} is not the run's dcfa1c68089b: "
        "limits.max_frame_id 72000 -> 180000"
    )
    hashes_only = f"its config hash {today.config_hash[:12]} is not the run's dcfa1c68089b"
    assert identity_difference(run, identity) == hashes_only  # without the build's settings
    other = replace(today, config=replace(older.config, d_min_m=25.0)).settings()
    assert identity_difference(run, identity, other).endswith(
        ": d_min_m 6.0 -> 25.0; limits.max_frame_id 72000 -> 180000"
    )
    same = {**identity, "build_config_hash": older.config_hash}
    assert identity_difference(run, same, older.settings()) == (
        "same config, but its manifest.json differs from the run's build (other inputs, or edited)"
    )
