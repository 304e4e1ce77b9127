"""Physical plausibility of raw rows: each limit, the order of reasons, position outliers and jumps."""

from __future__ import annotations

import polars as pl
from conftest import make_row, straight_track

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.plausibility import (
    LIMITS,
    NgsimDrop,
    jump_rows,
    outlier_rows,
    passes_row_checks,
    row_drop_reason,
)
from ngsim_graphs.sources.ngsim.tracks import build_tracks

FT = 0.3048


def reasons(rows: list[dict]) -> list[str | None]:
    frame = pl.DataFrame(rows, schema=ns.RAW_SCHEMA)
    found = frame.select(row_drop_reason(LIMITS)).to_series().to_list()
    passes = frame.select(passes_row_checks(LIMITS)).to_series().to_list()
    assert passes == [reason is None for reason in found]  # the cheap test, row by row
    return found


def test_each_limit_by_hand() -> None:
    limit_fps = 70.0 / FT  # 229.66 ft/s
    rows = [
        make_row(1, 5),  # fine
        make_row(1, -1),
        make_row(1, 72_001),
        make_row(1, 72_000),  # the last frame allowed
        make_row(0, 5),
        make_row(1, 5, local_y_ft=5_000.0 / FT + 1.0),
        make_row(1, 5, local_x_ft=-(5_000.0 / FT + 1.0)),
        make_row(1, 5, v_vel_fps=-0.01),
        make_row(1, 5, v_vel_fps=1e308),
        make_row(1, 5, v_vel_fps=limit_fps - 0.01),  # just inside
        make_row(1, 5, v_acc=-(15.0 / FT + 0.01)),
        make_row(1, 5, v_acc=None),  # v_Acc is not required: empty is no reason
    ]
    assert reasons(rows) == [
        None,
        DropReason.FRAME_ID.value,
        DropReason.FRAME_ID.value,
        None,
        DropReason.VEHICLE_ID.value,
        DropReason.POSITION.value,
        DropReason.POSITION.value,
        DropReason.SPEED.value,
        DropReason.SPEED.value,
        None,
        DropReason.ACCELERATION.value,
        None,
    ]


def test_the_columns_beside_the_motion_by_hand() -> None:
    longest_ft, widest_ft = 40.0 / FT, 5.0 / FT
    rows = [
        make_row(1, 5, v_length=longest_ft, v_width=widest_ft),  # the largest allowed
        make_row(1, 5, v_length=0.0),
        make_row(1, 5, v_length=1e308),
        make_row(1, 5, v_width=-5.0),
        make_row(1, 5, v_length=None, v_width=None),  # empty: no reason
        make_row(1, 5, lane_id=0),  # arterials number intersections 0
        make_row(1, 5, lane_id=-3),
        make_row(1, 5, lane_id=256),
        make_row(1, 5, v_class=9),
        make_row(1, 5, v_class=0),
        make_row(1, 5, space_headway=-0.01),
        make_row(1, 5, space_headway=5_000.0 / FT + 1.0),
        make_row(1, 5, time_headway=-1e300),
        make_row(1, 5, time_headway=10_000.0),
        make_row(1, 5, preceding=-1),
        make_row(1, 5, following=-7),
        make_row(1, 5, preceding=12, space_headway=80.0, time_headway=1.7),
    ]
    size, lane = DropReason.VEHICLE_SIZE.value, DropReason.LANE.value
    vehicle_class, headway = NgsimDrop.VEHICLE_CLASS.value, DropReason.HEADWAY.value
    assert reasons(rows) == [
        None, size, size, size, None, None, lane, lane, vehicle_class, vehicle_class,
        headway, headway, headway, headway, headway, headway, None,
    ]  # fmt: skip


def test_a_row_counts_under_its_first_failed_check() -> None:
    # Negative frame, zero vehicle, huge speed: the frame check comes first.
    assert reasons([make_row(0, -3, v_vel_fps=1e9)]) == [DropReason.FRAME_ID.value]
    assert reasons([make_row(0, 3, v_vel_fps=1e9)]) == [DropReason.VEHICLE_ID.value]


def _flags(rows: list[dict]) -> tuple[list[bool], list[bool]]:
    frame = pl.DataFrame(rows, schema=ns.RAW_SCHEMA).sort(s.VEHICLE_ID, s.FRAME_ID)
    return outlier_rows(frame, LIMITS).to_list(), jump_rows(frame, LIMITS).to_list()


def test_one_displaced_row_is_an_outlier_wherever_it_is() -> None:
    for bad in (0, 4, 9):  # first, middle, last frame
        rows = straight_track(1, range(10))
        rows[bad] = {**rows[bad], ns.LOCAL_Y: rows[bad][ns.LOCAL_Y] + 3_280.0}  # 1 km away
        outlier, _ = _flags(rows)
        assert outlier == [i == bad for i in range(10)], bad


def test_a_short_displaced_burst_is_an_outlier_a_long_one_a_jump() -> None:
    # Frames 0..29 at 3 ft per frame; frames 10..12 displaced 1 km: three outliers, no jump left.
    # Displaced for 11 frames (10..20), longer than 1 s: two jumps (at 10 and 21), no outlier.
    for last, outliers in ((12, [10, 11, 12]), (20, [])):
        rows = [
            make_row(1, f, local_y_ft=3.0 * f + (3_280.0 if 10 <= f <= last else 0.0))
            for f in range(30)
        ]
        outlier, jump = _flags(rows)
        assert [f for f in range(30) if outlier[f]] == outliers
        assert [f for f in range(30) if jump[f]] == [10, last + 1]  # before any row is dropped
        frame = pl.DataFrame(rows, schema=ns.RAW_SCHEMA)
        _, report = build_tracks(frame, ("us-101", "0750am-0805am"), BuildConfig(), 0)
        assert (report.position_outliers, report.position_jumps) == (
            len(outliers),
            0 if outliers else 2,
        )


def test_a_displaced_rest_of_record_is_a_jump_not_an_outlier() -> None:
    # Frames 0..4 at y = 3 f ft, frames 5..9 one kilometre further: one jump, at frame 5.
    rows = [make_row(1, f, local_y_ft=3.0 * f + (3_280.0 if f >= 5 else 0.0)) for f in range(10)]
    outlier, jump = _flags(rows)
    assert outlier == [False] * 10
    assert jump == [f == 5 for f in range(10)]


def test_jumps_are_checked_within_a_vehicle_and_across_consecutive_frames_only() -> None:
    # Two vehicles 1 km apart; vehicle 2 has a frame gap over which it moved 1 km (no jump: a gap).
    v1 = straight_track(1, range(5))
    v2 = [make_row(2, f, local_y_ft=3_300.0 + (3_280.0 if f > 2 else 0.0)) for f in (0, 1, 2, 6, 7)]
    outlier, jump = _flags(v1 + v2)
    assert outlier == [False] * 10 and jump == [False] * 10


def test_a_threshold_move_is_not_a_jump() -> None:
    step_ft = 10.0 / FT  # exactly the limit
    rows = [make_row(1, f, local_y_ft=step_ft * f) for f in range(4)]
    assert _flags(rows) == ([False] * 4, [False] * 4)


def test_tracks_drop_outliers_and_split_at_jumps() -> None:
    # Vehicle 1, frames 0..19 at 3 ft per frame; frame 8 displaced 1 km (an outlier); from frame
    # 14 on the whole record is 1 km further (a jump): tracks [0..7], [9..13], [14..19].
    rows = [make_row(1, f, local_y_ft=3.0 * f + (3_280.0 if f >= 14 else 0.0)) for f in range(20)]
    rows[8] = {**rows[8], ns.LOCAL_Y: 9_999.0}
    key = ("us-101", "0750am-0805am")
    tracks, report = build_tracks(pl.DataFrame(rows, schema=ns.RAW_SCHEMA), key, BuildConfig(), 0)
    assert (report.rows, report.position_outliers, report.position_jumps, report.gaps) == (
        20,
        1,
        1,
        1,
    )
    assert (report.tracks, report.grid_rows) == (3, 9)  # even frames: 0..6, 10, 12, 14..18
    assert tracks.group_by(s.TRACK_ID, maintain_order=True).agg(pl.col(s.FRAME_ID)).rows() == [
        (0, [0, 2, 4, 6]),
        (1, [10, 12]),
        (2, [14, 16, 18]),
    ]
    assert report.first_outlier is None  # rows without provenance columns
