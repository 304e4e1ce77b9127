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
from ngsim_graphs.cleaning import drop_duplicate_rows, drop_incomplete_rows, split_at_gaps, to_si_units
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.kinematics import add_heading
from ngsim_graphs.reading import ROW, file_sha256, read_raw_file
from ngsim_graphs.recordings import label_recordings
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
    recordings: tuple[str, ...]  # "location/period" of each recording the file holds


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
) -> tuple[dict[RecordingKey, pl.DataFrame], FileReport]:
    """Parse one file and split its usable rows by recording (NGSIM units, + location, period)."""
    raw = read_raw_file(path, config.locations)
    complete, missing = drop_incomplete_rows(raw.frame.drop(ROW))
    labelled = label_recordings(complete, path)
    kept = labelled.filter(pl.col(s.LOCATION).is_in(config.locations))
    parts = kept.partition_by(s.LOCATION, s.PERIOD, as_dict=True, maintain_order=True)
    by_key = {(str(k[0]), str(k[1])): frame for k, frame in sorted(parts.items())}
    report = FileReport(
        path=str(path),
        raw_format=raw.raw_format.value,
        size_bytes=raw.size_bytes,
        sha256=file_sha256(path),
        rows_read=raw.rows_read,
        rows_other_locations=raw.rows_other_locations + labelled.height - kept.height,
        rows_missing_values=missing,
        recordings=tuple(f"{loc}/{period}" for loc, period in by_key),
    )
    return by_key, report


def build_tracks(
    raw: pl.DataFrame, config: BuildConfig, first_track_id: int
) -> tuple[pl.DataFrame, RecordingReport]:
    """The tracks table of one recording from its raw rows (any order, duplicates allowed).

    Tracks are numbered from `first_track_id` in (vehicle, segment) order; rows come out sorted
    by track and frame, columns as TRACKS_SCHEMA.
    """
    unique, exact, conflicting = drop_duplicate_rows(raw)
    segmented, gaps = split_at_gaps(unique)
    grid = to_si_units(downsample_to_grid(segmented, config.frames_per_step))
    track_index = pl.struct(s.VEHICLE_ID, s.SEGMENT).rle_id().cast(pl.Int32)
    numbered = grid.with_columns((track_index + first_track_id).alias(s.TRACK_ID))
    tracks = add_heading(numbered, config.smoothing_window_steps, config.min_heading_speed_mps)
    tracks = tracks.select(s.TRACKS_SCHEMA.names()).cast(dict(s.TRACKS_SCHEMA))
    location, period = raw.select(s.LOCATION, s.PERIOD).row(0)
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
