"""highD files to the tracks table (docs/highd.md): the highD `Source`.

Per input file: a tracks file is parsed, its rows beyond the physical limits or with an empty
required field are dropped and counted, the rest are mapped to the road frame (`geometry`)
with the help of the recording's two meta files, the rows of a vehicle that moves against its
drivingDirection are dropped and counted, and the rest staged for the recording. The meta files
are inputs in their own right (listed in the manifest with size and checksum); they give no
rows, so their reports say `rows_read` 0. Per recording: exact duplicates dropped, conflicting
ones resolved, each vehicle's record split at frame gaps, the 0.2 s grid kept by frame number
(`frame % 5 == 0`), time from the 25 Hz frame number, tracks numbered and the heading derived;
then the speed check (`sources.speeds.check_speed_column`): the speeds must be those the
positions show.

Not done for highD, whose trajectories come smoothed from its own tracker: the position
outlier and jump checks of NGSIM (the reports' counts are 0).
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources import cleaning, contract, lanes, speeds
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.files import (
    FIRST_LINE,
    ROW,
    RecordingMeta,
    count_data_rows,
    find_highd_files,
    is_highd_file,
    read_recording_meta,
    read_tracks,
    read_tracks_meta,
)
from ngsim_graphs.sources.highd.geometry import (
    LIMITS,
    STAGED_SCHEMA,
    moves_backwards,
    row_drop_reason,
    to_road_frame,
)
from ngsim_graphs.sources.highd.recordings import (
    FRAME_PERIOD_MS,
    FRAME_PERIOD_S,
    FRAME_RATE_HZ,
    chosen_locations,
    frames_per_step,
    is_highd_location,
    location_name,
    parse_file_name,
    period_name,
    sibling,
)
from ngsim_graphs.sources.highd.schema import HighdFile
from ngsim_graphs.sources.limits import PhysicalLimits

METRES = 1.0  # highD's unit of length, in metres (the speed check's evidence is in it)
TRACKS_FORMAT = f"highd-{HighdFile.TRACKS.value}"  # a tracks file's contract.FileReport.raw_format
# Conflicting duplicates (one vehicle and frame, different values) keep the row that sorts first
# by these columns (the smallest y_m, then x_m, ...): a rule of the values alone, never of the
# order of the file.
CONFLICT_ORDER: tuple[str, ...] = (
    s.Y_M,
    s.X_M,
    *(c for c in STAGED_SCHEMA if c not in (s.VEHICLE_ID, s.FRAME_ID, s.Y_M, s.X_M)),
)

# The parsed columns a row may leave empty, each by its name.
_OPTIONAL = {c: c for c in hs.HIGHD_TRACKS_SCHEMA if c not in hs.HIGHD_REQUIRED_COLUMNS}


def _recording(
    path: Path, limits: PhysicalLimits
) -> tuple[HighdFile, RecordingMeta, contract.RecordingKey]:
    """The kind of file `path` is (by name), its recording's meta and key."""
    named = parse_file_name(path)
    if named is None:
        raise NgsimInputError(
            path, "not named like a highD file (NN_tracks.csv, NN_tracksMeta.csv, ...)"
        )
    prefix, kind = named
    meta_path = sibling(path, prefix, HighdFile.RECORDING_META)
    if not meta_path.is_file():
        raise NgsimInputError(
            path, f"no {meta_path.name} beside it: a highD recording needs all three files"
        )
    meta = read_recording_meta(meta_path, limits)
    if meta.recording_id != int(prefix):
        raise NgsimInputError(
            meta_path,
            f"recording id {meta.recording_id}, but the file name says {prefix}",
            line=FIRST_LINE,
        )
    return kind, meta, _recording_key(meta)


def _recording_key(meta: RecordingMeta) -> contract.RecordingKey:
    return location_name(meta.location_id), period_name(meta.recording_id)


def _report(
    path: Path, key: contract.RecordingKey, chosen: bool, **counts: object
) -> contract.FileReport:
    """A file's report; `counts` fill in what reading its rows found (a meta file has none)."""
    fields: dict[str, object] = {
        "rows_read": 0,
        "rows_other_locations": 0,
        "rows_missing_values": 0,
        "first_missing_line": None,
        "rows_dropped": {r.value: 0 for r in cleaning.FILE_REASONS},
        "first_dropped_line": {},
        "rows_checked": 0,
    }
    fields.update(counts)
    kind = parse_file_name(path)
    return contract.FileReport(
        path=str(path),
        raw_format=f"highd-{kind[1].value if kind else HighdFile.TRACKS.value}",
        size_bytes=path.stat().st_size,
        sha256=file_sha256(path),
        locations_found=(key[0],),
        recordings=(f"{key[0]}/{key[1]}",) if chosen else (),
        **fields,  # type: ignore[arg-type]
    )


def _check_whole_tracks(path: Path, raw: pl.DataFrame, vehicles: pl.DataFrame) -> None:
    """Raise when a track has fewer rows in the tracks file than its numFrames in the
    tracksMeta file: a file cut short at a line end (which keeps every line whole) loses the
    end of one track and every track after it."""
    counts = raw.filter(pl.col(hs.HIGHD_ID).is_not_null()).group_by(hs.HIGHD_ID).len("rows")
    short = (
        vehicles.join(counts, left_on=s.VEHICLE_ID, right_on=hs.HIGHD_ID, how="left")
        .with_columns(pl.col("rows").fill_null(0))
        .filter(pl.col("rows") < pl.col(hs.HIGHD_NUM_FRAMES))
        .sort(s.VEHICLE_ID)
    )
    if short.height:
        track, rows, frames = short.select(s.VEHICLE_ID, "rows", hs.HIGHD_NUM_FRAMES).row(0)
        others = short.height - 1
        more = f" (and {others:,} more track{'s' * (others > 1)})" if others else ""
        meta_name = sibling(path, parse_file_name(path)[0], HighdFile.TRACKS_META).name  # type: ignore[index]
        raise NgsimInputError(
            path,
            f"track {track} has {rows:,} rows where {meta_name} says {frames:,} (numFrames)"
            f"{more}: cut short?",
        )


def _check_lateral_positions(path: Path, usable: pl.DataFrame, meta: RecordingMeta) -> None:
    """`lanes.check_lanes` of the recording: each laneId's vehicles (their centres, image y)
    must be between that lane's markings."""
    centre = pl.col(hs.HIGHD_Y) + pl.col(hs.HIGHD_HEIGHT) / 2
    rows = usable.select(pl.col(hs.HIGHD_LANE_ID).alias(s.LANE_ID), centre.alias(lanes.LATERAL_M))
    bands = lanes.marked_lanes(meta.upper_markings_m, meta.lower_markings_m)
    name = "/".join(_recording_key(meta))
    lanes.check_lanes(path, name, lanes.lane_medians(rows), bands, "y")


def _road_rows(
    usable: pl.DataFrame, path: Path, meta: RecordingMeta, file_index: int, vehicles: pl.DataFrame
) -> pl.DataFrame:
    """Raw tracks rows (with SOURCE_LINE) in the road frame, with provenance: each with its
    vehicle's class and drivingDirection from the tracksMeta file (`vehicles`), which must
    know it."""
    prefix = parse_file_name(path)[0]  # type: ignore[index]
    joined = usable.join(
        vehicles.select(s.VEHICLE_ID, s.V_CLASS, hs.HIGHD_DRIVING_DIRECTION),
        left_on=hs.HIGHD_ID,
        right_on=s.VEHICLE_ID,
        how="left",
        maintain_order="left",
    )
    unknown = joined.filter(pl.col(hs.HIGHD_DRIVING_DIRECTION).is_null())
    if unknown.height:
        raise NgsimInputError(
            path,
            f"track id {unknown[hs.HIGHD_ID][0]} has no row in {prefix}_tracksMeta.csv",
            line=int(unknown[s.SOURCE_LINE][0]),
        )
    return to_road_frame(
        joined.with_columns(pl.lit(file_index, dtype=pl.UInt16).alias(s.SOURCE_FILE)), meta
    )


def _staged_rows(
    path: Path, meta: RecordingMeta, limits: PhysicalLimits, file_index: int
) -> tuple[pl.DataFrame, dict[str, object]]:
    """The usable rows of a tracks file in the road frame, with provenance; and its report.

    A row counts under the first reason it breaks: an empty required field, a row check
    (geometry.row_drop_reason), then its vehicle's driving against its direction."""
    raw = read_tracks(path)
    prefix = parse_file_name(path)[0]  # type: ignore[index]
    vehicles = read_tracks_meta(sibling(path, prefix, HighdFile.TRACKS_META))
    _check_whole_tracks(path, raw, vehicles)
    complete = pl.all_horizontal(pl.col(hs.HIGHD_REQUIRED_COLUMNS).is_not_null())
    checked = raw.with_columns(
        pl.when(complete).then(row_drop_reason(limits)).alias("reason"),
        complete.alias("complete"),
        (pl.col(ROW) + FIRST_LINE).alias(s.SOURCE_LINE),
    )
    usable = checked.filter(pl.col("complete") & pl.col("reason").is_null())
    _check_lateral_positions(path, usable, meta)
    rows = _road_rows(usable, path, meta, file_index, vehicles)
    backwards = rows.select(moves_backwards()).to_series()
    against = rows.filter(backwards).select(
        pl.lit(DropReason.DIRECTION.value).alias("reason"), s.SOURCE_LINE
    )
    rows = rows.filter(~backwards)
    reasons = pl.concat([checked.select("reason", s.SOURCE_LINE), against])
    dropped = (
        reasons.drop_nulls("reason").group_by("reason").agg(pl.len(), pl.col(s.SOURCE_LINE).min())
    )
    missing = checked.filter(~pl.col("complete"))
    counts = {reason: n for reason, n, _ in dropped.iter_rows()}
    report: dict[str, object] = {
        "rows_read": raw.height,
        "rows_missing_values": missing.height,
        "first_missing_line": int(missing[s.SOURCE_LINE].min()) if missing.height else None,
        "rows_dropped": {r.value: counts.get(r.value, 0) for r in cleaning.FILE_REASONS},
        "first_dropped_line": {r: first for r, _, first in sorted(dropped.iter_rows())},
        "rows_checked": raw.height - missing.height,
        "notes": cleaning.empty_column_notes(raw, _OPTIONAL),
    }
    return rows, report


def read_file(
    path: Path,
    config: BuildConfig,
    limits: PhysicalLimits,
    file_index: int,
    strict: bool,
    scratch: Path | None = None,
) -> contract.FileRows:
    """Read one highD file: a tracks file gives its recording's rows (STAGED_SCHEMA, with
    RECORDING_INDEX and provenance); a meta file is checked and gives none. (A recording's file
    is read in memory: `scratch` is not used.)"""
    frames_per_step(config.time_step_s, path)  # a grid the 25 Hz frames cannot land on fails first
    kind, meta, key = _recording(path, limits)
    allowed = chosen_locations(config.locations)
    chosen = allowed is None or key[0] in allowed
    empty = pl.LazyFrame(
        schema={**STAGED_SCHEMA, s.RECORDING_INDEX: pl.Int32, **s.PROVENANCE_SCHEMA}
    )
    if kind is HighdFile.TRACKS_META:
        read_tracks_meta(path)  # its recording's meta was read above
    if kind is not HighdFile.TRACKS:
        return contract.FileRows(empty, {}, _report(path, key, chosen))
    if not chosen:
        n = count_data_rows(path)
        return contract.FileRows(
            empty, {}, _report(path, key, chosen, rows_read=n, rows_other_locations=n)
        )
    rows, counts = _staged_rows(path, meta, limits, file_index)
    report = _report(path, key, chosen, **counts)
    cleaning.check_file_drops(report, limits, strict)
    staged = rows.with_columns(pl.lit(0, dtype=pl.Int32).alias(s.RECORDING_INDEX))
    return contract.FileRows(staged.lazy().select(empty.collect_schema().names()), {key: 0}, report)


def vehicle_tracks(
    raw: pl.DataFrame,
    key: contract.RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    first_track_id: int,
) -> contract.TracksPart:
    """The tracks of the vehicles of `raw` in recording `key` (all the rows of each, from its
    staged rows: any order, duplicates allowed), what cleaning them counted, and the evidence
    of the speed check (`speeds.speed_comparison` of their 25 Hz rows, in metres). (Its rows
    were held to `limits` as read: nothing here reads them.)

    Tracks are numbered from `first_track_id` in (vehicle, segment) order; rows come out sorted
    by track and frame, columns as TRACKS_SCHEMA. time_s = frame / 25, global_time = 40 * frame
    (ms since the recording's frame 0; highD's frames start at 1).
    """
    unique, exact, conflicting = cleaning.drop_duplicate_rows(raw, CONFLICT_ORDER)
    compared = speeds.speed_comparison(unique, s.X_M, s.Y_M, s.SPEED_MPS, FRAME_PERIOD_S)
    segmented, gaps = cleaning.split_at_gaps(unique)
    location, period = key
    on_grid = cleaning.downsample_to_grid(
        segmented, frames_per_step(config.time_step_s, Path(f"{location}/{period}"))
    )
    grid = on_grid.with_columns(
        pl.lit(location).alias(s.LOCATION),
        pl.lit(period).alias(s.PERIOD),
        (pl.col(s.FRAME_ID) / FRAME_RATE_HZ).alias(s.TIME_S),
        (pl.col(s.FRAME_ID).cast(pl.Int64) * FRAME_PERIOD_MS).alias(s.GLOBAL_TIME),
    )
    tracks = contract.finish_tracks(grid, first_track_id, config)
    report = cleaning.cleaned_report(key, raw.height, unique, tracks, (exact, conflicting), gaps)
    return contract.TracksPart(tracks, report, compared)


def build_tracks(
    raw: pl.DataFrame, key: contract.RecordingKey, config: BuildConfig, first_track_id: int
) -> tuple[pl.DataFrame, contract.RecordingReport]:
    """The tracks table and report of recording `key` from all its staged rows at once: the
    tests' reference; a build cleans parts (vehicle_tracks)."""
    part = vehicle_tracks(raw, key, config, LIMITS, first_track_id)
    return part.tracks, speeds.joined_report([part], key, METRES)


def recording_report(
    parts: list[contract.TracksPart],
    key: contract.RecordingKey,
    config: BuildConfig,
    limits: PhysicalLimits,
    files: list[contract.FileReport],
    strict: bool,
) -> contract.RecordingReport:
    """The parts' counts summed and the speed check's medians (`speeds.joined_report`), after
    the recording's one check: xVelocity and yVelocity must be the speed the positions show
    (its rows were checked as read, read_file)."""
    report = speeds.joined_report(parts, key, METRES)
    name = f"{report.location}/{report.period}"
    tracks_files = [f.path for f in files if name in f.recordings and f.raw_format == TRACKS_FORMAT]
    units = "metres per second (x and y: metres)"
    speeds.check_speed_column(", ".join(tracks_files), report, limits, "xVelocity", units)
    return report


SOURCE = contract.Source(  # the contract's four functions in its order, then how it is told
    "highd",
    find_highd_files,
    read_file,
    vehicle_tracks,
    recording_report,
    frame_period_s=FRAME_PERIOD_S,
    limits=LIMITS,
    label="highD",
    suffixes=(".csv",),
    claims=is_highd_file,
    is_location=is_highd_location,
    locations_help="highd-N (a highD locationId; none named: every one)",
)
