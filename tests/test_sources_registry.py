"""The registry: a new source is its folder and one line in SOURCES; locations and detection ask
every registered source. A toy format defined here, registered by monkeypatching SOURCES, is
built like NGSIM's and highD's: nothing after the seam knows it."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.sources import registry
from ngsim_graphs.sources.cleaning import (
    FILE_REASONS,
    downsample_to_grid,
    drop_duplicate_rows,
    split_at_gaps,
)
from ngsim_graphs.sources.contract import (
    FileReport,
    FileRows,
    RecordingKey,
    RecordingReport,
    Source,
    TracksPart,
    finish_tracks,
    joined_counts,
)
from ngsim_graphs.sources.registry import check_locations, choose_source

# The toy format: `<anything>.toy`, a CSV of one recording of road "toy-road" at 10 Hz, metres.
TOY_COLUMNS = {s.VEHICLE_ID: pl.Int32, s.FRAME_ID: pl.Int32, s.X_M: pl.Float64, s.Y_M: pl.Float64}
TOY_KEY: RecordingKey = ("toy-road", "morning")
FRAME_STEP_S = 0.1


def find_toy_files(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    found = [p for path in paths for p in ([path] if path.is_file() else path.rglob("*.toy"))]
    return sorted(found), []


def read_toy_file(
    path: Path, config: BuildConfig, file_index: int, strict: bool, scratch: Path | None = None
) -> FileRows:
    rows = pl.read_csv(path, schema=TOY_COLUMNS).with_row_index(s.SOURCE_LINE, offset=2)
    staged = rows.select(
        *TOY_COLUMNS,
        pl.lit(0, dtype=pl.Int32).alias(s.RECORDING_INDEX),
        pl.lit(file_index, dtype=pl.UInt16).alias(s.SOURCE_FILE),
        pl.col(s.SOURCE_LINE).cast(pl.Int64),
    )
    report = FileReport(
        path=str(path),
        raw_format="toy",
        size_bytes=path.stat().st_size,
        sha256=file_sha256(path),
        rows_read=rows.height,
        rows_other_locations=0,
        rows_missing_values=0,
        first_missing_line=None,
        rows_dropped={reason.value: 0 for reason in FILE_REASONS},
        first_dropped_line={},
        rows_checked=rows.height,
        locations_found=(TOY_KEY[0],),
        recordings=(f"{TOY_KEY[0]}/{TOY_KEY[1]}",),
    )
    return FileRows(staged.lazy(), {TOY_KEY: 0}, report)


def toy_tracks(
    raw: pl.DataFrame, key: RecordingKey, config: BuildConfig, first_track_id: int
) -> TracksPart:
    unique, exact, conflicting = drop_duplicate_rows(raw, (s.Y_M, s.X_M))
    segmented, gaps = split_at_gaps(unique)
    grid = downsample_to_grid(segmented, config.frames_per_step).with_columns(
        pl.lit(key[0]).alias(s.LOCATION),
        pl.lit(key[1]).alias(s.PERIOD),
        (pl.col(s.FRAME_ID) * FRAME_STEP_S).alias(s.TIME_S),
        (pl.col(s.FRAME_ID).cast(pl.Int64) * 100).alias(s.GLOBAL_TIME),
        pl.lit(10.0).alias(s.SPEED_MPS),
        pl.lit(0.0).alias(s.ACCEL_MPS2),
        pl.lit(1, dtype=pl.Int16).alias(s.LANE_ID),
        pl.lit(2, dtype=pl.Int8).alias(s.V_CLASS),
        pl.lit(4.5).alias(s.LENGTH_M),
        pl.lit(2.0).alias(s.WIDTH_M),
        *(pl.lit(None, dtype=pl.Int32).alias(c) for c in (s.PRECEDING, s.FOLLOWING)),
        *(pl.lit(None, dtype=pl.Float64).alias(c) for c in (s.SPACE_HEADWAY_M, s.TIME_HEADWAY_S)),
    )
    tracks = finish_tracks(grid, first_track_id, config)
    report = RecordingReport(
        location=key[0],
        period=key[1],
        rows=raw.height,
        exact_duplicates=exact,
        conflicting_duplicates=conflicting,
        position_outliers=0,
        position_jumps=0,
        gaps=gaps,
        vehicles=unique[s.VEHICLE_ID].n_unique(),
        tracks=tracks[s.TRACK_ID].n_unique(),
        grid_rows=tracks.height,
    )
    return TracksPart(tracks, report, pl.DataFrame())


def toy_report(
    parts: list[TracksPart],
    key: RecordingKey,
    config: BuildConfig,
    files: list[FileReport],
    strict: bool,
) -> RecordingReport:
    return joined_counts(parts, key)


TOY = Source(
    name="toy",
    find_files=find_toy_files,
    read_file=read_toy_file,
    vehicle_tracks=toy_tracks,
    recording_report=toy_report,
    label="Toy",
    suffixes=(".toy",),
    claims=lambda path: path.suffix == ".toy",
    is_location=lambda name: name == TOY_KEY[0],
    locations_help="toy-road",
)


def write_toy(path: Path) -> Path:
    """Three vehicles 3.5 m apart side by side at 10 m/s for 12 s (frames 0..119), and one row of
    vehicle 1 twice (an exact duplicate)."""
    lines = ["vehicle_id,frame_id,x_m,y_m"]
    for vehicle in (1, 2, 3):
        for frame in range(120):
            lines.append(f"{vehicle},{frame},{3.5 * vehicle},{frame * 1.0}")
    lines.append("1,7,3.5,7.0")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def toy_registered(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.SOURCES, TOY.name, TOY)


def test_a_toy_source_registered_in_one_line_is_built(toy_registered: None, tmp_path: Path) -> None:
    raw = write_toy(tmp_path / "raw" / "road.toy")
    config = BuildConfig(locations=("toy-road",))
    assert choose_source([raw.parent])[0] is TOY  # told from the content, before NGSIM
    result = run_build([raw.parent], tmp_path / "build", config)
    manifest = result.manifest
    assert manifest.dataset == "toy"
    assert [f.raw_format for f in manifest.inputs] == ["toy"]
    counts = manifest.counts
    # 361 rows, one exact duplicate; 60 grid steps (even frames 0..118) of each of 3 tracks
    assert (counts.rows_read, counts.rows, counts.exact_duplicates) == (361, 361, 1)
    assert (counts.tracks, counts.grid_rows) == (3, 180)
    # One window a track: (60 - 41) // 40 + 1; the vehicle split: ids <= round(0.7 * 3) train,
    # <= round(0.8 * 3) validation (none), the rest test.
    assert manifest.splits == {"train": 2, "val": 0, "test": 1}
    build = open_build(tmp_path / "build")
    tracks = build.tracks().collect().sort(s.TRACK_ID, s.TIME_S)
    first = tracks.filter(pl.col(s.VEHICLE_ID) == 2).head(2)
    assert first.select(s.TIME_S, s.X_M, s.Y_M).rows() == [(0.0, 7.0, 0.0), (0.2, 7.0, 2.0)]
    train = build.samples("train")
    assert train[s.EGO_VEHICLE_ID].to_list() == [1, 2]
    assert train[s.ORIGIN_Y_M].to_list() == [30.0, 30.0]  # present step 15: frame 30
    forced = run_build([raw], tmp_path / "forced", config, dataset="toy")
    assert forced.manifest.splits == manifest.splits


def test_locations_are_those_of_the_registered_sources(toy_registered: None) -> None:
    check_locations(("toy-road", "us-101", "highd-2"))
    with pytest.raises(ValueError, match=r"unknown location\(s\) \['nowhere'\]; .* or toy-road$"):
        check_locations(("toy-road", "nowhere"))


def test_without_the_toy_its_location_is_unknown(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown location\(s\) \['toy-road'\]"):
        run_build(
            [write_toy(tmp_path / "road.toy")], tmp_path / "build", BuildConfig(("toy-road",))
        )
