"""The typed manifest: written, read back and compared; its JSON form byte for byte; old and
malformed manifests."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
from test_build import synthetic_build

from ngsim_graphs import layout
from ngsim_graphs.config import BuildConfig, SplitMode
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.manifest import DEFAULT_DATASET, Manifest, json_form
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.scaling import MinMaxScaler


@pytest.fixture()
def copy(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> Path:
    """A copy of the session's synthetic build, free to be rewritten."""
    return Path(shutil.copytree(synthetic_build(tmp_path_factory)[1], tmp_path / "copy"))


def test_written_then_read_is_equal_and_the_same_bytes(copy: Path) -> None:
    before = layout.manifest_path(copy).read_bytes()
    read = layout.read_manifest(copy)
    assert read.manifest_sha256 is not None and read.files and read.dataset == "ngsim"
    written = layout.write_manifest(copy, read)
    assert layout.manifest_path(copy).read_bytes() == before
    assert written == read and layout.read_manifest(copy) == written
    assert read.to_dict() == json.loads(before)


def test_a_build_returns_the_manifest_it_wrote(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    raw = synthetic_build(tmp_path_factory)[0]
    result = run_build([raw], tmp_path / "out", BuildConfig())
    read = layout.read_manifest(tmp_path / "out")
    assert read == result.manifest and read.to_dict() == result.manifest.to_dict()
    assert read.config == BuildConfig() and read.scaler.is_fitted
    assert [r.index for r in read.recordings] == list(range(len(read.recordings)))
    assert read.counts.samples == sum(read.splits.values()) > 0


def test_an_unwritten_manifest_round_trips_through_its_dict(copy: Path) -> None:
    unsealed = replace(layout.read_manifest(copy), files={}, manifest_sha256=None)
    values = unsealed.to_dict()
    assert "files" not in values and "manifest_sha256" not in values
    assert Manifest.from_dict(json.loads(json.dumps(values))) == unsealed


def test_a_manifest_without_dataset_reads_as_ngsim(copy: Path) -> None:
    values = json.loads(layout.manifest_path(copy).read_text())
    del values["dataset"]  # written before the key was added
    layout.write_manifest_json(copy, values)
    assert layout.read_manifest(copy).dataset == DEFAULT_DATASET == "ngsim"


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.update(scaler=[1, 2]),
        lambda m: m.update(recordings="us-101"),
        lambda m: m["counts"].pop("rows_read"),
        lambda m: m["inputs"][0].update(unknown_count=1),
    ],
    ids=["scaler", "recordings", "counts", "inputs"],
)
def test_a_sealed_manifest_of_another_form_is_one_error_line(
    copy: Path, edit: Callable[[dict], object]
) -> None:
    values = json.loads(layout.manifest_path(copy).read_text())
    edit(values)
    layout.write_manifest_json(copy, values)  # sealed: it passes the checksum
    with pytest.raises(NgsimInputError, match="unreadable build manifest") as err:
        layout.read_manifest(copy)
    assert str(err.value).startswith(f"{layout.manifest_path(copy)}: ") and "\n" not in str(
        err.value
    )


def test_json_form_is_the_form_json_gives_back() -> None:
    value = {"b": (1, SplitMode.TIME), "a": {"d": [2.5], "c": None}}
    assert json_form(value) == json.loads(json.dumps(value))
    assert list(json_form(value)) == ["a", "b"] and list(json_form(value)["a"]) == ["c", "d"]
    assert json_form(MinMaxScaler.empty().to_dict())["x_m"] == {
        "max": None,
        "min": None,
        "to": [-1.0, 1.0],
    }
