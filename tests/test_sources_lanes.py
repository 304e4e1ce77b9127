"""Lateral positions against lanes (sources/lanes.py): the rule a recording's lateral column
must pass, with lane medians a person can compute."""

from __future__ import annotations

import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.lanes import (
    FREEWAY_LANES,
    LATERAL_M,
    MIN_LANE_ROWS,
    check_lanes,
    check_one_lane,
    lane_medians,
    marked_lanes,
)


def medians_of(lateral_by_lane: dict[int, list[float]]) -> pl.DataFrame:
    rows = pl.DataFrame(
        {
            s.LANE_ID: [lane for lane, xs in lateral_by_lane.items() for _ in xs],
            LATERAL_M: [x for xs in lateral_by_lane.values() for x in xs],
        },
        schema={s.LANE_ID: pl.Int16, LATERAL_M: pl.Float64},
    )
    return lane_medians(rows)


def test_marked_lanes_number_highd_lanes_from_the_top() -> None:
    # 2 + 2 lanes: upper lanes 2, 3; the median is 4; lower lanes 5, 6.
    assert marked_lanes((8.0, 11.5, 15.0), (18.0, 21.5, 25.0)) == {
        2: (8.0, 11.5), 3: (11.5, 15.0), 5: (18.0, 21.5), 6: (21.5, 25.0),
    }  # fmt: skip


def test_lane_medians_per_lane() -> None:
    # (lane, rows, median, 5th and 95th percentiles, the nearest values) in m.
    medians = medians_of({1: [1.0, 2.0, 9.0], 2: [5.0]})
    assert medians.rows() == [(1, 3, 2.0, 1.0, 9.0), (2, 1, 5.0, 5.0, 5.0)]


def test_lanes_near_their_bands_pass() -> None:
    # Lane k's vehicles around (k - 0.5) * 3.7 m, some wandering a lane off: the medians stay.
    xs = {
        k: [(k - 0.5) * 3.7 + d for d in (-0.8, 0.3, 0.0, 4.0)] * MIN_LANE_ROWS for k in (1, 2, 6)
    }
    check_lanes("a.txt", "us-101/0750am-0805am", medians_of(xs), FREEWAY_LANES, "Local_X")
    # A lane median just within a lane width beyond its band (lane 1: 0..3.7 m, up to 7.4 m).
    check_lanes("a.txt", "r", medians_of({1: [7.3] * MIN_LANE_ROWS}), FREEWAY_LANES, "Local_X")


def test_a_lane_median_beyond_a_lane_width_is_refused() -> None:
    xs = {1: [1.8] * MIN_LANE_ROWS, 2: [7.5] * MIN_LANE_ROWS, 3: [30.0] * MIN_LANE_ROWS}
    with pytest.raises(
        NgsimInputError,
        match=r"a\.txt: recording us-101/0750am-0805am: .* 1 of 3 lanes have their median "
        r"Local_X more than a lane width outside the lane \(lane 3: 30\.0 m, the lane at 7\.4 "
        r"to 11\.1 m\)",
    ):
        check_lanes("a.txt", "us-101/0750am-0805am", medians_of(xs), FREEWAY_LANES, "Local_X")


def test_few_rows_and_lanes_without_a_band_are_not_judged() -> None:
    xs = {1: [30.0] * (MIN_LANE_ROWS - 1), 7: [90.0] * MIN_LANE_ROWS, 11: [0.0] * 500}
    check_lanes("a.txt", "r", medians_of(xs), FREEWAY_LANES, "Local_X")


def test_one_lane_of_every_row_spread_over_the_road_is_refused() -> None:
    # 100 rows, Local_X 1..20 m in steps of about 0.19 m, every one in lane 3: its 5th and 95th
    # percentiles (nearest) 1.96 and 19.04 m, 17.1 m apart (4.6 lane widths).
    xs = [1.0 + 19.0 * i / 99 for i in range(100)]
    with pytest.raises(
        NgsimInputError,
        match=r"a\.txt: recording r: Lane_ID is 3 in 100\.0% of its 100 rows, whose Local_X "
        r"spread over 17\.1 m \(4\.6 lane widths: 2\.0 to 19\.0 m, the 5th and 95th percentiles\)",
    ):
        check_one_lane("a.txt", "r", medians_of({3: xs}), "Lane_ID", "Local_X")
    # 90 of 100 rows in one lane: refused too; 89 of them, a lane of a two-lane road: not.
    with pytest.raises(NgsimInputError, match=r"Lane_ID is 0 in 90\.0% of its 100 rows"):
        check_one_lane("a.txt", "r", medians_of({0: xs[:90], 2: xs[90:]}), "Lane_ID", "Local_X")
    check_one_lane("a.txt", "r", medians_of({0: xs[:89], 2: xs[89:]}), "Lane_ID", "Local_X")


def test_one_lane_of_every_row_within_a_lane_or_two_passes() -> None:
    # A one-lane road (all rows within 7.4 m, two lane widths), a road of lanes with their own
    # rows, too few rows, no rows: nothing to say.
    check_one_lane(
        "a.txt",
        "r",
        medians_of({1: [0.5 + 7.4 * i / 99 for i in range(100)]}),
        "Lane_ID",
        "Local_X",
    )
    lanes = {lane: [3.7 * lane - 1.85 + 0.01 * i for i in range(100)] for lane in range(1, 6)}
    check_one_lane("a.txt", "r", medians_of(lanes), "Lane_ID", "Local_X")
    few = [float(i) for i in range(MIN_LANE_ROWS - 1)]
    check_one_lane("a.txt", "r", medians_of({3: few}), "Lane_ID", "Local_X")
    check_one_lane("a.txt", "r", medians_of({}), "Lane_ID", "Local_X")
