"""What a run records: run info written and read back as typed records, settings a run lacks at
their defaults, a newer aigem's setting refused in one line, every layout of a run a group."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from aigem.config import ModelConfig, TrainConfig
from aigem.runs.provenance import BuildIdentity, BuildRecord, identity_difference
from aigem.runs.records import (
    RUN_INFO,
    RunState,
    info_of,
    model_config,
    read_record,
    run_info,
    state_json,
    state_of,
    train_config,
    write_record,
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
    with pytest.raises(NgsimInputError) as error:
        model_config({"model": {"layers": 0}}, path)
    assert str(error.value) == f"{path}: a model config this aigem cannot use: layers must be >= 1"
    with pytest.raises(NgsimInputError, match="cannot use: dropout must be below 1, not 1"):
        model_config({"model": {"dropout": 1.0}}, path)


@pytest.mark.parametrize(
    ("field", "value"), [("hidden", 0), ("heads", 0), ("future_steps", 0), ("dropout", -0.1)]
)
def test_a_model_config_of_no_model_is_refused(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        ModelConfig(**{field: value})


def test_every_run_layout_reads_as_a_group(tiny_horizons_run: Path, tmp_path: Path) -> None:
    """read_group, the one adapter: aigem 0.1.0's run of one model is a group of one (its folder
    its member), a run of several the members its horizons.json names; a folder of neither is one
    error line."""
    from aigem.runs.records import Group, group_of_member, planned_group, read_group

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
    recorded = BuildIdentity(older.config_hash, "a" * 64)
    # what the run recorded: the config with its limits
    run = BuildRecord(Path("/b"), recorded, 0.2, older.settings(), {})
    limits = replace(older.limits, max_frame_id=180_000)  # highD's own, today
    today = replace(
        older, limits=limits, config_hash=config_hash(older.config.to_dict(), limits.to_dict())
    )
    identity = BuildIdentity(today.config_hash, "b" * 64)
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
    same = replace(identity, config_hash=older.config_hash)
    assert identity_difference(run, same, older.settings()) == (
        "same config, but its manifest.json differs from the run's build (other inputs, or edited)"
    )


def test_run_info_is_written_as_recorded_and_reads_back_typed(
    tiny_build: Path, tmp_path: Path
) -> None:
    """run.json: the build's record, the configs and the digests, in INFO_KEYS' order; read back,
    the same typed record; a checkpoint's info (the same keys but the digests) alike."""
    info = run_info(tiny_build, ModelConfig(cv_residual=True), TrainConfig(epochs=3))
    write_record(tmp_path, info, {"best.pt": ("a" * 64,), "last.pt": ("b" * 64, "c" * 64)})
    document = json.loads((tmp_path / RUN_INFO).read_text())
    assert list(document) == [
        "build_dir", "build_config_hash", "build_manifest_sha256", "build_config", "scaler",
        "model", "train", "checkpoint_sha256",
    ]  # fmt: skip
    assert document["build_dir"] == str(tiny_build.resolve()) and document["train"]["epochs"] == 3
    assert document["checkpoint_sha256"] == {"best.pt": ["a" * 64], "last.pt": ["b" * 64, "c" * 64]}
    record = read_record(tmp_path)
    assert record.info == info and record.info.build.time_step_s == 0.2
    assert record.digests == {"best.pt": ("a" * 64,), "last.pt": ("b" * 64, "c" * 64)}
    assert info_of(info.to_json(), tmp_path / "best.pt") == info
    state = RunState(3, 1, 0.5)
    assert state_json(state) == {"next_epoch": 3, "best_epoch": 1, "best_val_loss": 0.5}
    assert state_of(state_json(state), tmp_path / "last.pt") == state
