"""One recording's raw rows to its tracks table; one file's rows split by recording."""

from __future__ import annotations

import math
from pathlib import Path

import polars as pl
import pytest
from conftest import US101_FIRST, US101_SECOND, make_row, set_budget, straight_track, write_portal
from polars.testing import assert_frame_equal

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.sources.ngsim import files
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M
from ngsim_graphs.sources.ngsim.plausibility import LIMITS
from ngsim_graphs.sources.ngsim.tracks import (
    build_tracks,
    read_file_recordings,
    vehicle_tracks,
)
from ngsim_graphs.sources.speeds import joined_report

KEY = ("us-101", "0750am-0805am")


def raw(rows: list[dict]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema=ns.RAW_SCHEMA)


def test_tracks_of_one_recording_by_hand() -> None:
    # Vehicle 4: frames 1..9 with 6 and 7 missing (a gap): tracks {2, 4} and {8}.
    # Vehicle 9: frames 0..4, shuffled and with one exact duplicate: track {0, 2, 4}.
    v4 = [make_row(4, f, local_y_ft=10.0 * f) for f in (1, 2, 3, 4, 5, 8, 9)]
    v9 = [make_row(9, f, local_x_ft=12.0, local_y_ft=5.0 * f) for f in (3, 0, 4, 2, 1, 2)]
    tracks, report = build_tracks(raw(v4 + v9), KEY, BuildConfig(), first_track_id=100)
    assert tracks.schema == s.TRACKS_SCHEMA
    assert tracks.select(s.TRACK_ID, s.VEHICLE_ID, s.SEGMENT, s.FRAME_ID).rows() == [
        (100, 4, 0, 2),
        (100, 4, 0, 4),
        (101, 4, 1, 8),
        (102, 9, 0, 0),
        (102, 9, 0, 2),
        (102, 9, 0, 4),
    ]
    assert tracks[s.Y_M].to_list() == pytest.approx([6.096, 12.192, 24.384, 0.0, 3.048, 6.096])
    assert tracks[s.HEADING_RAD].to_list() == [0.0] * 6
    assert (report.rows, report.exact_duplicates, report.conflicting_duplicates) == (13, 1, 0)
    assert (report.gaps, report.vehicles, report.tracks, report.grid_rows) == (1, 2, 3, 6)


def test_heading_follows_a_lane_change_on_the_grid() -> None:
    # 1 ft/frame sideways, 3 ft/frame forward: on the 0.2 s grid (2, 6) ft per step.
    rows = [make_row(1, f, local_x_ft=10.0 + f, local_y_ft=3.0 * f) for f in range(0, 21)]
    tracks, _ = build_tracks(raw(rows), KEY, BuildConfig(), first_track_id=0)
    assert tracks.height == 11
    assert tracks[s.HEADING_RAD].to_list() == pytest.approx([math.atan2(1.0, 3.0)] * 11)


def twenty_vehicles(frames: int, start_ms: int) -> list[dict[str, float]]:
    """Vehicles 1..20 at frames 0..`frames` - 1 of the recording starting at `start_ms`: as
    few as a recording beside a larger one holds."""
    return [r for v in range(1, 21) for r in straight_track(v, range(frames), start_ms=start_ms)]


def test_file_rows_split_by_recording(tmp_path: Path) -> None:
    first = twenty_vehicles(4, US101_FIRST.start_epoch_ms)
    second = twenty_vehicles(2, US101_SECOND.start_epoch_ms)
    path = write_portal(tmp_path / "p.csv", second + first + [make_row(3, 9, local_x=None)])
    read = read_file_recordings(path, BuildConfig())
    report = read.report
    assert sorted(read.recordings) == [("us-101", "0750am-0805am"), ("us-101", "0805am-0820am")]
    first = read.recording_rows(("us-101", "0750am-0805am")).collect()
    assert first.columns == [*ns.RAW_SCHEMA.names(), *s.PROVENANCE_SCHEMA.names()]
    assert first.height == 80
    assert read.recording_rows(("us-101", "0805am-0820am")).collect().height == 40
    assert (report.rows_read, report.rows_missing_values, report.raw_format) == (121, 1, "portal")
    assert report.recordings == ("us-101/0750am-0805am", "us-101/0805am-0820am")


def test_rows_read_through_a_scratch_file_are_the_rows_read_in_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With a scratch folder the text is parsed a chunk at a time (here of 2,000 bytes: a dozen
    lines) into files there, scanned back: the same rows of each recording, in the same order,
    and the same report, dropped rows and all."""
    set_budget(monkeypatch, text_chunk_bytes=2000)
    first = twenty_vehicles(4, US101_FIRST.start_epoch_ms)
    second = twenty_vehicles(3, US101_SECOND.start_epoch_ms)
    bad = [make_row(3, 9, local_x=None), make_row(4, 2, v_vel_fps=-5.0)]
    path = write_portal(tmp_path / "p.csv", second + bad + first)
    in_memory = read_file_recordings(path, BuildConfig(), 2)
    scanned = read_file_recordings(path, BuildConfig(), 2, tmp_path / "scratch")
    assert (
        len(list((tmp_path / "scratch").glob(f"{files.PARSED_STEM}-*.{files.PARSED_SUFFIX}"))) > 2
    )
    assert scanned.report == in_memory.report
    assert scanned.report.rows_missing_values == 1 and sum(scanned.report.rows_dropped.values())
    assert scanned.recordings == in_memory.recordings
    for key in in_memory.recordings:
        rows = scanned.recording_rows(key).collect()
        assert rows.height in (60, 80)
        assert_frame_equal(rows, in_memory.recording_rows(key).collect())


def test_a_recording_cleaned_a_part_of_its_vehicles_at_a_time_is_cleaned_alike() -> None:
    """Vehicle 1: an outlier (frame 8, whose drop leaves a gap) and a jump (from frame 20);
    vehicle 2: an exact and a conflicting duplicate and a gap; vehicle 3 at another speed, so
    that the rows compared for speed are an even number: a median between two rows. In parts
    {1, 2}, {3} (numbered on from the first part's tracks) the tracks and every count of the
    report are those of all three at once, the medians too."""
    v1 = [make_row(1, f, local_y_ft=3.0 * f + (3_280.0 if f >= 20 else 0.0)) for f in range(30)]
    v1[8] = {**v1[8], ns.LOCAL_Y: 9_999.0}
    v2 = [make_row(2, f, local_x_ft=30.0, local_y_ft=2.5 * f) for f in (*range(12), *range(15, 27))]
    v2 += [v2[3], {**v2[5], ns.V_VEL: 31.0}]
    v3 = [make_row(3, f, local_y_ft=4.0 * f, v_vel_fps=39.0 + f % 3) for f in range(23)]
    rows = raw(v1 + v2 + v3).with_columns(
        pl.lit(0, pl.UInt16).alias(s.SOURCE_FILE),
        (pl.int_range(pl.len(), dtype=pl.Int64) + 2)
        .cast(s.PROVENANCE_SCHEMA[s.SOURCE_LINE])
        .alias(s.SOURCE_LINE),
    )
    config = BuildConfig()
    whole, report = build_tracks(rows, KEY, config, first_track_id=0)
    assert report.position_outliers == 1 and report.position_jumps == 1
    assert (report.exact_duplicates, report.conflicting_duplicates, report.gaps) == (1, 1, 2)
    assert report.speed_rows_compared % 2 == 0 and report.first_outlier == (0, 10)

    by_vehicle = rows.partition_by(s.VEHICLE_ID, as_dict=True)
    first = vehicle_tracks(pl.concat([by_vehicle[(2,)], by_vehicle[(1,)]]), KEY, config, LIMITS, 0)
    second = vehicle_tracks(by_vehicle[(3,)], KEY, config, LIMITS, first.report.tracks)
    assert (first.report.tracks, second.report.tracks) == (5, 1)
    assert joined_report([first, second], KEY, FEET_TO_M) == report
    assert_frame_equal(pl.concat([first.tracks, second.tracks]), whole)
