"""The realism report's statistics of tracks tables, each worked out by hand on tiny tables."""

from __future__ import annotations

from statistics import pstdev

import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.realism import ALL, densities, noise_measures, realism, step_values

DT = 0.2


def tracks(rows: list[tuple]) -> pl.LazyFrame:
    """(location, period, track, step, x, y, speed, acceleration, lane, space headway, time
    headway) rows."""
    names = (s.LOCATION, s.PERIOD, s.TRACK_ID, "step", s.X_M, s.Y_M, s.SPEED_MPS, s.ACCEL_MPS2,
             s.LANE_ID, s.SPACE_HEADWAY_M, s.TIME_HEADWAY_S)  # fmt: skip
    frame = pl.DataFrame(rows, schema=names, orient="row")
    return frame.lazy().with_columns((pl.col("step") * DT).alias(s.TIME_S)).drop("step")


# us-101: one track of five steps, one lane change; i-80: one track of three steps, two slow.
ROWS = [
    ("us-101", "p", 1, 0, 1.0, 0.0, 10.0, 0.0, 1, 20.0, 2.0),
    ("us-101", "p", 1, 1, 1.1, 2.0, 11.0, 3.5, 1, None, None),
    ("us-101", "p", 1, 2, 1.1, 5.0, 13.0, 1.0, 2, 22.0, 1.7),
    ("us-101", "p", 1, 3, 1.3, 8.0, 13.0, 0.0, 2, 24.0, 1.8),
    ("us-101", "p", 1, 4, 1.3, 10.0, 12.0, -3.0, 2, 26.0, 2.1),
    ("i-80", "q", 7, 10, 5.0, 0.0, 4.0, 0.0, 3, None, None),
    ("i-80", "q", 7, 11, 5.0, 1.0, 4.0, 0.5, 3, None, None),
    ("i-80", "q", 7, 12, 5.0, 3.0, 6.0, 0.5, 3, None, None),
]


def test_step_values_by_hand() -> None:
    # In any order: the rows of a track are taken in time order.
    values = step_values(tracks(ROWS[::-1]), DT).filter(pl.col(s.LOCATION) == "us-101")
    assert values["speed_change_mps2"].to_list()[1:] == pytest.approx([5.0, 10.0, 0.0, -5.0])
    assert values["speed_change_mps2"][0] is None
    # The recorded acceleration 0, 3.5, 1, 0, -3 changes by 3.5, -2.5, -1, -3 per 0.2 s.
    assert values["jerk_mps3"].to_list()[1:] == pytest.approx([17.5, -12.5, -5.0, -15.0])
    assert values["lateral_speed_mps"].to_list()[1:] == pytest.approx([0.5, 0.0, 1.0, 0.0])
    assert values["lane_change"].to_list() == [None, False, True, False, False]


def test_density_by_hand() -> None:
    # us-101: y spans 10 m, lanes 1 (2 rows) and 2 (3 rows): 1 vehicle / (0.01 km * 2 lanes).
    # i-80: y spans 3 m, one lane: 1 / 0.003.
    density = densities(tracks(ROWS), DT).sort(s.LOCATION)
    assert density["density_veh_per_km_lane"].to_list() == pytest.approx(
        [1 / 0.003] * 3 + [50.0] * 5
    )


def test_a_lane_of_few_rows_is_not_a_lane_of_the_section() -> None:
    # 99 rows in lane 1 and one in lane 2 (1 %, under 2 %): one lane.
    rows = [
        ("us-101", "p", t, 0, 1.0, float(t), 10.0, 0.0, 1 if t else 2, None, None)
        for t in range(100)
    ]
    [density] = densities(tracks(rows), DT)["density_veh_per_km_lane"].to_list()
    assert density == pytest.approx(100 / 0.099)


def test_rates_and_distributions_by_hand() -> None:
    found = realism(tracks(ROWS), DT)
    assert set(found) == {"us-101", "i-80", ALL}
    us101, i80, every = found["us-101"], found["i-80"], found[ALL]
    # One lane change in 5 rows of 0.2 s: 1 s of a vehicle's time, 1/60 min.
    assert us101.lane_changes_per_vehicle_minute == pytest.approx(60.0)
    assert every.lane_changes_per_vehicle_minute == pytest.approx(1 / (8 * DT / 60))
    assert (us101.slow_share, i80.slow_share, every.slow_share) == (0.0, 2 / 3, 2 / 8)
    speed = us101.distributions["speed_mps"]
    assert (speed.count, speed.mean, speed.min, speed.max) == (5, 11.8, 10.0, 13.0)
    change = every.distributions["speed_change_mps2"]  # us-101's 5, 10, 0, -5; i-80's 0, 10
    assert (change.count, change.mean) == (6, pytest.approx(20 / 6))
    # |acceleration| > 3: us-101's 3.5 (not -3); per track, |jerk| > 15: 1 of 4 steps, 0 of 2.
    assert (us101.hard_accel_share, every.hard_accel_share) == (0.2, 1 / 8)
    assert (us101.hard_jerk_track_share, every.hard_jerk_track_share) == (0.25, 0.125)
    headway = us101.distributions["time_headway_s"]  # no leader: no value
    assert (headway.count, headway.p50) == (4, pytest.approx(1.9))
    assert i80.distributions["space_headway_m"].count == 0


def noisy_tracks(rows: list[tuple]) -> pl.LazyFrame:
    """(location, period, track, step, x, speed, lane, heading) rows."""
    names = (s.LOCATION, s.PERIOD, s.TRACK_ID, "step", s.X_M, s.SPEED_MPS, s.LANE_ID, s.HEADING_RAD)
    frame = pl.DataFrame(rows, schema=names, orient="row")
    return frame.lazy().with_columns((pl.col("step") * DT).alias(s.TIME_S)).drop("step")


# us-101/p: track 1 of four steps (a lane change), track 2 of two; i-80/q: track 7 of three.
NOISY_ROWS = [
    ("us-101", "p", 1, 0, 1.0, 10.0, 1, 0.0),
    ("us-101", "p", 1, 1, 1.1, 11.0, 1, 0.1),
    ("us-101", "p", 1, 2, 1.1, 13.0, 2, -0.1),
    ("us-101", "p", 1, 3, 1.3, 13.0, 2, 0.0),
    ("us-101", "p", 2, 0, 5.0, 4.0, 3, 0.2),
    ("us-101", "p", 2, 1, 5.0, 6.0, 3, 0.2),
    ("i-80", "q", 7, 5, 5.0, 4.0, 3, 0.0),
    ("i-80", "q", 7, 6, 5.0, 4.0, 3, 0.0),
    ("i-80", "q", 7, 7, 5.0, 6.0, 3, 0.0),
]


def test_noise_measures_by_hand() -> None:
    # Shuffled: rows are taken per track in time order, never differenced across two tracks.
    found = noise_measures(noisy_tracks(NOISY_ROWS[::-1]), DT)
    assert list(found) == ["i-80/q", "us-101/p", ALL]
    us101, i80, every = found["us-101/p"], found["i-80/q"], found[ALL]
    # Acceleration (v[t+1] - v[t]) / 0.2: track 1's 1, 2, 0 m/s per step, track 2's 2; i-80's 0, 2.
    assert us101.accel_std_mps2 == pytest.approx(pstdev([5.0, 10.0, 0.0, 10.0]))
    assert every.accel_std_mps2 == pytest.approx(pstdev([5.0, 10.0, 0.0, 10.0, 0.0, 10.0]))
    # Jerk (v[t+1] - 2 v[t] + v[t-1]) / 0.04: track 1's (13 - 22 + 10) and (13 - 26 + 11); track 2
    # has no step with a neighbour on both sides; i-80's (6 - 8 + 4).
    assert us101.jerk_std_mps3 == pytest.approx(pstdev([25.0, -50.0]))  # 37.5
    assert i80.jerk_std_mps3 == 0.0  # one value
    assert every.jerk_std_mps3 == pytest.approx(pstdev([25.0, -50.0, 50.0]))
    # Lateral acceleration from x: track 1's (1.1 - 2.2 + 1.0) / 0.04 and (1.3 - 2.2 + 1.1) / 0.04.
    assert us101.lateral_accel_std_mps2 == pytest.approx(3.75)
    assert every.lateral_accel_std_mps2 == pytest.approx(pstdev([-2.5, 5.0, 0.0]))
    # Heading: every row's value.
    assert us101.heading_std_rad == pytest.approx(pstdev([0.0, 0.1, -0.1, 0.0, 0.2, 0.2]))
    assert every.heading_std_rad == pytest.approx(pstdev([0.0, 0.1, -0.1, 0.0, 0.2, 0.2, 0, 0, 0]))
    # One lane change in 3 + 1 consecutive pairs; none in i-80's 2.
    assert (us101.lane_changes_per_track_step, i80.lane_changes_per_track_step) == (0.25, 0.0)
    assert every.lane_changes_per_track_step == pytest.approx(1 / 6)
    assert (us101.rows, i80.rows, every.rows) == (6, 3, 9)


def test_noise_measures_of_single_rows_are_none() -> None:
    found = noise_measures(noisy_tracks(NOISY_ROWS[:1]), DT)
    assert found["us-101/p"] == found[ALL]
    alone = found[ALL]
    assert alone.heading_std_rad == 0.0
    assert (alone.jerk_std_mps3, alone.accel_std_mps2, alone.lateral_accel_std_mps2) == (None,) * 3
    assert alone.lane_changes_per_track_step is None
