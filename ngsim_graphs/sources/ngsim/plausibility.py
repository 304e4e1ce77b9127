"""Physical plausibility of raw rows: which are impossible, and why (docs/conventions.md).

Real exports hold stray rows: a damaged number, a swapped column, a vehicle that jumps a
kilometre in a frame. Each such row is dropped on its own and counted per reason; it never costs
its recording. The limits are NGSIM's (`LIMITS`, the NGSIM Source's `limits`: metric, its
frame ids its 10 Hz frames); rows are in NGSIM's units (feet) here, so the limits are converted
once.
"""

from __future__ import annotations

from enum import Enum

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources import cleaning
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M
from ngsim_graphs.sources.speeds import distance, same_vehicle


class NgsimDrop(str, Enum):
    """Why NGSIM's rows are dropped beyond the shared reasons (`schema.DropReason`)."""

    GLOBAL_TIME = "global_time_off_recording"  # Global_Time - 100 * Frame_ID not its recording's
    VEHICLE_CLASS = "vehicle_class_unknown"  # v_Class none of 1 (motorcycle), 2 (car), 3 (truck)


# What an NGSIM row may hold (the NGSIM Source's `limits`): the metric defaults, and frame ids up
# to two hours of its 10 Hz frames (a 1 s outlier burst: 10 frames; a 10 m jump in 0.1 s: 100 m/s).
LIMITS = PhysicalLimits(max_frame_id=72_000)

# The NGSIM source's own reasons (`Source.drop_reasons`), as its reports say them.
DROP_REASONS: dict[str, str] = {
    NgsimDrop.GLOBAL_TIME.value: (
        "Global_Time off its recording (Global_Time - 100 * Frame_ID differs)"
    ),
    NgsimDrop.VEHICLE_CLASS.value: "v_Class none of 1 (motorcycle), 2 (car), 3 (truck)",
}
# Every reason an NGSIM file's report counts.
FILE_REASONS: tuple[str, ...] = (*(r.value for r in cleaning.FILE_REASONS), *DROP_REASONS)

# The row checks in the order they are tried: a row is counted under the first that fails.
ROW_CHECKS: tuple[DropReason | NgsimDrop, ...] = (
    DropReason.FRAME_ID,
    DropReason.VEHICLE_ID,
    DropReason.POSITION,
    DropReason.SPEED,
    DropReason.ACCELERATION,
    DropReason.VEHICLE_SIZE,
    DropReason.LANE,
    NgsimDrop.VEHICLE_CLASS,
    DropReason.HEADWAY,
)
VEHICLE_CLASSES = (1, 2, 3)  # motorcycle, car, truck
_ROW, _RUN = "__row", "__run"


def feet(metres: float) -> float:
    """A limit in metres in NGSIM's feet."""
    return metres / FEET_TO_M


def _failed(reason: DropReason | NgsimDrop, limits: PhysicalLimits) -> pl.Expr:
    """True where a row breaks the limit behind `reason` (null values break nothing)."""
    if reason is DropReason.FRAME_ID:
        return (pl.col(s.FRAME_ID) < 0) | (pl.col(s.FRAME_ID) > limits.max_frame_id)
    if reason is DropReason.VEHICLE_ID:
        return pl.col(s.VEHICLE_ID) < 1
    if reason is DropReason.POSITION:
        far = feet(limits.max_abs_position_m)
        return (pl.col(ns.LOCAL_X).abs() > far) | (pl.col(ns.LOCAL_Y).abs() > far)
    if reason is DropReason.SPEED:
        return (pl.col(ns.V_VEL) < 0) | (pl.col(ns.V_VEL) > feet(limits.max_speed_mps))
    if reason is DropReason.ACCELERATION:
        return pl.col(ns.V_ACC).abs() > feet(limits.max_abs_accel_mps2)
    if reason is DropReason.VEHICLE_SIZE:
        return _outside(ns.V_LENGTH, 0, feet(limits.max_vehicle_length_m), True) | _outside(
            ns.V_WIDTH, 0, feet(limits.max_vehicle_width_m), True
        )
    if reason is DropReason.LANE:
        return _outside(s.LANE_ID, 0, limits.max_lane_id)
    if reason is NgsimDrop.VEHICLE_CLASS:
        return ~pl.col(s.V_CLASS).is_in(VEHICLE_CLASSES)
    if reason is DropReason.HEADWAY:
        # 0 says "no leader" for Space_Headway and the ids, 9999.99 for Time_Headway.
        return (
            _outside(ns.SPACE_HEADWAY, 0, feet(limits.max_abs_position_m))
            | _outside(ns.TIME_HEADWAY, 0, ns.NO_LEADER_TIME_HEADWAY_S)
            | (pl.col(s.PRECEDING) < 0)
            | (pl.col(s.FOLLOWING) < 0)
        )
    raise ValueError(f"{reason} is not a row check")


def _outside(column: str, low: float, high: float, open_below: bool = False) -> pl.Expr:
    """Whether a value lies outside [low, high] ((low, high] where `open_below`)."""
    below = pl.col(column) <= low if open_below else pl.col(column) < low
    return below | (pl.col(column) > high)


def passes_row_checks(limits: PhysicalLimits) -> pl.Expr:
    """Whether a raw row fails none of ROW_CHECKS: `row_drop_reason` is null, told without
    making a text per row."""
    return ~pl.any_horizontal([_failed(reason, limits).fill_null(False) for reason in ROW_CHECKS])


def row_drop_reason(limits: PhysicalLimits) -> pl.Expr:
    """The first of ROW_CHECKS a raw row fails, as its DropReason value; null for a good row."""
    chain = pl.when(_failed(ROW_CHECKS[0], limits).fill_null(False)).then(
        pl.lit(ROW_CHECKS[0].value)
    )
    for reason in ROW_CHECKS[1:]:
        chain = chain.when(_failed(reason, limits).fill_null(False)).then(pl.lit(reason.value))
    return chain.otherwise(pl.lit(None, dtype=pl.String))


def _jumps(far_ft: float) -> tuple[pl.Expr, pl.Expr, pl.Expr, pl.Expr]:
    """(adjacent frame before, adjacent frame after, jump from the one before, jump to the one
    after) per row of a frame sorted by vehicle and frame; a jump is a move of more than
    `far_ft` between adjacent frames of one vehicle."""
    before, after = same_vehicle(1, 1), same_vehicle(-1, 1)
    jump_in = before & (distance(ns.LOCAL_X, ns.LOCAL_Y, 1) > far_ft).fill_null(False)
    jump_out = after & (distance(ns.LOCAL_X, ns.LOCAL_Y, -1) > far_ft).fill_null(False)
    return before, after, jump_in, jump_out


def outlier_rows(frame: pl.DataFrame, limits: PhysicalLimits) -> pl.Series:
    """Which rows of `frame` (sorted by vehicle and frame) are position outliers (bool).

    First, single rows that jump away from every adjacent frame they have (one damaged
    position, also at a record's first or last frame). Then, among the others, short bursts:
    runs of at most `max_outlier_frames` rows that jump away from the rows before and after
    them (a few damaged positions in a row). Any other jump (a long stretch of a record
    displaced, as when an id is reused) is left to split the track (`jump_rows`).
    """
    far = feet(limits.max_jump_m)
    before, after, jump_in, jump_out = _jumps(far)
    isolated = (jump_in | jump_out) & ~(before & ~jump_in) & ~(after & ~jump_out)
    indexed = frame.select(s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_X, ns.LOCAL_Y).with_row_index(_ROW)
    single = indexed.select(isolated).to_series()
    rest = indexed.filter(~single)
    before, _, jump_in, jump_out = _jumps(far)
    runs = rest.with_columns(
        (~before | jump_in).cum_sum().alias(_RUN), jump_in.alias("in"), jump_out.alias("out")
    )
    burst = (
        (pl.len().over(_RUN) <= limits.max_outlier_frames)
        & pl.col("in").first().over(_RUN)
        & pl.col("out").last().over(_RUN)
    )
    burst_rows = runs.filter(burst)[_ROW]
    return single | indexed[_ROW].is_in(burst_rows.implode())


def jump_rows(frame: pl.DataFrame, limits: PhysicalLimits) -> pl.Series:
    """Rows (bool) that moved more than `max_jump_m` from the adjacent frame before them: where
    a track is split, as at a frame gap. `frame` sorted by vehicle and frame."""
    _, _, jump_in, _ = _jumps(feet(limits.max_jump_m))
    return frame.select(jump_in).to_series()
