"""Recognising recordings (location, period) from frame 0's epoch time, also inside one file."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from conftest import I80_FIRST, US101_FIRST, US101_SECOND, make_row

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import (
    MIN_RECORDING_VEHICLES,
    OFFICIAL_RECORDINGS,
    find_official_recording,
    identify_recordings,
    location_from_path,
    period_label,
    recording_index,
)


def frame_of(rows: list[dict], locations: list[str | None]) -> pl.DataFrame:
    frame = pl.DataFrame(rows, schema=ns.RAW_SCHEMA)
    return frame.with_columns(pl.Series(s.LOCATION, locations, dtype=pl.String))


def test_official_table_times() -> None:
    # 07:50 PDT on 2005-06-15 is 14:50 UTC.
    assert OFFICIAL_RECORDINGS[0].start_epoch_ms == 1118847000000
    assert [r.period for r in OFFICIAL_RECORDINGS if r.location == "i-80"] == [
        "0400-0415", "0500-0515", "0515-0530",
    ]  # fmt: skip


def test_find_official_recording_within_tolerance() -> None:
    start = US101_SECOND.start_epoch_ms
    assert find_official_recording(start - 4 * 60_000) == US101_SECOND
    assert find_official_recording(I80_FIRST.start_epoch_ms + 30 * 60_000) is None  # 16:30
    assert find_official_recording(start, "i-80") is None


def test_period_label_of_unofficial_time() -> None:
    # 2005-06-16 08:28:00 PDT = 15:28 UTC; 9000 frames = 15 minutes.
    assert period_label(1118935680000, 9000) == "0828-0843"


def test_combined_file_separates_periods_with_colliding_vehicle_ids() -> None:
    # Vehicles 1..20 in two us-101 periods (their ids collide), one vehicle of i-80.
    rows = [
        *[
            make_row(v, f, start_ms=US101_FIRST.start_epoch_ms)
            for v in range(1, 21)
            for f in (0, 1)
        ],
        *[make_row(v, 0, start_ms=US101_SECOND.start_epoch_ms) for v in range(1, 21)],
        make_row(5, 0, start_ms=I80_FIRST.start_epoch_ms),
    ]
    index, names = identify_recordings(frame_of(rows, ["us-101"] * 60 + ["i-80"]), Path("x"))
    assert [names[i] for i in index] == [
        *[("us-101", "0750am-0805am")] * 40,
        *[("us-101", "0805am-0820am")] * 20,
        ("i-80", "0400-0415"),
    ]


def test_per_period_file_location_from_time_or_folder() -> None:
    official = frame_of([make_row(1, 0, start_ms=I80_FIRST.start_epoch_ms)], [None])
    assert identify_recordings(official, Path("any.txt"))[1] == [("i-80", "0400-0415")]
    lankershim_ms = 1118935680000  # not one of the six: location from the folder name
    # make_row puts frame 0 seven seconds before start_ms
    other = frame_of([make_row(1, 0, start_ms=lankershim_ms + 7_000)], [None])
    index, names = identify_recordings(other, Path("/data/Lankershim/trajectories.txt"))
    assert index.to_list() == [0] and names == [("lankershim", "0828-0828")]
    with pytest.raises(NgsimInputError, match=r"nowhere\.txt: cannot tell the location"):
        identify_recordings(other, Path("/data/nowhere.txt"))


def test_location_from_path_spellings() -> None:
    assert location_from_path(Path("/d/US-101/vehicle-trajectory-data/x.csv")) == "us-101"
    assert location_from_path(Path("/d/I80/x.txt")) == "i-80"
    assert location_from_path(Path("/d/data/x.txt")) is None


def test_a_row_with_a_stray_global_time_is_dropped_not_its_recording() -> None:
    # 200 rows of us-101 0750am; row 50's Global_Time is 100 ms late: its frame-0 time differs,
    # names the same official period, and holds 1 row: a stray, not a second recording.
    rows = [make_row(1 + f // 100, f % 100) for f in range(200)]
    rows[50] = {**rows[50], s.GLOBAL_TIME: rows[50][s.GLOBAL_TIME] + 100}
    index, names = identify_recordings(frame_of(rows, [None] * 200), Path("t.txt"))
    assert names == [("us-101", "0750am-0805am")]
    assert index.to_list() == [None if i == 50 else 0 for i in range(200)]


def test_stray_times_far_off_need_no_location() -> None:
    # A Global_Time of 0 in a per-period file names no period and no folder tells the location:
    # as a stray it is dropped, where it would otherwise fail the whole file.
    rows = [make_row(1, f) for f in range(200)] + [make_row(2, 3, global_time=0)]
    index, names = identify_recordings(frame_of(rows, [None] * 201), Path("/data/nowhere.txt"))
    assert names == [("us-101", "0750am-0805am")] and index.null_count() == 1


def test_two_large_groups_of_one_period_keep_the_larger() -> None:
    # 60 rows at one frame-0 time, 40 rows 2 s later: both name us-101 0750am. The larger is the
    # recording; the 40 are strays (which the build then refuses as more than a small share).
    rows = [make_row(1, f) for f in range(60)] + [
        make_row(2, f, start_ms=US101_FIRST.start_epoch_ms + 2_000) for f in range(40)
    ]
    index, names = identify_recordings(frame_of(rows, [None] * 100), Path("t.txt"))
    assert names == [("us-101", "0750am-0805am")]
    assert index.to_list() == [0] * 60 + [None] * 40


@pytest.mark.parametrize("vehicles", [19, 20])
def test_a_clock_of_twenty_whole_vehicles_is_a_recording_of_its_own(vehicles: int) -> None:
    # Vehicles 1..30 on one clock, then `vehicles` others 11.7 s later: 20 whole vehicles are a
    # recording of their own (its name suffixed), fewer are stray rows.
    later = US101_FIRST.start_epoch_ms + 11_700
    rows = [make_row(v, f) for v in range(1, 31) for f in range(10)] + [
        make_row(v, f, start_ms=later) for v in range(31, 31 + vehicles) for f in range(10)
    ]
    frame = frame_of(rows, [None] * len(rows))
    index, keys, notes = recording_index(frame.lazy(), Path("t.txt"))
    index = frame.select(index).to_series()
    if vehicles < MIN_RECORDING_VEHICLES:
        assert keys == [("us-101", "0750am-0805am")] and index.null_count() == 10 * vehicles
        return
    assert keys == [("us-101", "0750am-0805am"), ("us-101", "0750am-0805am-2")]
    assert index.to_list() == [0] * 300 + [1] * 200
    assert notes[keys[1]].startswith("us-101/0750am-0805am-2: 20 vehicles (200 rows) keep a ")
    assert "+11.7 s from us-101/0750am-0805am's" in notes[keys[1]]


def test_recordings_are_indexed_by_location_and_time_whatever_their_size() -> None:
    rows = (
        [make_row(v, 0, start_ms=US101_SECOND.start_epoch_ms) for v in range(1, 31)]
        + [make_row(v, 0, start_ms=US101_FIRST.start_epoch_ms) for v in range(1, 21)]
        + [make_row(1, f, start_ms=I80_FIRST.start_epoch_ms) for f in range(20)]
    )
    locations = ["us-101"] * 50 + ["i-80"] * 20
    index, names = identify_recordings(frame_of(rows, locations), Path("p.csv"))
    assert names == [
        ("i-80", "0400-0415"),
        ("us-101", "0750am-0805am"),
        ("us-101", "0805am-0820am"),
    ]
    assert index.to_list() == [2] * 30 + [1] * 20 + [0] * 20


@pytest.mark.parametrize("vehicles", [1, 19, 20])
def test_a_group_beside_the_largest_is_a_recording_only_with_twenty_vehicles(
    vehicles: int,
) -> None:
    # 25 vehicles of us-101 0750am, then `vehicles` others, 10 rows each, on us-101 0805am's
    # clock: far from the first and naming a period of their own, and not small (10 rows of
    # one vehicle are 4 % of the largest), but under 20 vehicles they are stray rows.
    rows = [make_row(v, f) for v in range(1, 26) for f in range(10)] + [
        make_row(v, f, start_ms=US101_SECOND.start_epoch_ms)
        for v in range(101, 101 + vehicles)
        for f in range(10)
    ]
    index, names = identify_recordings(frame_of(rows, [None] * len(rows)), Path("t.txt"))
    if vehicles < MIN_RECORDING_VEHICLES:
        assert names == [("us-101", "0750am-0805am")]
        assert index.to_list() == [0] * 250 + [None] * 10 * vehicles
        return
    assert names == [("us-101", "0750am-0805am"), ("us-101", "0805am-0820am")]
    assert index.to_list() == [0] * 250 + [1] * 200


def test_a_damaged_time_column_is_not_a_thousand_recordings() -> None:
    # Frame-0 times 11 minutes apart: neither near each other nor one of the official periods.
    # Each of one vehicle: stray rows, all but the largest group's (the first row).
    rows = [make_row(1, f, global_time=1_000_000_000_000 + 660_000 * f) for f in range(150)]
    index, names = identify_recordings(frame_of(rows, ["us-101"] * 150), Path("p.csv"))
    assert names == [("us-101", "1846-1846")] and index.to_list() == [0] + [None] * 149
    # 101 groups of 20 vehicles each, as many recordings: too many for one file.
    rows = [
        make_row(v, 0, global_time=1_000_000_000_000 + 660_000 * g)
        for g in range(101)
        for v in range(1, 21)
    ]
    with pytest.raises(NgsimInputError, match=r"p\.csv: more than 100 recordings .*Global_Time"):
        identify_recordings(frame_of(rows, ["us-101"] * len(rows)), Path("p.csv"))


@pytest.mark.parametrize("rows_shifted", [5, 40])
def test_one_vehicle_an_hour_off_is_stray_rows_though_it_names_a_period_of_its_own(
    rows_shifted: int,
) -> None:
    # 2,500 rows of i-80 0400 and one vehicle's record an hour late: it names i-80's 0500-0515,
    # which no larger group names, but one vehicle is no recording, whether its rows are under
    # 1 % of the largest (5) or not (40).
    rows = [
        make_row(v, f, start_ms=I80_FIRST.start_epoch_ms) for v in range(1, 26) for f in range(100)
    ]
    late = I80_FIRST.start_epoch_ms + 3_600_000
    rows += [make_row(26, f, start_ms=late) for f in range(rows_shifted)]
    index, names = identify_recordings(frame_of(rows, [None] * len(rows)), Path("t.txt"))
    assert names == [("i-80", "0400-0415")]
    assert index.to_list() == [0] * 2500 + [None] * rows_shifted


def test_a_small_group_of_twenty_whole_vehicles_naming_a_period_of_its_own_is_a_recording() -> None:
    # 2,500 rows of us-101 0750am and 20 vehicles of 0805am, a row each: under 1 % of the
    # largest, but a clock of twenty whole vehicles of their own.
    rows = [make_row(v, f) for v in range(1, 26) for f in range(100)]
    rows += [make_row(v, 0, start_ms=US101_SECOND.start_epoch_ms) for v in range(101, 121)]
    index, names = identify_recordings(frame_of(rows, ["us-101"] * len(rows)), Path("p.csv"))
    assert names == [("us-101", "0750am-0805am"), ("us-101", "0805am-0820am")]
    assert index.to_list() == [0] * 2500 + [1] * 20


def test_only_usable_rows_form_recordings_but_all_are_placed() -> None:
    rows = [make_row(1, f) for f in range(200)] + [
        make_row(2, f, start_ms=I80_FIRST.start_epoch_ms) for f in range(3)
    ]
    usable = pl.Series(
        [True] * 200 + [False] * 3
    )  # the i-80 rows failed a check: no recording of their own
    index, names = identify_recordings(frame_of(rows, [None] * 203), Path("t.txt"), usable)
    assert names == [("us-101", "0750am-0805am")] and index.to_list() == [0] * 200 + [None] * 3


def test_no_usable_row_places_every_row_in_no_recording() -> None:
    rows = [make_row(1, f) for f in range(3)]
    usable = pl.Series([False] * 3)
    index, names = identify_recordings(frame_of(rows, [None] * 3), Path("t.txt"), usable)
    assert names == [] and index.dtype == pl.UInt16 and index.to_list() == [None] * 3


def test_a_portal_row_is_placed_by_location_and_time_together() -> None:
    # Two locations, a recording each: a row takes the recording of its location and its time
    # together, none for an i-80 row at us-101's time or a row without location at i-80's.
    us, i80 = US101_FIRST.start_epoch_ms, I80_FIRST.start_epoch_ms
    rows = (
        [make_row(1, f, start_ms=us) for f in range(100)]
        + [make_row(2, f, start_ms=i80) for f in range(100)]
        + [make_row(3, 0, start_ms=us), make_row(4, 0, start_ms=i80)]
    )
    locations = ["us-101"] * 100 + ["i-80"] * 100 + ["i-80", None]
    usable = pl.Series([True] * 200 + [False] * 2)
    index, names = identify_recordings(frame_of(rows, locations), Path("p.csv"), usable)
    assert names == [("i-80", I80_FIRST.period), ("us-101", US101_FIRST.period)]
    assert index.to_list() == [1] * 100 + [0] * 100 + [None, None]


@pytest.mark.parametrize("i80_rows", [1, 50])
def test_rows_of_another_location_in_a_file_of_one_are_strays(i80_rows: int) -> None:
    # A per-period file (no Location column) of us-101 0750am with i-80 0400's rows inserted:
    # the file's location is its largest group's, us-101, and the i-80 rows are strays, whether
    # one (under 1 % of the largest) or 50 (which the build then refuses as too many).
    rows = [make_row(1 + f // 100, f % 100) for f in range(1000)]
    rows += [make_row(7, f, start_ms=I80_FIRST.start_epoch_ms) for f in range(i80_rows)]
    index, names = identify_recordings(frame_of(rows, [None] * len(rows)), Path("t.txt"))
    assert names == [("us-101", "0750am-0805am")]
    assert index.to_list() == [0] * 1000 + [None] * i80_rows
