"""Raw files to the tracks table, each stage a pure function.

Per input file: parse, drop incomplete and implausible rows, label recordings (dropping stray rows
whose Global_Time disagrees with their recording), say whether the file looks cut at a line end
(`truncation`), and stage each recording's rows (a recording may come from several files). Per part
of a recording's vehicles: drop duplicates and position outliers, split at frame gaps and position
jumps, downsample to the grid, convert to SI, number the tracks and derive the heading; per
recording, join the parts' reports and check the speed column. Every dropped row is counted per
reason, with the first line it was on.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.cleaning import (
    check_dropped,
    check_file_drops,
    cleaned_report,
    describe,
    downsample_to_grid,
    drop_duplicate_rows,
    empty_column_checks,
    empty_column_lines,
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
)
from ngsim_graphs.sources.lanes import (
    FREEWAY_LANES,
    FREEWAY_LOCATIONS,
    LATERAL_M,
    check_lanes,
    check_one_lane,
    lane_medians,
)
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import (
    CONFLICT_ORDER,
    FEET_TO_M,
    is_complete,
    to_si_units,
)
from ngsim_graphs.sources.ngsim.files import read_raw_file
from ngsim_graphs.sources.ngsim.formats import CANDIDATE_SUFFIXES, find_raw_files, is_ngsim_file
from ngsim_graphs.sources.ngsim.neighbours import check_neighbours
from ngsim_graphs.sources.ngsim.plausibility import (
    DROP_REASONS,
    FILE_REASONS,
    LIMITS,
    NgsimDrop,
    jump_rows,
    outlier_rows,
    passes_row_checks,
    row_drop_reason,
)
from ngsim_graphs.sources.ngsim.recordings import (
    FRAME_PERIOD_S,
    KNOWN_LOCATION_NAMES,
    is_ngsim_location,
    recording_index,
)
from ngsim_graphs.sources.ngsim.truncation import cut_record_note, vehicle_records
from ngsim_graphs.sources.speeds import check_speed_column, joined_report, speed_comparison
from ngsim_graphs.sources.text import ROW

# The columns as NGSIM's header spells them, for messages: the required ones, the others.
SPELLED = {
    column: next(h for h in ns.PORTAL_HEADER if h.lower() == column) for column in ns.TXT_COLUMNS
}
REQUIRED_NAMES = tuple(SPELLED[column] for column in ns.REQUIRED_VALUE_COLUMNS)
OPTIONAL_NAMES = {c: name for c, name in SPELLED.items() if c not in ns.REQUIRED_VALUE_COLUMNS}


def read_file_recordings(
    path: Path,
    config: BuildConfig,
    file_index: int = 0,
    scratch: Path | None = None,
    limits: PhysicalLimits = LIMITS,
) -> FileRows:
    """Parse one file, drop what no recording can use (beyond `limits`, NGSIM's by default), and
    tell its chosen recordings apart.

    Returns every parsed row in NGSIM units with a RECORDING_INDEX column and the provenance
    columns SOURCE_FILE = `file_index` and SOURCE_LINE, the index of each chosen recording, and the
    file's report (its notes: recordings told apart by their own clock, optional columns empty in
    every row, the file looking cut at a line end). The index is null for incomplete, implausible
    and stray rows, which are dropped. The rows are lazy, and each count a streaming pass over
    them: with `scratch` (`read_raw_file`), no more than a part of them is ever in memory.
    """
    raw = read_raw_file(path, config.locations, scratch)
    complete = is_complete()
    reason = pl.when(complete).then(row_drop_reason(limits))
    usable = complete & passes_row_checks(limits)
    index, names, notes = recording_index(raw.frame, path, usable)
    chosen = {key: i for i, key in enumerate(names) if key[0] in config.locations}
    in_chosen = index.is_in(list(chosen.values())).fill_null(False)
    # Rows of recordings the build did not choose are other locations' rows, whatever they
    # hold: nothing of them is checked. Strays belong to no recording: to none chosen when the
    # file holds none (a per-period file of another location). A file that yields no recording
    # at all has no location to leave out: every row of it is counted under its reason.
    strays_elsewhere = bool(names) and not chosen
    other = (index.is_not_null() & ~in_chosen) | (pl.lit(strays_elsewhere) & index.is_null())
    stray = usable & index.is_null()
    reason = (
        pl.when(~complete | other)
        .then(None)
        .when(stray)
        .then(pl.lit(NgsimDrop.GLOBAL_TIME.value))
        .otherwise(reason)
    )
    line = pl.col(ROW) + raw.first_line
    rows = raw.frame.select(
        *ns.RAW_SCHEMA.names(),
        pl.when(usable & in_chosen).then(index).alias(s.RECORDING_INDEX),
        pl.lit(file_index, dtype=pl.UInt16).alias(s.SOURCE_FILE),
        line.alias(s.SOURCE_LINE),
    )
    dropped = (
        raw.frame.select(reason.alias("reason"), line.alias(s.SOURCE_LINE))
        .drop_nulls("reason")
        .group_by("reason")
        .agg(pl.len(), pl.col(s.SOURCE_LINE).min())
        .collect(engine="streaming")
    )
    counts = {r: n for r, n, _ in dropped.iter_rows()}
    summary = raw.frame.select(
        (usable & in_chosen).sum().alias("kept"),
        (~complete).sum().alias("missing"),
        line.filter(~complete).min().alias("first_missing"),
        pl.len().alias("rows"),
        line.min().alias("first_line"),
        *empty_column_checks(OPTIONAL_NAMES),
    ).collect(engine="streaming")
    kept, missing, first_missing, height, first, *empty = summary.row(0)
    if missing == height:  # nothing to place in a recording: say why, naming the file
        raise NgsimInputError(
            path,
            f"every one of its {missing:,} rows has an empty required field "
            f"({', '.join(REQUIRED_NAMES)}); the first at line {first}",
        )
    if not names:
        _raise_unusable(path, counts, {r: first for r, _, first in dropped.iter_rows()})
    records = vehicle_records(raw.frame, pl.when(in_chosen).then(index))
    cut = cut_record_note(records, names, raw.first_line)
    report = FileReport(
        path=str(path),
        raw_format=raw.raw_format.value,
        size_bytes=raw.size_bytes,
        sha256=file_sha256(path),
        rows_read=raw.rows_read,
        rows_other_locations=raw.rows_read - kept - missing - sum(counts.values()),
        rows_missing_values=missing,
        first_missing_line=None if missing == 0 else int(first_missing),
        rows_dropped={r: counts.get(r, 0) for r in FILE_REASONS},
        first_dropped_line={r: first for r, _, first in sorted(dropped.iter_rows())},
        rows_checked=kept + sum(counts.values()),
        locations_found=tuple(sorted(set(raw.locations_found) | {loc for loc, _ in names})),
        recordings=tuple(f"{loc}/{period}" for loc, period in sorted(chosen)),
        notes=tuple(note for key, note in sorted(notes.items()) if key in chosen)
        + empty_column_lines(empty, OPTIONAL_NAMES)
        + ((cut,) if cut else ()),
    )
    return FileRows(rows, chosen, report)


def _raise_unusable(path: Path, counts: dict[str, int], first_line: dict[str, int]) -> None:
    """Refuse a file none of whose rows can be placed in a recording: a file lost in silence as
    "rows of other locations" would take its recording with it."""
    total = sum(counts.values())
    detail = ", ".join(
        f"{n:,} {describe(reason, DROP_REASONS)}" for reason, n in sorted(counts.items()) if n
    )
    line = min(first_line.values())
    raise NgsimInputError(
        path,
        f"no row of it can be used: all {total:,} rows with every required field are "
        f"implausible ({detail}); the first at line {line} (columns swapped, other units, "
        "a damaged file?)",
    )


def _first_source(rows: pl.DataFrame) -> tuple[int, int] | None:
    """(file index, line) of the first of `rows`, if they carry their provenance."""
    if rows.height == 0 or s.SOURCE_FILE not in rows.columns:
        return None
    first = rows.select(s.SOURCE_FILE, s.SOURCE_LINE).sort(s.SOURCE_FILE, s.SOURCE_LINE).row(0)
    return int(first[0]), int(first[1])


def vehicle_tracks(
    raw: pl.DataFrame,
    key: RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    first_track_id: int,
) -> TracksPart:
    """The tracks of the vehicles of `raw` (all the rows of each, any order, duplicates allowed)
    in recording `key`, and what cleaning them counted (the Source contract's part).

    Tracks are numbered from `first_track_id` in (vehicle, segment) order; rows come out sorted
    by track and frame, columns as TRACKS_SCHEMA. Every step looks at one vehicle's rows at a
    time; the evidence is the rows `speed_comparison` compares, for the recording's median.
    """
    unique, exact, conflicting = drop_duplicate_rows(raw, CONFLICT_ORDER)
    outlier = outlier_rows(unique, limits)
    cleaned = unique.filter(~outlier)
    jumps = jump_rows(cleaned, limits)
    compared = speed_comparison(cleaned, ns.LOCAL_X, ns.LOCAL_Y, ns.V_VEL, FRAME_PERIOD_S)
    segmented, gaps = split_at_gaps(cleaned, jumps)
    location, period = key
    on_grid = downsample_to_grid(
        segmented, frames_per_step(config.time_step_s, FRAME_PERIOD_S)
    ).with_columns(pl.lit(location).alias(s.LOCATION), pl.lit(period).alias(s.PERIOD))
    grid = to_si_units(on_grid)
    tracks = finish_tracks(grid, first_track_id, config)
    report = cleaned_report(
        key,
        raw.height,
        unique,
        tracks,
        (exact, conflicting),
        gaps,
        outliers=int(outlier.sum()),
        jumps=int(jumps.sum()),
        first_outlier=_first_source(unique.filter(outlier)),
    )
    return TracksPart(tracks, report, compared)


def build_tracks(
    raw: pl.DataFrame,
    key: RecordingKey,
    config: BuildConfig,
    first_track_id: int,
    limits: PhysicalLimits = LIMITS,
) -> tuple[pl.DataFrame, RecordingReport]:
    """The tracks table and report of recording `key` from all its raw rows at once, without
    the recording's checks (see vehicle_tracks): the tests' reference; a build cleans parts."""
    part = vehicle_tracks(raw, key, config, limits, first_track_id)
    return part.tracks, joined_report([part], key, FEET_TO_M)


def read_file(
    path: Path,
    config: BuildConfig,
    limits: PhysicalLimits,
    file_index: int,
    strict: bool,
    scratch: Path | None = None,
) -> FileRows:
    """read_file_recordings, then the rule of dropped rows (`cleaning.check_dropped`) and the
    checks of each recording's columns against each other: lanes, neighbours and headways."""
    read = read_file_recordings(path, config, file_index, scratch, limits)
    check_file_drops(read.report, limits, strict, DROP_REASONS)
    check_lateral_positions(path, read)
    check_neighbours(path, read)
    return read


def check_lateral_positions(path: Path, read: FileRows) -> None:
    """The lanes of each recording of the file: one lane must not hold nearly every row of
    lateral positions several lanes apart (`lanes.check_one_lane`), and on the freeways Local_X
    must be where Lane_ID says (`lanes.check_lanes`: lanes 1..6, 12 ft each from the left
    edge)."""
    if not read.recordings:
        return
    rows = read.rows.filter(pl.col(s.RECORDING_INDEX).is_not_null()).select(
        s.RECORDING_INDEX, s.LANE_ID, (pl.col(ns.LOCAL_X) * FEET_TO_M).alias(LATERAL_M)
    )
    medians = lane_medians(rows, (s.RECORDING_INDEX,))
    for (location, period), index in read.recordings.items():
        of_recording = medians.filter(pl.col(s.RECORDING_INDEX) == index)
        name = f"{location}/{period}"
        check_one_lane(path, name, of_recording, "Lane_ID", "Local_X")
        if location in FREEWAY_LOCATIONS:
            check_lanes(path, name, of_recording, FREEWAY_LANES, "Local_X")


def recording_report(
    parts: list[TracksPart],
    key: RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    files: list[FileReport],
    strict: bool,
) -> RecordingReport:
    """joined_report, then the recording's checks: the speed column must be a speed; position
    outliers follow the rule of every dropped row (see plausibility)."""
    report = joined_report(parts, key, FEET_TO_M)
    name = f"{report.location}/{report.period}"
    sources = ", ".join(f.path for f in files if name in f.recordings)
    check_speed_column(sources, report, limits)
    if report.first_outlier is not None:
        file_index, line = report.first_outlier
        reason = DropReason.POSITION_OUTLIER.value
        check_dropped(
            files[file_index].path,
            {reason: report.position_outliers},
            {reason: line},
            report.rows,
            limits,
            strict,
        )
    return report


SOURCE = Source(
    name="ngsim",
    find_files=find_raw_files,
    read_file=read_file,
    vehicle_tracks=vehicle_tracks,
    recording_report=recording_report,
    frame_period_s=FRAME_PERIOD_S,
    limits=LIMITS,
    label="NGSIM",
    suffixes=CANDIDATE_SUFFIXES,
    claims=is_ngsim_file,
    is_location=is_ngsim_location,
    locations_help=", ".join(KNOWN_LOCATION_NAMES),
    drop_reasons=DROP_REASONS,
)
