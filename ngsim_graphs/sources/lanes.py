"""Lateral positions against lanes: a recording whose lateral column is not where its lanes are.

A whole column wrong in every row (highD's y set to 0, NGSIM's Local_X swapped with
Space_Headway) passes every row check: each value looks plausible on its own. Its lanes do not:
the vehicles of a lane drive within that lane. Each lane with enough rows must have its median
lateral position within its band, give or take a lane width; a real recording's medians lie
near the bands' centres, a foot or so off. And a lane is a lane wide: one lane cannot hold
(nearly) every row of a recording whose lateral positions spread over several lanes, as it does
when the lane column is one value in every row (lane 3, whose band holds the road's middle).
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError

LANE_WIDTH_M = 3.7  # NGSIM's lanes are 12 ft; highD's about 3.75 m
MIN_LANE_ROWS = 50  # a lane with fewer rows says too little (5 s of one vehicle at 10 Hz)
LATERAL_M = "__lateral_m"
# NGSIM's main freeway lanes, numbered from the left edge of the road (Local_X = 0): US-101's
# five and its auxiliary lane 6, I-80's six. Ramps (7, 8) and the arterials' turn bays are not
# where their number says, and are left out.
FREEWAY_LOCATIONS = ("us-101", "i-80")
FREEWAY_LANES: dict[int, tuple[float, float]] = {
    lane: ((lane - 1) * LANE_WIDTH_M, lane * LANE_WIDTH_M) for lane in range(1, 7)
}
# One lane holding this share of a recording's rows, whose lateral positions spread over more
# than MAX_LANE_SPREAD_M between these quantiles, is not a lane: a real lane's rows lie within
# about a lane width (lane changes, a few % of them, reach the next), and a real recording's
# busiest lane holds a third of its rows or less.
ONE_LANE_SHARE = 0.9
SPREAD_QUANTILES = (0.05, 0.95)
MAX_LANE_SPREAD_M = 2 * LANE_WIDTH_M
SPREAD_NAMES = "5th and 95th percentiles"  # of SPREAD_QUANTILES, as messages say them


def marked_lanes(
    upper_m: tuple[float, ...], lower_m: tuple[float, ...]
) -> dict[int, tuple[float, float]]:
    """highD's lanes between its markings, in image y (m): laneIds count from the top of the
    image, the edges and the median included, so the upper lanes are 2, 3, ... and the lower
    ones follow after the median's id."""
    upper = {lane: (upper_m[lane - 2], upper_m[lane - 1]) for lane in range(2, len(upper_m) + 1)}
    first = len(upper_m) + 2
    lower = {first + j: (lower_m[j], lower_m[j + 1]) for j in range(len(lower_m) - 1)}
    return upper | lower


def lane_medians(rows: pl.LazyFrame | pl.DataFrame, by: tuple[str, ...] = ()) -> pl.DataFrame:
    """The rows, the median lateral position and its SPREAD_QUANTILES ("low_m", "high_m") of
    each lane (of each group of `by`), in m: `rows` hold LANE_ID and LATERAL_M (m)."""
    lateral = pl.col(LATERAL_M)
    low, high = SPREAD_QUANTILES
    return (
        rows.lazy()
        .drop_nulls([s.LANE_ID, LATERAL_M])
        .group_by(*by, s.LANE_ID)
        .agg(
            pl.len().alias("rows"),
            lateral.median().alias("median_m"),
            lateral.quantile(low).alias("low_m"),
            lateral.quantile(high).alias("high_m"),
        )
        .sort(*by, s.LANE_ID)
        .collect(engine="streaming")
    )


def check_one_lane(
    path: Path | str, recording: str, medians: pl.DataFrame, lane_column: str, column: str
) -> None:
    """Raise naming `path` and `recording` when one lane (of `medians`, from lane_medians, of
    the recording alone) with MIN_LANE_ROWS rows holds ONE_LANE_SHARE of its rows and their
    lateral positions (`column`) spread over more than MAX_LANE_SPREAD_M: the lane column
    (`lane_column`) is one value in (nearly) every row, not the lanes the vehicles drive in."""
    if medians.height == 0:
        return
    total = int(medians["rows"].sum())
    lane, rows, low_m, high_m = (
        medians.sort("rows", s.LANE_ID, descending=[True, False])
        .select(s.LANE_ID, "rows", "low_m", "high_m")
        .row(0)
    )
    spread_m = high_m - low_m
    if rows < max(MIN_LANE_ROWS, ONE_LANE_SHARE * total) or spread_m <= MAX_LANE_SPREAD_M:
        return
    raise NgsimInputError(
        path,
        f"recording {recording}: {lane_column} is {lane} in {rows / total:.1%} of its "
        f"{total:,} rows, whose {column} spread over {spread_m:.1f} m ({spread_m / LANE_WIDTH_M:.1f} "
        f"lane widths: {low_m:.1f} to {high_m:.1f} m, the {SPREAD_NAMES}): "
        f"one lane cannot hold them; is {lane_column} one value in every row, or another "
        "column's?",
    )


def check_lanes(
    path: Path | str,
    recording: str,
    medians: pl.DataFrame,
    bands: dict[int, tuple[float, float]],
    column: str,
) -> None:
    """Raise naming `path` and `recording` when a lane of `bands` with MIN_LANE_ROWS rows has
    its median lateral position (`medians`, from lane_medians) more than a lane width outside
    its band: the `column` the lateral positions come from is not where the lanes are."""
    checked = medians.filter(
        pl.col(s.LANE_ID).is_in(list(bands)) & (pl.col("rows") >= MIN_LANE_ROWS)
    )
    off = [
        (lane, median, bands[lane])
        for lane, median in checked.select(s.LANE_ID, "median_m").iter_rows()
        if not bands[lane][0] - LANE_WIDTH_M <= median <= bands[lane][1] + LANE_WIDTH_M
    ]
    if off:
        lane, median, (low, high) = off[0]
        raise NgsimInputError(
            path,
            f"recording {recording}: its lateral positions are not where its lanes are: "
            f"{len(off)} of {checked.height} lanes have their median {column} more than a lane "
            f"width outside the lane (lane {lane}: {median:.1f} m, the lane at {low:.1f} to "
            f"{high:.1f} m); is {column} another column's, or all one value?",
        )
