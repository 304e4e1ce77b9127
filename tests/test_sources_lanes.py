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
    medians = medians_of({1: [1.0, 2.0, 9.0], 2: [5.0]})
    assert medians.rows() == [(1, 3, 2.0), (2, 1, 5.0)]


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
