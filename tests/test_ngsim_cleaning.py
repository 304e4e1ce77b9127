"""Incomplete rows, exact and conflicting duplicates, gap splitting, SI conversion."""

from __future__ import annotations

import polars as pl
import pytest
from conftest import make_row

from ngsim_graphs import schema as s
from ngsim_graphs.sources import cleaning
from ngsim_graphs.sources.cleaning import drop_duplicate_rows, split_at_gaps
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import (
    CONFLICT_ORDER,
    FEET_TO_M,
    is_complete,
    to_si_units,
)


def raw(rows: list[dict]) -> pl.DataFrame:
    frame = pl.DataFrame(rows, schema=ns.RAW_SCHEMA)
    return frame.with_columns(pl.lit("us-101").alias(s.LOCATION), pl.lit("p").alias(s.PERIOD))


def test_incomplete_rows_are_those_with_an_empty_required_field() -> None:
    frame = raw([make_row(1, 0), make_row(1, 1, local_x=None), make_row(1, 2, v_acc=None)])
    kept = frame.filter(is_complete())
    assert kept[s.FRAME_ID].to_list() == [0, 2]  # an empty v_Acc is not required


def test_rows_repeat_a_vehicle_and_frame_as_their_struct_says_over_all_of_int32() -> None:
    """The one-Int64 key of (vehicle, frame) finds the same repeated rows as the pair does, at
    int32's ends too (where vehicle * 2**32 + frame alone would leave int64)."""
    ends = [-(2**31), -(2**31) + 1, -1, 0, 1, 2**31 - 1]
    pairs = [(v, f) for v in ends for f in ends]
    frame = pl.DataFrame(
        {s.VEHICLE_ID: [v for v, _ in pairs] * 2, s.FRAME_ID: [f for _, f in pairs] * 2},
        schema={s.VEHICLE_ID: pl.Int32, s.FRAME_ID: pl.Int32},
    ).head(len(pairs) + 7)  # the first seven pairs twice, the rest once
    repeated = frame.select(cleaning._row_key(frame).is_duplicated()).to_series()
    assert repeated.to_list() == [i % len(pairs) < 7 for i in range(frame.height)]


def test_exact_and_conflicting_duplicates() -> None:
    rows = [
        make_row(1, 1),
        make_row(1, 0, local_y_ft=50.0),
        make_row(1, 0, local_y_ft=50.0),  # exact duplicate
        make_row(1, 0, local_y_ft=49.0),  # conflicts: smaller Local_Y wins
        make_row(2, 0, local_y_ft=10.0, local_x_ft=20.0),
        make_row(2, 0, local_y_ft=10.0, local_x_ft=19.0),  # conflicts: tie on y, smaller x wins
    ]
    kept, exact, conflicting = drop_duplicate_rows(raw(rows), CONFLICT_ORDER)
    assert (exact, conflicting) == (1, 2)
    assert kept.select(s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_Y, ns.LOCAL_X).rows() == [
        (1, 0, 49.0, 18.0),
        (1, 1, 100.0, 18.0),
        (2, 0, 10.0, 19.0),
    ]


def test_duplicate_rule_does_not_depend_on_row_order() -> None:
    rows = [
        make_row(v, f, local_y_ft=10.0 * f + d)
        for v in (1, 2)
        for f in range(5)
        for d in (0.0, 0.7, 0.3)
    ]
    forward = drop_duplicate_rows(raw(rows), CONFLICT_ORDER)[0]
    backward = drop_duplicate_rows(raw(rows[::-1]), CONFLICT_ORDER)[0]
    shuffled = drop_duplicate_rows(
        raw(rows).sample(fraction=1.0, shuffle=True, seed=3), CONFLICT_ORDER
    )[0]
    assert forward.equals(backward) and forward.equals(shuffled)
    assert forward[ns.LOCAL_Y].to_list() == [0.0, 10.0, 20.0, 30.0, 40.0] * 2


def test_tracks_split_at_frame_gaps() -> None:
    frames = {1: [0, 1, 2, 5, 6, 9], 2: [3, 4, 5]}
    rows = [make_row(v, f) for v, fs in frames.items() for f in fs]
    segmented, gaps = split_at_gaps(raw(rows))
    assert gaps == 2
    assert segmented[s.SEGMENT].to_list() == [0, 0, 0, 1, 1, 2, 0, 0, 0]


def test_si_units_and_sentinels() -> None:
    rows = [
        make_row(
            1, 3, local_x_ft=10.0, local_y_ft=100.0, v_vel_fps=50.0, v_acc=-2.0, v_length=16.0
        ),
        make_row(1, 4, preceding=7, following=9, space_headway=80.0, time_headway=1.6),
    ]
    frame = raw(rows).with_columns(pl.lit(0, dtype=pl.Int16).alias(s.SEGMENT))
    si = to_si_units(frame)
    first, second = si.row(0, named=True), si.row(1, named=True)
    assert first[s.X_M] == pytest.approx(3.048)
    assert first[s.Y_M] == pytest.approx(30.48)
    assert first[s.SPEED_MPS] == pytest.approx(15.24)
    assert first[s.ACCEL_MPS2] == pytest.approx(-0.6096)
    assert first[s.LENGTH_M] == pytest.approx(16 * FEET_TO_M)
    assert first[s.TIME_S] == pytest.approx(0.3)
    assert (first[s.PRECEDING], first[s.FOLLOWING], first[s.SPACE_HEADWAY_M], first[s.TIME_HEADWAY_S]) == (
        None, None, None, None,
    )  # fmt: skip
    assert (second[s.PRECEDING], second[s.FOLLOWING]) == (7, 9)
    assert second[s.SPACE_HEADWAY_M] == pytest.approx(24.384)
    assert second[s.TIME_HEADWAY_S] == pytest.approx(1.6)
