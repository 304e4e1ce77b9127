"""A vehicle's motion as its rows show it, and the check of a speed column against it.

Over rows sorted by vehicle and frame, in any one unit of length (NGSIM's feet, highD's metres):
which row is the same vehicle some frames away (`same_vehicle`), how far apart two rows are
(`distance`), and per recording whether the speed column is the speed the positions show
(`speed_comparison`, `speed_medians`, `check_speed_column`): a swapped column or another unit
is an error that names it. A recording's medians are exact and streamed (`streamed_median`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import polars as pl

from ngsim_graphs import budget
from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.contract import RecordingKey, RecordingReport, TracksPart, joined_counts
from ngsim_graphs.sources.limits import PhysicalLimits

SPEED_WINDOW_FRAMES = 5  # each side: the motion a speed is compared with spans 1 s at 10 Hz
MIN_SPEED_ROWS = 100  # fewer rows with a whole window say too little to judge the column


def same_vehicle(shift: int, frames: int) -> pl.Expr:
    """Whether the row `shift` rows away (in a frame sorted by vehicle and frame) is the same
    vehicle exactly `frames` frames away. Plain shifts: far cheaper than window expressions."""
    return (
        (pl.col(s.VEHICLE_ID).shift(shift) == pl.col(s.VEHICLE_ID))
        & ((pl.col(s.FRAME_ID).shift(shift) - pl.col(s.FRAME_ID)).abs() == frames)
    ).fill_null(False)


def distance(x: str, y: str, first: int, second: int = 0) -> pl.Expr:
    """Distance between the positions (`x`, `y`) of the rows `first` and `second` rows away
    (null at the frame's ends)."""
    dx = pl.col(x).shift(first) - pl.col(x).shift(second)
    dy = pl.col(y).shift(first) - pl.col(y).shift(second)
    return (dx * dx + dy * dy).sqrt()


def speed_comparison(
    frame: pl.DataFrame, x: str, y: str, speed: str, frame_period_s: float
) -> pl.DataFrame:
    """How well the `speed` column agrees with the motion the positions (`x`, `y`) show, row by
    row; `frame` sorted by vehicle and frame, `frame_period_s` apart (NGSIM's 0.1 s; highD's
    0.04 s).

    For every row with the same vehicle recorded SPEED_WINDOW_FRAMES frames before and after
    it, the shown speed is the distance between those two positions over their time apart (a
    centred difference: position jitter averages out, steady acceleration does not bias it).
    Returns those rows' "vel" and "shown", in the frame's unit of length per second. A
    vehicle's rows are compared among themselves: the rows of sets of whole vehicles,
    concatenated, are those of all at once."""
    h = SPEED_WINDOW_FRAMES
    whole = same_vehicle(-h, h) & same_vehicle(h, h)
    shown = distance(x, y, -h, h) / (2 * h * frame_period_s)
    compared = frame.select(shown.alias("shown"), pl.col(speed).alias("vel"), whole.alias("whole"))
    return compared.filter(pl.col("whole").fill_null(False)).drop("whole")


def speed_medians(
    compared: pl.DataFrame | pl.LazyFrame, metres_per_unit: float
) -> tuple[float, float, int]:
    """(median |vel - shown speed|, median shown speed, rows compared) in m/s of the rows of
    `speed_comparison` (in units of `metres_per_unit` metres); NaN medians when no row has a
    whole window.

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
    return mismatch * metres_per_unit, speed * metres_per_unit, rows


def joined_report(
    parts: list[TracksPart], key: RecordingKey, metres_per_unit: float
) -> RecordingReport:
    """The report of the recording made of `parts`, before its checks: summed counts, and the
    medians of the speed comparison (the parts' evidence, in units of `metres_per_unit`
    metres) over all its rows, streamed where the evidence is lazy, as a build stages it."""
    evidence = pl.concat([p.evidence.lazy() for p in parts])
    mismatch, shown, compared = speed_medians(evidence, metres_per_unit)
    return replace(
        joined_counts(parts, key),
        speed_mismatch_mps=mismatch,
        shown_speed_mps=shown,
        speed_rows_compared=compared,
    )


def streamed_median(values: pl.LazyFrame) -> float | None:
    """Polars' median of the one column of `values` (nulls left out; None if all are), exactly,
    with no more than `budget.Budget.median_held_values` of them in memory at once where no value is NaN.

    No more values than that: Polars' median of them all, collected. More: the middle values
    (one, or two of an even count) are found by counting the values in bins of a histogram over
    the range they are in, keeping the bin they fall in, until it holds few enough to sort;
    Polars then takes their median, as it would of all the values."""
    column = pl.col(values.collect_schema().names()[0])
    values = values.filter(column.is_not_null())
    count, nans = values.select(pl.len(), column.is_nan().sum()).collect(engine="streaming").row(0)
    if count == 0:
        return None
    # NaN sorts above every number, and few values are held at once: Polars' own median of all.
    if nans or count <= budget.BUDGET.median_held_values:
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
        if count <= budget.BUDGET.median_held_values:
            return values.collect(engine="streaming").to_series().sort()[k]
        # The same expression in every pass: a value falls in the same bin each time.
        n_bins = budget.BUDGET.median_bins
        bins = ((column - low) / (high - low) * n_bins).floor().clip(0, n_bins - 1)
        per_bin = values.group_by(bins.alias("bin")).len().sort("bin").collect(engine="streaming")
        if per_bin.height == 1:  # a range too wide for its bins: no narrowing, every value held
            return values.collect(engine="streaming").to_series().sort()[k]
        before = per_bin["len"].cum_sum() - per_bin["len"]
        at = int((before <= k).sum()) - 1
        k -= int(before[at])
        values = values.filter(bins == per_bin["bin"][at])


def check_speed_column(
    path: str,
    report: RecordingReport,
    limits: PhysicalLimits,
    column: str = "v_Vel",
    units: str = "feet per second",
) -> None:
    """Raise when the speed `column` (in `units`, as the message says) of the recording of
    `report` (its files: `path`) is not the speed the positions show (see speed_comparison)."""
    mismatch_mps, speed_mps, rows = (
        report.speed_mismatch_mps,
        report.shown_speed_mps,
        report.speed_rows_compared,
    )
    allowed = limits.max_speed_mismatch_mps + limits.max_speed_mismatch_share * speed_mps
    if rows >= MIN_SPEED_ROWS and mismatch_mps > allowed:
        raise NgsimInputError(
            path,
            f"{column} disagrees with the vehicles' motion: the median difference from the speed "
            f"their positions show is {mismatch_mps:.1f} m/s over {rows:,} rows (median speed "
            f"{speed_mps:.1f} m/s, {allowed:.1f} allowed); is {column} swapped with another "
            f"column, or in other units than {units}?",
        )
