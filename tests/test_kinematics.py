"""Heading on straight, lane-changing and stopped tracks, against hand-computed values."""

from __future__ import annotations

import math

import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.kinematics import add_heading


def track(xs: list[float], ys: list[float], speeds: list[float], track_id: int = 0) -> pl.DataFrame:
    return pl.DataFrame(
        {s.TRACK_ID: [track_id] * len(xs), s.X_M: xs, s.Y_M: ys, s.SPEED_MPS: speeds}
    )


def headings(frame: pl.DataFrame, window: int = 1, min_speed: float = 2.0) -> list[float]:
    return add_heading(frame, window, min_speed)[s.HEADING_RAD].to_list()


def test_straight_along_y_is_zero_and_positions_untouched() -> None:
    frame = track([1.0] * 5, [0.0, 2.0, 4.0, 6.0, 8.0], [10.0] * 5)
    out = add_heading(frame, 5, 2.0)
    assert out[s.HEADING_RAD].to_list() == [0.0] * 5
    assert out[s.X_M].to_list() == frame[s.X_M].to_list()


def test_lane_change_heading_is_atan2_dx_dy_and_first_step_copies_next() -> None:
    # Unsmoothed (window 1): moves of (0, 2), (0.5, 2), (0.5, 2), (0, 2).
    frame = track([0.0, 0.0, 0.5, 1.0, 1.0], [0.0, 2.0, 4.0, 6.0, 8.0], [10.0] * 5)
    expected_turn = math.atan2(0.5, 2.0)
    assert headings(frame) == pytest.approx([0.0, 0.0, expected_turn, expected_turn, 0.0])


def test_lane_change_to_the_left_is_negative() -> None:
    frame = track([3.0, 3.0, 2.0], [0.0, 2.0, 4.0], [10.0] * 3)
    assert headings(frame) == pytest.approx([0.0, 0.0, math.atan2(-1.0, 2.0)])


def test_smoothing_is_a_centred_moving_average_shrinking_symmetrically() -> None:
    # Window 3 on a jitter spike at step 2. The radius is 0 at both ends, 1 inside:
    # smoothed x = [0, 1/3, 1/3, 1/3, 0]; the linear y is kept exactly.
    frame = track([0.0, 0.0, 1.0, 0.0, 0.0], [0.0, 2.0, 4.0, 6.0, 8.0], [10.0] * 5)
    turn = math.atan2(1 / 3, 2.0)
    assert headings(frame, window=3) == pytest.approx([turn, turn, 0.0, 0.0, -turn])


def test_steady_lane_change_keeps_its_heading_up_to_the_track_ends() -> None:
    xs = [0.3 * k for k in range(8)]
    ys = [2.0 * k for k in range(8)]
    assert headings(track(xs, ys, [10.0] * 8), window=5) == pytest.approx(
        [math.atan2(0.3, 2.0)] * 8
    )


def test_stopped_vehicle_holds_last_heading() -> None:
    # Moves right-forward, then stops and jitters sideways: heading must hold.
    xs = [0.0, 1.0, 2.0, 2.3, 1.9, 2.1]
    ys = [0.0, 1.0, 2.0, 2.0, 2.0, 2.0]
    speeds = [5.0, 5.0, 5.0, 0.1, 0.0, 0.2]
    assert headings(track(xs, ys, speeds)) == pytest.approx([math.pi / 4] * 6)


def test_track_starting_stopped_takes_first_moving_heading_and_never_moving_is_zero() -> None:
    start_stopped = track([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.5, 5.0])
    assert headings(start_stopped) == pytest.approx([math.pi / 4] * 4)
    parked = track([0.0, 0.3, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.0], track_id=1)
    assert headings(parked) == [0.0, 0.0, 0.0]


def test_tracks_do_not_leak_into_each_other() -> None:
    a = track([0.0, 0.0], [0.0, 2.0], [10.0, 10.0], track_id=0)
    b = track([5.0, 6.0], [0.0, 1.0], [10.0, 10.0], track_id=1)
    assert headings(pl.concat([a, b]), window=3) == pytest.approx(
        [0.0, 0.0, math.pi / 4, math.pi / 4]
    )
