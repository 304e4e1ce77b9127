"""The registry: a new source is its folder and one line in SOURCE_MODULES; locations and
detection ask every registered source. The toy source (tests/toy_source/: 25 Hz, its own
columns, a drop reason of its own) is registered here by that one line and built like NGSIM's and
highD's: nothing after the seam knows it."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest

from ngsim_cli.build_view import _dropped_lines
from ngsim_graphs import schema as s
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.sources import registry
from ngsim_graphs.sources.registry import check_locations, choose_source, load_source

TOY_MODULE = "toy_source.tracks"  # tests/ is on the path; a real source's: ngsim_graphs.sources.<name>.tracks
TOY = load_source(TOY_MODULE)


def write_toy(path: Path) -> Path:
    """Three vehicles 3.5 m apart side by side at 10 m/s (36 km/h) for 12 s (frames 0..299 at
    25 Hz: 0.4 m a frame), one row of vehicle 1 twice (an exact duplicate), and one row of car 0
    (dropped: the toy's own reason)."""
    lines = ["frame;car;s_m;d_m;speed_kmh"]
    for vehicle in (1, 2, 3):
        for frame in range(300):
            lines.append(f"{frame};{vehicle};{frame * 0.4:.1f};{3.5 * vehicle};36.0")
    lines.append("7;1;2.8;3.5;36.0")
    lines.append("8;0;0.0;0.0;0.0")  # a placeholder row: the toy's own drop reason
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def toy_registered(monkeypatch: pytest.MonkeyPatch) -> None:
    """The one line a new source adds to SOURCE_MODULES, as the registry loads it."""
    monkeypatch.setitem(registry.SOURCES, "toy", load_source(TOY_MODULE))


def test_a_toy_source_registered_in_one_line_is_built(toy_registered: None, tmp_path: Path) -> None:
    raw = write_toy(tmp_path / "raw" / "road.toy")
    config = BuildConfig(locations=("toy-road",))
    assert choose_source([raw.parent])[0] is registry.SOURCES["toy"]  # by content, before NGSIM
    result = run_build([raw.parent], tmp_path / "build", config)
    manifest = result.manifest
    assert manifest.dataset == "toy"
    # its own limits (90,000 of its 25 Hz frames), recorded beside the config that holds none
    assert manifest.limits == TOY.limits and manifest.limits.max_frame_id == 90_000
    assert manifest.to_dict()["limits"]["max_frame_id"] == 90_000
    # what the CLI's help lists of the datasets and their locations, from the registry
    assert registry.labels_in_words() == "NGSIM, highD or Toy"
    assert registry.locations_in_words().endswith("; Toy: toy-road")
    assert [f.raw_format for f in manifest.inputs] == ["toy"]
    counts = manifest.counts
    # 902 rows, the car-0 row dropped, one exact duplicate; 60 grid steps (frames 0, 5, ...,
    # 295: 0.2 s at 25 Hz) of each of 3 tracks
    assert (counts.rows_read, counts.rows, counts.exact_duplicates) == (902, 901, 1)
    # the toy's own reason beside the shared ones, by its name, and in the build's report
    assert counts.rows_dropped["toy_no_car"] == 1
    assert set(counts.rows_dropped) == {*(r.value for r in s.DropReason), "toy_no_car"}
    assert _dropped_lines(result) == [
        f"dropped 1 row: a placeholder row of no car (car 0) (first: {raw}, line 903)."
    ]
    assert (counts.tracks, counts.grid_rows) == (3, 180)
    # One window a track: (60 - 41) // 40 + 1; the vehicle split: ids <= round(0.7 * 3) train,
    # <= round(0.8 * 3) validation (none), the rest test.
    assert manifest.splits == {"train": 2, "val": 0, "test": 1}
    build = open_build(tmp_path / "build")
    tracks = build.tracks().collect().sort(s.TRACK_ID, s.TIME_S)
    first = tracks.filter(pl.col(s.VEHICLE_ID) == 2).head(2)
    # the lateral d_m is x, the longitudinal s_m is y; the second grid row is frame 5
    assert first.select(s.FRAME_ID, s.TIME_S, s.X_M, s.Y_M, s.SPEED_MPS).rows() == [
        (0, 0.0, 7.0, 0.0, 10.0),
        (5, 0.2, 7.0, 2.0, 10.0),
    ]
    train = build.samples("train")
    assert train[s.EGO_VEHICLE_ID].to_list() == [1, 2]
    assert train[s.ORIGIN_Y_M].to_list() == [30.0, 30.0]  # present step 15: 3 s, frame 75
    forced = run_build([raw], tmp_path / "forced", config, dataset="toy")
    assert forced.manifest.splits == manifest.splits


def test_a_grid_of_no_whole_number_of_the_sources_frames_is_refused(
    toy_registered: None, tmp_path: Path
) -> None:
    """0.1 s is a whole number of NGSIM's frames but not of the toy's 0.04 s ones."""
    raw = write_toy(tmp_path / "raw" / "road.toy")
    config = BuildConfig(locations=("toy-road",), time_step_s=0.1, stride_s=8.0)
    with pytest.raises(
        NgsimInputError,
        match=r"road\.toy: the grid step of 0\.1 s is not a whole "
        r"number of frames of 0\.04 s \(25 Hz\), Toy's frame period",
    ):
        run_build([raw], tmp_path / "build", config)
    assert not (tmp_path / "build").exists()


def test_locations_are_those_of_the_registered_sources(toy_registered: None) -> None:
    check_locations(("toy-road", "us-101", "highd-2"))
    with pytest.raises(ValueError, match=r"unknown location\(s\) \['nowhere'\]; .* or toy-road$"):
        check_locations(("toy-road", "nowhere"))


def test_without_the_toy_its_location_is_unknown(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown location\(s\) \['toy-road'\]"):
        run_build(
            [write_toy(tmp_path / "road.toy")], tmp_path / "build", BuildConfig(("toy-road",))
        )


def test_the_help_texts_list_the_registered_datasets() -> None:
    assert registry.labels_in_words() == "NGSIM or highD"
    assert registry.locations_in_words() == (
        "NGSIM: us-101, i-80, lankershim, peachtree; highD: highd-N (a highD locationId; none "
        "named: every one)"
    )
    assert [registry.in_words(n) for n in (["a"], ["a", "b"], ["a", "b", "c"])] == [
        "a",
        "a or b",
        "a, b or c",
    ]
