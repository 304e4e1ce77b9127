"""Raw files to the tracks table: one recording at a time, each stage a pure function.

Per input file: parse, drop incomplete and implausible rows, label recordings (dropping stray
rows whose Global_Time disagrees with their recording), and stage each recording's rows (a
recording may come from several files). Per recording: drop duplicates and position outliers,
split at frame gaps and position jumps, downsample to the grid, convert to SI, number the tracks
and derive the heading. Every dropped row is counted per reason, with the first line it was on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.cleaning import drop_duplicate_rows, is_complete, split_at_gaps, to_si_units
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.kinematics import add_heading
from ngsim_graphs.plausibility import jump_rows, outlier_rows, row_drop_reason, speed_mismatch_mps
from ngsim_graphs.reading import ROW, read_raw_file
from ngsim_graphs.recordings import RECORDING_INDEX, identify_recordings
from ngsim_graphs.resampling import downsample_to_grid
from ngsim_graphs.schema import DropReason

RecordingKey = tuple[str, str]  # (location, period)


@dataclass(frozen=True)
class FileReport:
    """What reading one input file found, and which of its rows were dropped before cleaning.

    rows_read = rows_other_locations + rows_missing_values + sum(rows_dropped) + the rows it
    gave its chosen recordings (RecordingReport.rows).
    """

    path: str
    raw_format: str
    size_bytes: int
    sha256: str
    rows_read: int
    rows_other_locations: int  # of locations (or recordings) the build did not choose
    rows_missing_values: int  # an empty required field
    first_missing_line: int | None  # the first line with an empty required field
    rows_dropped: dict[str, int]  # per DropReason of the row checks and Global_Time: every reason
    first_dropped_line: dict[str, int]  # per reason with dropped rows: the first line
    rows_checked: int  # rows of the chosen recordings with every required field, kept or dropped
    locations_found: tuple[str, ...]  # every location the file holds, chosen or not
    recordings: tuple[str, ...]  # "location/period" of each chosen recording the file holds


@dataclass(frozen=True)
class RecordingReport:
    """What cleaning one recording counted, and the size of its tracks table."""

    location: str
    period: str
    rows: int  # 10 Hz rows of the recording that passed the row checks (duplicates included)
    exact_duplicates: int
    conflicting_duplicates: int
    position_outliers: int  # rows dropped: displaced from the neighbouring frames (outlier_rows)
    position_jumps: int  # other moves beyond the jump limit, each of which split a track
    gaps: int  # frame gaps, each of which split a vehicle's record into two tracks
    vehicles: int
    tracks: int
    grid_rows: int  # rows of the tracks table (0.2 s grid)
    # v_Vel against the motion the positions show (plausibility.speed_mismatch_mps)
    speed_mismatch_mps: float = math.nan  # median |v_Vel - shown speed|
    shown_speed_mps: float = math.nan  # median shown speed
    speed_rows_compared: int = 0
    first_outlier: tuple[int, int] | None = None  # (input file index, line) of the first outlier


# The required columns as NGSIM's header spells them, for messages.
REQUIRED_NAMES = tuple(
    next(h for h in s.PORTAL_HEADER if h.lower() == column) for column in s.REQUIRED_VALUE_COLUMNS
)
FILE_REASONS: tuple[DropReason, ...] = tuple(r for r in DropReason if r is not DropReason.POSITION_OUTLIER)


def read_file_recordings(
    path: Path, config: BuildConfig, file_index: int = 0
) -> tuple[pl.DataFrame, dict[RecordingKey, int], FileReport]:
    """Parse one file, drop what no recording can use, and tell its chosen recordings apart.

    Returns (every parsed row in NGSIM units with a RECORDING_INDEX column and the provenance
    columns SOURCE_FILE = `file_index` and SOURCE_LINE, the index of each chosen recording, the
    file's report). The index is null for incomplete, implausible and stray rows, which are
    dropped. No copy of the rows is made here: the caller takes one recording at a time.
    """
    raw = read_raw_file(path, config.locations)
    complete = raw.frame.select(is_complete()).to_series()
    reason = raw.frame.select(pl.when(complete).then(row_drop_reason(config.limits))).to_series()
    usable = complete & reason.is_null()
    timed = raw.frame.select(s.LOCATION, s.FRAME_ID, s.GLOBAL_TIME)
    index, names = identify_recordings(timed, path, usable)
    chosen = {key: i for i, key in enumerate(names) if key[0] in config.locations}
    in_chosen = index.is_in(list(chosen.values())).fill_null(False)
    # Rows of recordings the build did not choose are other locations' rows, whatever they
    # hold: nothing of them is checked. Strays belong to no recording: to none chosen when the
    # file holds none (a per-period file of another location).
    other = (index.is_not_null() & ~in_chosen) | (pl.lit(not chosen) & index.is_null())
    stray = usable & index.is_null()
    reason = pl.select(
        pl.when(~complete | other).then(None)
        .when(stray).then(pl.lit(DropReason.GLOBAL_TIME.value))
        .otherwise(reason)
    ).to_series()  # fmt: skip
    line = (pl.col(ROW) + raw.first_line).alias(s.SOURCE_LINE)
    rows = raw.frame.select(
        *s.RAW_SCHEMA.names(),
        pl.when(usable & in_chosen).then(index).alias(RECORDING_INDEX),
        pl.lit(file_index, dtype=pl.UInt16).alias(s.SOURCE_FILE),
        line,
    )
    dropped = (
        pl.DataFrame({"reason": reason, s.SOURCE_LINE: rows[s.SOURCE_LINE]})
        .drop_nulls("reason")
        .group_by("reason")
        .agg(pl.len(), pl.col(s.SOURCE_LINE).min())
    )
    counts = {r: n for r, n, _ in dropped.iter_rows()}
    kept = int(rows[RECORDING_INDEX].is_not_null().sum())
    missing = int((~complete).sum())
    if missing == raw.frame.height:  # nothing to place in a recording: say why, naming the file
        raise NgsimInputError(
            path,
            f"every one of its {missing:,} rows has an empty required field "
            f"({', '.join(REQUIRED_NAMES)}); the first at line {raw.first_line + int(raw.frame[ROW][0])}",
        )
    report = FileReport(
        path=str(path),
        raw_format=raw.raw_format.value,
        size_bytes=raw.size_bytes,
        sha256=file_sha256(path),
        rows_read=raw.rows_read,
        rows_other_locations=raw.rows_read - kept - missing - sum(counts.values()),
        rows_missing_values=missing,
        first_missing_line=None if missing == 0 else int(rows.filter(~complete)[s.SOURCE_LINE].min()),
        rows_dropped={r.value: counts.get(r.value, 0) for r in FILE_REASONS},
        first_dropped_line={r: first for r, _, first in sorted(dropped.iter_rows())},
        rows_checked=kept + sum(counts.values()),
        locations_found=tuple(sorted(set(raw.locations_found) | {loc for loc, _ in names})),
        recordings=tuple(f"{loc}/{period}" for loc, period in sorted(chosen)),
    )
    return rows, chosen, report


def recording_rows(rows: pl.DataFrame, index: int) -> pl.DataFrame:
    """The rows of one recording out of a file's rows (see read_file_recordings)."""
    return rows.filter(pl.col(RECORDING_INDEX) == index).drop(RECORDING_INDEX)


def _first_source(rows: pl.DataFrame) -> tuple[int, int] | None:
    """(file index, line) of the first of `rows`, if they carry their provenance."""
    if rows.height == 0 or s.SOURCE_FILE not in rows.columns:
        return None
    first = rows.select(s.SOURCE_FILE, s.SOURCE_LINE).sort(s.SOURCE_FILE, s.SOURCE_LINE).row(0)
    return int(first[0]), int(first[1])


def build_tracks(
    raw: pl.DataFrame, key: RecordingKey, config: BuildConfig, first_track_id: int
) -> tuple[pl.DataFrame, RecordingReport]:
    """The tracks table of recording `key` from its raw rows (any order, duplicates allowed).

    Tracks are numbered from `first_track_id` in (vehicle, segment) order; rows come out sorted
    by track and frame, columns as TRACKS_SCHEMA.
    """
    unique, exact, conflicting = drop_duplicate_rows(raw)
    outlier = outlier_rows(unique, config.limits)
    cleaned = unique.filter(~outlier)
    jumps = jump_rows(cleaned, config.limits)
    mismatch, shown, compared = speed_mismatch_mps(cleaned)
    segmented, gaps = split_at_gaps(cleaned, jumps)
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
        position_outliers=int(outlier.sum()),
        position_jumps=int(jumps.sum()),
        gaps=gaps,
        vehicles=unique[s.VEHICLE_ID].n_unique(),
        tracks=tracks[s.TRACK_ID].n_unique(),
        grid_rows=tracks.height,
        speed_mismatch_mps=mismatch,
        shown_speed_mps=shown,
        speed_rows_compared=compared,
        first_outlier=_first_source(unique.filter(outlier)),
    )
    return tracks, report
