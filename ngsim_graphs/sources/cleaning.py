"""The cleaning every source shares, over rows keyed by (vehicle, frame): duplicates, frame
gaps, the grid, and the rule of dropped rows (docs/conventions.md).

Every function is pure over a polars frame and returns what it removed, for the build report.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.contract import FileReport, RecordingKey, RecordingReport
from ngsim_graphs.sources.limits import PhysicalLimits

_BREAK = "__break"

# The shared reasons a file's report counts (position outliers are found per recording); a
# source's own (`Source.drop_reasons`) come after them.
FILE_REASONS: tuple[DropReason, ...] = tuple(
    r for r in DropReason if r is not DropReason.POSITION_OUTLIER
)
DESCRIPTIONS: dict[DropReason, str] = {
    DropReason.FRAME_ID: "Frame_ID out of range",
    DropReason.VEHICLE_ID: "Vehicle_ID below 1",
    DropReason.POSITION: "Local_X or Local_Y out of range",
    DropReason.SPEED: "v_Vel negative or above the speed limit",
    DropReason.ACCELERATION: "v_Acc above the acceleration limit",
    DropReason.POSITION_OUTLIER: "position jumps away from the neighbouring frames",
    DropReason.VEHICLE_SIZE: "v_Length or v_Width not above 0 or above the size limit",
    DropReason.LANE: "Lane_ID below 0 or above the lane limit",
    DropReason.HEADWAY: "a headway or a Preceding/Following id out of range",
    DropReason.DIRECTION: "the positions move against the vehicle's driving direction",
}


def descriptions(own: Mapping[str, str] | None = None) -> dict[str, str]:
    """What the rows dropped for each reason were, as a report says it, by reason value: the
    shared DropReasons and `own`, a source's own reasons (value -> description)."""
    return {**{reason.value: text for reason, text in DESCRIPTIONS.items()}, **(own or {})}


def describe(reason: str, own: Mapping[str, str] | None = None) -> str:
    """`descriptions(own)` of one reason."""
    return descriptions(own)[reason]


def empty_column_checks(columns: dict[str, str]) -> list[pl.Expr]:
    """Whether each of `columns` (parsed name: the name as the file spells it) is empty in every
    row: expressions to select beside a file's other totals (one pass over it)."""
    return [pl.col(c).is_null().all().alias(c) for c in columns]


def empty_column_lines(flags: Sequence[bool], columns: dict[str, str]) -> tuple[str, ...]:
    """A line for each of `columns` whose flag (`empty_column_checks`, in order) says it is empty
    in every row: an optional column, so the rows are kept, but a column emptied (or swapped
    with an empty one) must not pass without a word."""
    return tuple(
        f"column {name} is empty in every row (its values are missing from the build)"
        for name, empty in zip(columns.values(), flags, strict=True)
        if empty
    )


def empty_column_notes(
    frame: pl.LazyFrame | pl.DataFrame, columns: dict[str, str]
) -> tuple[str, ...]:
    """`empty_column_lines` of `frame`'s columns, in a pass of its own."""
    flags = frame.lazy().select(empty_column_checks(columns)).collect(engine="streaming").row(0)
    return empty_column_lines(flags, columns)


def drop_duplicate_rows(
    frame: pl.DataFrame, conflict_order: tuple[str, ...]
) -> tuple[pl.DataFrame, int, int]:
    """Drop exact duplicates, then keep one row per (vehicle, frame): the first by
    `conflict_order`, columns whose values decide (never the order of the file).

    `frame` holds whole vehicles of one recording. Returns (rows sorted by vehicle and frame,
    exact duplicates dropped, conflicting duplicates dropped). Provenance columns are not
    values: two rows alike but for their line are exact. Only the few rows whose (vehicle,
    frame) occurs more than once go through the full-row comparison.
    """
    keys = [s.VEHICLE_ID, s.FRAME_ID]
    repeated = frame.select(_row_key(frame).is_duplicated()).to_series()
    multi = frame.filter(repeated)
    values = [c for c in frame.columns if c not in s.PROVENANCE_SCHEMA]
    unique = multi.unique(subset=values, keep="first", maintain_order=True)
    ordered = unique.sort([*keys, *conflict_order], nulls_last=True)
    kept = ordered.unique(subset=keys, keep="first", maintain_order=True)
    cleaned = pl.concat([frame.filter(~repeated), kept]).sort(keys)
    return cleaned, multi.height - unique.height, unique.height - kept.height


def _row_key(frame: pl.DataFrame) -> pl.Expr:
    """(vehicle, frame) as one Int64, one to one, where both are Int32 (hashed three times as
    fast as their struct); their struct otherwise."""
    if frame.schema[s.VEHICLE_ID] != pl.Int32 or frame.schema[s.FRAME_ID] != pl.Int32:
        return pl.struct(s.VEHICLE_ID, s.FRAME_ID)
    vehicle, frame_id = pl.col(s.VEHICLE_ID).cast(pl.Int64), pl.col(s.FRAME_ID).cast(pl.Int64)
    return vehicle * 2**32 + (frame_id + 2**31)  # frame_id + 2**31 in [0, 2**32)


def split_at_gaps(frame: pl.DataFrame, breaks: pl.Series | None = None) -> tuple[pl.DataFrame, int]:
    """Number each vehicle's runs of consecutive frames: SEGMENT 0, 1, ... at every frame gap,
    and before every row where `breaks` (bool, one per row) is True (a position jump).

    `frame` must be sorted by vehicle and frame. Returns (frame with SEGMENT, frame gaps found).
    """
    step = pl.col(s.FRAME_ID).diff().over(s.VEHICLE_ID)
    gap = step.fill_null(1) != 1
    flagged = frame.with_columns(
        pl.Series(_BREAK, breaks) if breaks is not None else pl.lit(False).alias(_BREAK)
    )
    starts_segment = gap | (pl.col(_BREAK) & step.is_not_null())
    segmented = flagged.with_columns(
        starts_segment.cast(pl.Int16).cum_sum().over(s.VEHICLE_ID).alias(s.SEGMENT)
    ).drop(_BREAK)
    gaps = int(frame.select(gap.sum()).item())
    return segmented, gaps


def downsample_to_grid(frame: pl.DataFrame, frames_per_step: int) -> pl.DataFrame:
    """Keep the rows on the recording's frame grid: frame_id divisible by `frames_per_step`.

    The grid is the recording's, not the track's: every vehicle is sampled at the same instants,
    so neighbours at one grid step are seen at the same time. Never by row position.
    """
    return frame.filter(pl.col(s.FRAME_ID) % frames_per_step == 0)


def check_dropped(
    path: str,
    dropped: dict[str, int],
    first_line: dict[str, int],
    rows: int,
    limits: PhysicalLimits,
    strict: bool,
    own: Mapping[str, str] | None = None,
) -> None:
    """Raise when the rows dropped from `path` (per DropReason value, or a value of `own`, the
    source's own reasons) may not be dropped quietly.

    With `strict` any dropped row is an error; otherwise more than `max_dropped_share` of the
    `rows` checked is, because so many say the file is damaged or its columns are not what its
    header claims. `first_line`: the first line of each reason with rows.
    """
    bad = {reason: n for reason, n in dropped.items() if n}
    if not bad:
        return
    first = min(bad, key=lambda reason: first_line[reason])
    line = first_line[first]
    if strict:
        raise NgsimInputError(
            path, f"{describe(first, own)} (--strict: no row may be dropped)", line=line
        )
    total = sum(bad.values())
    if total > limits.max_dropped_share * rows:
        detail = ", ".join(f"{n:,} {describe(reason, own)}" for reason, n in bad.items())
        raise NgsimInputError(
            path,
            f"{total:,} of {rows:,} rows ({total / rows:.1%}) are implausible, more than the "
            f"{limits.max_dropped_share:.0%} a build drops: {detail}; the first at line {line} "
            "(columns swapped, other units, a damaged file?)",
        )


def check_file_drops(
    report: FileReport,
    limits: PhysicalLimits,
    strict: bool,
    own: Mapping[str, str] | None = None,
) -> None:
    """`check_dropped` of the rows a file's report says were dropped as it was read (`own`: the
    source's own reasons)."""
    check_dropped(
        report.path,
        report.rows_dropped,
        report.first_dropped_line,
        report.rows_checked,
        limits,
        strict,
        own,
    )


def cleaned_report(
    key: RecordingKey,
    rows: int,
    unique: pl.DataFrame,
    tracks: pl.DataFrame,
    duplicates: tuple[int, int],
    gaps: int,
    outliers: int = 0,
    jumps: int = 0,
    first_outlier: tuple[int, int] | None = None,
) -> RecordingReport:
    """The counts of cleaning some of a recording's vehicles: `rows` raw rows, `unique` of them
    left by `drop_duplicate_rows` ((exact, conflicting) `duplicates` dropped), `gaps` found by
    `split_at_gaps`, and their `tracks`; what a source's own checks found (position `outliers`
    and `jumps`, the first outlier's (file index, line)), none where it has none."""
    return RecordingReport(
        location=key[0],
        period=key[1],
        rows=rows,
        exact_duplicates=duplicates[0],
        conflicting_duplicates=duplicates[1],
        position_outliers=outliers,
        position_jumps=jumps,
        gaps=gaps,
        vehicles=unique[s.VEHICLE_ID].n_unique(),
        tracks=tracks[s.TRACK_ID].n_unique(),
        grid_rows=tracks.height,
        first_outlier=first_outlier,
    )
