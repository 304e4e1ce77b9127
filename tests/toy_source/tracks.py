"""The toy files to the tracks table: the toy `Source`, built like NGSIM's and highD's from the
shared cleaning of `sources/`; nothing after the seam knows it."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.sources.cleaning import (
    FILE_REASONS,
    check_file_drops,
    cleaned_report,
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
    frames_per_step,
    joined_counts,
)
from ngsim_graphs.sources.limits import PhysicalLimits

from . import schema as ts

FRAME_PERIOD_S = 0.04  # 25 Hz
LIMITS = PhysicalLimits(max_frame_id=90_000)  # what its rows may hold: an hour of its frames
KEY: RecordingKey = ("toy-road", "morning")
NO_CAR = "toy_no_car"  # its own drop reason: a placeholder row of car 0
DROP_REASONS = {NO_CAR: "a placeholder row of no car (car 0)"}


def find_files(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    found = [p for path in paths for p in ([path] if path.is_file() else path.rglob("*.toy"))]
    return sorted(found), []


def read_file(
    path: Path,
    config: BuildConfig,
    limits: PhysicalLimits,
    file_index: int,
    strict: bool,
    scratch: Path | None = None,
) -> FileRows:
    """The file's rows, renamed to the shared key columns, labelled as the one recording."""
    raw = pl.read_csv(path, schema=ts.RAW_SCHEMA, separator=ts.SEPARATOR)
    rows = raw.with_row_index(s.SOURCE_LINE, offset=2).select(
        pl.col(ts.CAR).alias(s.VEHICLE_ID),
        pl.col(ts.FRAME).alias(s.FRAME_ID),
        pl.col(ts.D_M).alias(s.X_M),
        pl.col(ts.S_M).alias(s.Y_M),
        (pl.col(ts.SPEED_KMH) / 3.6).alias(s.SPEED_MPS),
        pl.when(pl.col(ts.CAR) != 0).then(pl.lit(0, dtype=pl.Int32)).alias(s.RECORDING_INDEX),
        pl.lit(file_index, dtype=pl.UInt16).alias(s.SOURCE_FILE),
        pl.col(s.SOURCE_LINE).cast(pl.Int64),
    )
    no_car = rows.filter(pl.col(s.VEHICLE_ID) == 0)[s.SOURCE_LINE]
    report = FileReport(
        path=str(path),
        raw_format="toy",
        size_bytes=path.stat().st_size,
        sha256=file_sha256(path),
        rows_read=rows.height,
        rows_other_locations=0,
        rows_missing_values=0,
        first_missing_line=None,
        rows_dropped={**{reason.value: 0 for reason in FILE_REASONS}, NO_CAR: no_car.len()},
        first_dropped_line={NO_CAR: int(no_car.min())} if no_car.len() else {},
        rows_checked=rows.height,
        locations_found=(KEY[0],),
        recordings=(f"{KEY[0]}/{KEY[1]}",),
    )
    check_file_drops(report, limits, strict, DROP_REASONS)
    return FileRows(rows.lazy(), {KEY: 0}, report)


def vehicle_tracks(
    raw: pl.DataFrame,
    key: RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    first_track_id: int,
) -> TracksPart:
    unique, exact, conflicting = drop_duplicate_rows(raw, (s.Y_M, s.X_M))
    segmented, gaps = split_at_gaps(unique)
    on_grid = downsample_to_grid(segmented, frames_per_step(config.time_step_s, FRAME_PERIOD_S))
    grid = on_grid.with_columns(
        pl.lit(key[0]).alias(s.LOCATION),
        pl.lit(key[1]).alias(s.PERIOD),
        (pl.col(s.FRAME_ID) * FRAME_PERIOD_S).alias(s.TIME_S),
        (pl.col(s.FRAME_ID).cast(pl.Int64) * 40).alias(s.GLOBAL_TIME),
        pl.lit(0.0).alias(s.ACCEL_MPS2),
        pl.lit(1, dtype=pl.Int16).alias(s.LANE_ID),
        pl.lit(2, dtype=pl.Int8).alias(s.V_CLASS),
        pl.lit(4.5).alias(s.LENGTH_M),
        pl.lit(2.0).alias(s.WIDTH_M),
        *(pl.lit(None, dtype=pl.Int32).alias(c) for c in (s.PRECEDING, s.FOLLOWING)),
        *(pl.lit(None, dtype=pl.Float64).alias(c) for c in (s.SPACE_HEADWAY_M, s.TIME_HEADWAY_S)),
    )
    tracks = finish_tracks(grid, first_track_id, config)
    report = cleaned_report(key, raw.height, unique, tracks, (exact, conflicting), gaps)
    return TracksPart(tracks, report, pl.DataFrame())


def recording_report(
    parts: list[TracksPart],
    key: RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    files: list[FileReport],
    strict: bool,
) -> RecordingReport:
    return joined_counts(parts, key)


SOURCE = Source(
    name="toy",
    find_files=find_files,
    read_file=read_file,
    vehicle_tracks=vehicle_tracks,
    recording_report=recording_report,
    frame_period_s=FRAME_PERIOD_S,
    limits=LIMITS,
    label="Toy",
    suffixes=(".toy",),
    claims=lambda path: path.suffix == ".toy",
    is_location=lambda name: name == KEY[0],
    locations_help="toy-road",
    drop_reasons=DROP_REASONS,
)
