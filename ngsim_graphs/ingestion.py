"""Raw files to the tracks table: one recording at a time, each stage a pure function.

Per input file: parse, drop incomplete rows, label recordings, and stage each recording's rows
(a recording may come from several files). Per recording: drop duplicates, split at frame gaps,
downsample to the grid, convert to SI, number the tracks and derive the heading.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.cleaning import drop_duplicate_rows, is_complete, split_at_gaps, to_si_units
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.kinematics import add_heading
from ngsim_graphs.reading import ROW, file_sha256, read_raw_file
from ngsim_graphs.recordings import RECORDING_INDEX, identify_recordings
from ngsim_graphs.resampling import downsample_to_grid

RecordingKey = tuple[str, str]  # (location, period)


@dataclass(frozen=True)
class FileReport:
    """What reading one input file found."""

    path: str
    raw_format: str
    size_bytes: int
    sha256: str
    rows_read: int
    rows_other_locations: int
    rows_missing_values: int
    locations_found: tuple[str, ...]  # every location the file holds, chosen or not
    recordings: tuple[str, ...]  # "location/period" of each chosen recording the file holds


@dataclass(frozen=True)
class RecordingReport:
    """What cleaning one recording counted, and the size of its tracks table."""

    location: str
    period: str
    rows: int  # 10 Hz rows of the recording after the location filter and incomplete rows
    exact_duplicates: int
    conflicting_duplicates: int
    gaps: int  # frame gaps, each of which split a vehicle's record into two tracks
    vehicles: int
    tracks: int
    grid_rows: int  # rows of the tracks table (0.2 s grid)


def read_file_recordings(
    path: Path, config: BuildConfig
) -> tuple[pl.DataFrame, dict[RecordingKey, int], FileReport]:
    """Parse one file and tell its chosen recordings apart.

    Returns (every parsed row in NGSIM units with a RECORDING_INDEX column, the index of each
    chosen recording, the file's report). The index is null for incomplete rows, which are
    dropped. No copy of the rows is made here: the caller takes one recording at a time.
    """
    raw = read_raw_file(path, config.locations)
    complete = raw.frame.select(is_complete()).to_series()
    index, names = identify_recordings(raw.frame, path)
    rows = raw.frame.drop(ROW, s.LOCATION).with_columns(
        pl.when(complete).then(index).alias(RECORDING_INDEX)
    )
    chosen = {key: i for i, key in enumerate(names) if key[0] in config.locations}
    counts = rows.group_by(RECORDING_INDEX).len()
    kept = int(counts.filter(pl.col(RECORDING_INDEX).is_in(list(chosen.values())))["len"].sum())
    missing = int(counts.filter(pl.col(RECORDING_INDEX).is_null())["len"].sum())
    report = FileReport(
        path=str(path),
        raw_format=raw.raw_format.value,
        size_bytes=raw.size_bytes,
        sha256=file_sha256(path),
        rows_read=raw.rows_read,
        rows_other_locations=raw.rows_read - kept - missing,
        rows_missing_values=missing,
        locations_found=tuple(sorted(set(raw.locations_found) | {loc for loc, _ in names})),
        recordings=tuple(f"{loc}/{period}" for loc, period in sorted(chosen)),
    )
    return rows, chosen, report


def recording_rows(rows: pl.DataFrame, index: int) -> pl.DataFrame:
    """The rows of one recording out of a file's rows (see read_file_recordings)."""
    return rows.filter(pl.col(RECORDING_INDEX) == index).drop(RECORDING_INDEX)


def build_tracks(
    raw: pl.DataFrame, key: RecordingKey, config: BuildConfig, first_track_id: int
) -> tuple[pl.DataFrame, RecordingReport]:
    """The tracks table of recording `key` from its raw rows (any order, duplicates allowed).

    Tracks are numbered from `first_track_id` in (vehicle, segment) order; rows come out sorted
    by track and frame, columns as TRACKS_SCHEMA.
    """
    unique, exact, conflicting = drop_duplicate_rows(raw)
    segmented, gaps = split_at_gaps(unique)
    location, period = key
    on_grid = downsample_to_grid(segmented, config.frames_per_step).with_columns(
        pl.lit(location).alias(s.LOCATION), pl.lit(period).alias(s.PERIOD)
    )
    grid = to_si_units(on_grid)
    track_index = pl.struct(s.VEHICLE_ID, s.SEGMENT).rle_id().cast(pl.Int32)
    numbered = grid.with_columns((track_index + first_track_id).alias(s.TRACK_ID))
    tracks = add_heading(numbered, config.smoothing_window_steps, config.min_heading_speed_mps)
    tracks = tracks.select(s.TRACKS_SCHEMA.names()).cast(dict(s.TRACKS_SCHEMA))
    report = RecordingReport(
        location=location,
        period=period,
        rows=raw.height,
        exact_duplicates=exact,
        conflicting_duplicates=conflicting,
        gaps=gaps,
        vehicles=unique[s.VEHICLE_ID].n_unique(),
        tracks=tracks[s.TRACK_ID].n_unique(),
        grid_rows=tracks.height,
    )
    return tracks, report
