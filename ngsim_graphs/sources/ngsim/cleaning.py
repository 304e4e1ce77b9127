"""Cleaning raw rows: incomplete rows, exact and conflicting duplicates, SI units, gap splitting.

Every function is pure over a polars frame and returns what it removed, for the build report.
"""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s

FEET_TO_M = 0.3048
_BREAK = "__break"

# Conflicting duplicates (one vehicle and frame, different values) keep the row that sorts first
# by these columns: a rule that depends on the values only, never on the order of the file.
CONFLICT_ORDER: tuple[str, ...] = (s.LOCAL_Y, s.LOCAL_X, s.V_VEL, *s.TXT_COLUMNS)


def is_complete() -> pl.Expr:
    """Rows with every required field (vehicle, frame, time, position, speed); others are dropped."""
    return pl.all_horizontal(pl.col(s.REQUIRED_VALUE_COLUMNS).is_not_null())


def drop_duplicate_rows(frame: pl.DataFrame) -> tuple[pl.DataFrame, int, int]:
    """Drop exact duplicates, then keep one row per (vehicle, frame) by CONFLICT_ORDER.

    `frame` holds whole vehicles of one recording. Returns (rows sorted by vehicle and frame,
    exact duplicates dropped, conflicting duplicates dropped). Only the few rows whose (vehicle,
    frame) occurs more than once go through the full-row comparison.
    """
    keys = [s.VEHICLE_ID, s.FRAME_ID]
    repeated = frame.select(pl.struct(keys).is_duplicated()).to_series()
    multi = frame.filter(repeated)
    values = [c for c in frame.columns if c not in s.PROVENANCE_SCHEMA]
    unique = multi.unique(subset=values, keep="first")
    ordered = unique.sort([*keys, *CONFLICT_ORDER], nulls_last=True)
    kept = ordered.unique(subset=keys, keep="first", maintain_order=True)
    cleaned = pl.concat([frame.filter(~repeated), kept]).sort(keys)
    return cleaned, multi.height - unique.height, unique.height - kept.height


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


def to_si_units(frame: pl.DataFrame) -> pl.DataFrame:
    """The tracks table's columns in SI units, from raw columns in feet, feet/s and ms.

    NGSIM's sentinels become null: Preceding/Following 0 (none) and Time_Headway 9999.99 (no
    leader); Space_Headway is null wherever there is no preceding vehicle.
    """
    feet = lambda column: pl.col(column) * FEET_TO_M  # noqa: E731
    no_leader = pl.col(s.PRECEDING).is_null() | (pl.col(s.PRECEDING) == s.NO_NEIGHBOUR_ID)
    return frame.select(
        s.LOCATION,
        s.PERIOD,
        s.VEHICLE_ID,
        s.SEGMENT,
        s.FRAME_ID,
        (pl.col(s.FRAME_ID) * 0.1).alias(s.TIME_S),
        s.GLOBAL_TIME,
        feet(s.LOCAL_X).alias(s.X_M),
        feet(s.LOCAL_Y).alias(s.Y_M),
        feet(s.V_VEL).alias(s.SPEED_MPS),
        feet(s.V_ACC).alias(s.ACCEL_MPS2),
        s.LANE_ID,
        s.V_CLASS,
        feet(s.V_LENGTH).alias(s.LENGTH_M),
        feet(s.V_WIDTH).alias(s.WIDTH_M),
        pl.col(s.PRECEDING).replace(s.NO_NEIGHBOUR_ID, None),
        pl.col(s.FOLLOWING).replace(s.NO_NEIGHBOUR_ID, None),
        pl.when(no_leader).then(None).otherwise(feet(s.SPACE_HEADWAY)).alias(s.SPACE_HEADWAY_M),
        pl.when(pl.col(s.TIME_HEADWAY) >= s.NO_LEADER_TIME_HEADWAY_S)
        .then(None)
        .otherwise(pl.col(s.TIME_HEADWAY))
        .alias(s.TIME_HEADWAY_S),
    )
