"""Physical plausibility of raw rows: which are impossible, and why (SPEC section 1).

Real exports hold stray rows: a damaged number, a swapped column, a vehicle that jumps a
kilometre in a frame. Each such row is dropped on its own and counted per reason; it never costs
its recording. The limits live in `config.PhysicalLimits`; rows are in NGSIM's units (feet) here,
so the limits are converted once.
"""

from __future__ import annotations

import math

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import FRAME_STEP_S, PhysicalLimits
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M

# The row checks in the order they are tried: a row is counted under the first that fails.
ROW_CHECKS: tuple[DropReason, ...] = (
    DropReason.FRAME_ID,
    DropReason.VEHICLE_ID,
    DropReason.POSITION,
    DropReason.SPEED,
    DropReason.ACCELERATION,
    DropReason.VEHICLE_SIZE,
    DropReason.LANE,
    DropReason.VEHICLE_CLASS,
    DropReason.HEADWAY,
)
VEHICLE_CLASSES = (1, 2, 3)  # motorcycle, car, truck

DESCRIPTIONS: dict[DropReason, str] = {
    DropReason.FRAME_ID: "Frame_ID out of range",
    DropReason.VEHICLE_ID: "Vehicle_ID below 1",
    DropReason.POSITION: "Local_X or Local_Y out of range",
    DropReason.SPEED: "v_Vel negative or above the speed limit",
    DropReason.ACCELERATION: "v_Acc above the acceleration limit",
    DropReason.GLOBAL_TIME: "Global_Time off its recording (Global_Time - 100 * Frame_ID differs)",
    DropReason.POSITION_OUTLIER: "position jumps away from the neighbouring frames",
    DropReason.VEHICLE_SIZE: "v_Length or v_Width not above 0 or above the size limit",
    DropReason.LANE: "Lane_ID below 0 or above the lane limit",
    DropReason.VEHICLE_CLASS: "v_Class none of 1 (motorcycle), 2 (car), 3 (truck)",
    DropReason.HEADWAY: "a headway or a Preceding/Following id out of range",
    DropReason.DIRECTION: "the positions move against the vehicle's driving direction",
}


def feet(metres: float) -> float:
    """A limit in metres in NGSIM's feet."""
    return metres / FEET_TO_M


def _failed(reason: DropReason, limits: PhysicalLimits) -> pl.Expr:
    """True where a row breaks the limit behind `reason` (null values break nothing)."""
    if reason is DropReason.FRAME_ID:
        return (pl.col(s.FRAME_ID) < 0) | (pl.col(s.FRAME_ID) > limits.max_frame_id)
    if reason is DropReason.VEHICLE_ID:
        return pl.col(s.VEHICLE_ID) < 1
    if reason is DropReason.POSITION:
        far = feet(limits.max_abs_position_m)
        return (pl.col(s.LOCAL_X).abs() > far) | (pl.col(s.LOCAL_Y).abs() > far)
    if reason is DropReason.SPEED:
        return (pl.col(s.V_VEL) < 0) | (pl.col(s.V_VEL) > feet(limits.max_speed_mps))
    if reason is DropReason.ACCELERATION:
        return pl.col(s.V_ACC).abs() > feet(limits.max_abs_accel_mps2)
    if reason is DropReason.VEHICLE_SIZE:
        return _outside(s.V_LENGTH, 0, feet(limits.max_vehicle_length_m), True) | _outside(
            s.V_WIDTH, 0, feet(limits.max_vehicle_width_m), True
        )
    if reason is DropReason.LANE:
        return _outside(s.LANE_ID, 0, limits.max_lane_id)
    if reason is DropReason.VEHICLE_CLASS:
        return ~pl.col(s.V_CLASS).is_in(VEHICLE_CLASSES)
    if reason is DropReason.HEADWAY:
        # 0 says "no leader" for Space_Headway and the ids, 9999.99 for Time_Headway.
        return (
            _outside(s.SPACE_HEADWAY, 0, feet(limits.max_abs_position_m))
            | _outside(s.TIME_HEADWAY, 0, s.NO_LEADER_TIME_HEADWAY_S)
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


def _same_vehicle(shift: int, frames: int) -> pl.Expr:
    """Whether the row `shift` rows away (in a frame sorted by vehicle and frame) is the same
    vehicle exactly `frames` frames away. Plain shifts: far cheaper than window expressions."""
    return (
        (pl.col(s.VEHICLE_ID).shift(shift) == pl.col(s.VEHICLE_ID))
        & ((pl.col(s.FRAME_ID).shift(shift) - pl.col(s.FRAME_ID)).abs() == frames)
    ).fill_null(False)


def _distance_ft(first: int, second: int = 0) -> pl.Expr:
    """Distance between the rows `first` and `second` rows away (null at the frame's ends)."""
    dx = pl.col(s.LOCAL_X).shift(first) - pl.col(s.LOCAL_X).shift(second)
    dy = pl.col(s.LOCAL_Y).shift(first) - pl.col(s.LOCAL_Y).shift(second)
    return (dx * dx + dy * dy).sqrt()


def _jumps(far_ft: float) -> tuple[pl.Expr, pl.Expr, pl.Expr, pl.Expr]:
    """(adjacent frame before, adjacent frame after, jump from the one before, jump to the one
    after) per row of a frame sorted by vehicle and frame; a jump is a move of more than
    `far_ft` between adjacent frames of one vehicle."""
    before, after = _same_vehicle(1, 1), _same_vehicle(-1, 1)
    jump_in = before & (_distance_ft(1) > far_ft).fill_null(False)
    jump_out = after & (_distance_ft(-1) > far_ft).fill_null(False)
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
    indexed = frame.select(s.VEHICLE_ID, s.FRAME_ID, s.LOCAL_X, s.LOCAL_Y).with_row_index(_ROW)
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


_ROW, _RUN = "__row", "__run"
SPEED_WINDOW_FRAMES = 5  # each side: the motion a speed is compared with spans 1 s
MIN_SPEED_ROWS = 100  # fewer rows with a whole window say too little to judge the column


def speed_comparison(frame: pl.DataFrame, frame_period_s: float = FRAME_STEP_S) -> pl.DataFrame:
    """How well v_Vel agrees with the motion the positions show, row by row; `frame` sorted by
    vehicle and frame, `frame_period_s` apart (NGSIM's 0.1 s; highD's 0.04 s).

    For every row with the same vehicle recorded SPEED_WINDOW_FRAMES frames before and after
    it, the shown speed is the distance between those two positions over their time apart (a
    centred difference: position jitter averages out, steady acceleration does not bias it).
    Returns those rows' "vel" and "shown" (feet per second). A vehicle's rows are compared among
    themselves: the rows of sets of whole vehicles, concatenated, are those of all at once."""
    h = SPEED_WINDOW_FRAMES
    whole = _same_vehicle(-h, h) & _same_vehicle(h, h)
    shown = _distance_ft(-h, h) / (2 * h * frame_period_s)
    compared = frame.select(
        shown.alias("shown"), pl.col(s.V_VEL).alias("vel"), whole.alias("whole")
    )
    return compared.filter(pl.col("whole").fill_null(False)).drop("whole")


def speed_medians(compared: pl.DataFrame | pl.LazyFrame) -> tuple[float, float, int]:
    """(median |v_Vel - shown speed|, median shown speed, rows compared) in m/s of the rows of
    `speed_comparison`; NaN medians when no row has a whole window.

    A lazy table (a build's, from its staged files) is never held whole: each median is exact,
    found by `streamed_median`."""
    compared = compared.lazy()
    columns = {
        "mismatch": (pl.col("vel") - pl.col("shown")).abs(),
        "shown": pl.col("shown"),
    }
    rows = compared.select(pl.len()).collect(engine="streaming").item()
    if rows == 0:
        return math.nan, math.nan, 0
    mismatch, speed = (streamed_median(compared.select(e.alias(n))) for n, e in columns.items())
    return mismatch * FEET_TO_M, speed * FEET_TO_M, rows


# A median is found among at most this many values held at once (`streamed_median`), narrowed
# down a histogram of this many bins at a time.
MEDIAN_HELD_VALUES = 65_536
MEDIAN_BINS = 1_024


def streamed_median(values: pl.LazyFrame) -> float | None:
    """Polars' median of the one column of `values` (nulls left out; None if all are), exactly,
    with no more than MEDIAN_HELD_VALUES of them in memory at once where no value is NaN.

    The middle values (one, or two of an even count) are found by counting the values in bins
    of a histogram over the range they are in, keeping the bin they fall in, until it holds few
    enough to sort; Polars then takes their median, as it would of all the values."""
    column = pl.col(values.collect_schema().names()[0])
    values = values.filter(column.is_not_null())
    count, nans = values.select(pl.len(), column.is_nan().sum()).collect(engine="streaming").row(0)
    if count == 0:
        return None
    if nans:  # NaN sorts above every number: Polars' own median of all of them
        return values.collect(engine="streaming").to_series().median()
    middle = sorted({(count - 1) // 2, count // 2})
    dtype = values.collect_schema().dtypes()[0]
    return pl.Series([_kth_smallest(values, column, k) for k in middle], dtype=dtype).median()


def _kth_smallest(values: pl.LazyFrame, column: pl.Expr, k: int) -> float:
    """The k-th smallest (from 0) of a column without null or NaN (see `streamed_median`)."""
    while True:
        low, high, count = (
            values.select(column.min().alias("low"), column.max().alias("high"), pl.len())
            .collect(engine="streaming")
            .row(0)
        )
        if low == high:
            return low
        if count <= MEDIAN_HELD_VALUES:
            return values.collect(engine="streaming").to_series().sort()[k]
        # The same expression in every pass: a value falls in the same bin each time.
        bins = ((column - low) / (high - low) * MEDIAN_BINS).floor().clip(0, MEDIAN_BINS - 1)
        per_bin = values.group_by(bins.alias("bin")).len().sort("bin").collect(engine="streaming")
        if per_bin.height == 1:  # a range too wide for its bins: no narrowing, every value held
            return values.collect(engine="streaming").to_series().sort()[k]
        before = per_bin["len"].cum_sum() - per_bin["len"]
        at = int((before <= k).sum()) - 1
        k -= int(before[at])
        values = values.filter(bins == per_bin["bin"][at])


def check_speed_column(
    path: str,
    mismatch_mps: float,
    speed_mps: float,
    rows: int,
    limits: PhysicalLimits,
    column: str = "v_Vel",
    units: str = "feet per second",
) -> None:
    """Raise when the speed `column` (in `units`, as the message says) is not the speed the
    positions show (see speed_comparison)."""
    allowed = limits.max_speed_mismatch_mps + limits.max_speed_mismatch_share * speed_mps
    if rows >= MIN_SPEED_ROWS and mismatch_mps > allowed:
        raise NgsimInputError(
            path,
            f"{column} disagrees with the vehicles' motion: the median difference from the speed "
            f"their positions show is {mismatch_mps:.1f} m/s over {rows:,} rows (median speed "
            f"{speed_mps:.1f} m/s, {allowed:.1f} allowed); is {column} swapped with another "
            f"column, or in other units than {units}?",
        )


def check_dropped(
    path: str,
    dropped: dict[str, int],
    first_line: dict[str, int],
    rows: int,
    limits: PhysicalLimits,
    strict: bool,
) -> None:
    """Raise when the rows dropped from `path` (per DropReason value) may not be dropped quietly.

    With `strict` any dropped row is an error; otherwise more than `max_dropped_share` of the
    `rows` checked is, because so many say the file is damaged or its columns are not what its
    header claims. `first_line`: the first line of each reason with rows.
    """
    bad = {DropReason(reason): n for reason, n in dropped.items() if n}
    if not bad:
        return
    first = min(bad, key=lambda reason: first_line[reason.value])
    line = first_line[first.value]
    if strict:
        raise NgsimInputError(
            path, f"{DESCRIPTIONS[first]} (--strict: no row may be dropped)", line=line
        )
    total = sum(bad.values())
    if total > limits.max_dropped_share * rows:
        detail = ", ".join(f"{n:,} {DESCRIPTIONS[reason]}" for reason, n in bad.items())
        raise NgsimInputError(
            path,
            f"{total:,} of {rows:,} rows ({total / rows:.1%}) are implausible, more than the "
            f"{limits.max_dropped_share:.0%} a build drops: {detail}; the first at line {line} "
            "(columns swapped, other units, a damaged file?)",
        )
