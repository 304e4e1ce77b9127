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
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.registry import SOURCES


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


# The manifests of two tiny synthetic builds (NGSIM and highD, BuildConfig(d_sense_m=12.0,
# d_min_m=6.0)) that the ngsim-graphs before the limits were the source's wrote: their configs
# hold the limits, which were NGSIM's for both (max_frame_id 72,000 of NGSIM's 10 Hz frames).
OLDER = Path(__file__).parent / "fixtures" / "build-0.1.0"
OLDER_CONFIG = BuildConfig(d_sense_m=12.0, d_min_m=6.0)
OLDER_HASH = "dcfa1c68089b0a7558f9c2efe0c24a02f1890ee92ee3e03671fcbae840acb0d2"


@pytest.mark.parametrize("dataset", ["ngsim", "highd"])
def test_an_older_manifest_with_the_limits_in_its_config_loads(
    dataset: str, tmp_path: Path
) -> None:
    values = json.loads(layout.manifest_path(OLDER / dataset).read_text())
    assert "limits" not in values and values["config"]["limits"]["max_frame_id"] == 72_000
    read = layout.read_manifest(OLDER / dataset)  # its checksum and config hash checked
    assert (read.dataset, read.config, read.config_hash) == (dataset, OLDER_CONFIG, OLDER_HASH)
    assert read.limits == PhysicalLimits(max_frame_id=72_000)  # as recorded
    assert read.settings() == values["config"]  # what its hash covers: its config, as written
    # Written again, in today's form (the limits beside the config), its config hash holds.
    layout.write_manifest_json(tmp_path, {**read.to_dict(), "files": {}})
    again = json.loads(layout.manifest_path(tmp_path).read_text())
    assert "limits" not in again["config"] and again["limits"] == values["config"]["limits"]
    assert layout.read_manifest(tmp_path).config_hash == OLDER_HASH


def test_an_ngsim_build_of_today_hashes_as_before_and_a_highd_build_does_not() -> None:
    """NGSIM's limits are those the config held; highD's frame limit is its own 25 Hz frames'
    now (180,000 for the same two hours): its builds' config hash is another."""
    for config, before in (
        (OLDER_CONFIG, OLDER_HASH),
        # the default build's (the paper's, at d_min 25 m), as the code before wrote it
        (BuildConfig(), "06b53f81ae77166ac5ef0715ffeb37e084c80e2a5ba6d98d1c670e98ea287b15"),
    ):
        assert layout.config_hash(config.to_dict(), SOURCES["ngsim"].limits.to_dict()) == before
        assert layout.config_hash(config.to_dict(), SOURCES["highd"].limits.to_dict()) != before
    assert SOURCES["highd"].limits == replace(SOURCES["ngsim"].limits, max_frame_id=180_000)


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.update(scaler=[1, 2]),
        lambda m: m.update(recordings="us-101"),
        lambda m: m["counts"].pop("rows_read"),
        lambda m: m["inputs"][0].update(unknown_count=1),
        lambda m: m.update(  # a limit of a newer ngsim-graphs, in a manifest it sealed
            limits=(newer := {**m["limits"], "max_warp_m": 1.0}),
            config_hash=layout.config_hash(m["config"], newer),
        ),
    ],
    ids=["scaler", "recordings", "counts", "inputs", "limits"],
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
