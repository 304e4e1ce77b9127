"""highD rows to the tracks table: the road frame of both directions, the grid by frame number,
cleaning, the drop rules, detection and the build's inputs. Values computed by hand from the
fixtures (see highd_fixtures: markings 8.0/11.5/15.0 above the median, 18.0/21.5/25.0 below).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import polars as pl
import pytest
from highd_fixtures import (
    LONG,
    TWO_DIRECTIONS,
    track_rows,
    two_directions,
    two_directions_rows,
    write_recording,
)
from test_cli_ngsim import assert_failed_cleanly, error_line, invoke, snapshot

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.cleaning import DESCRIPTIONS
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.geometry import LIMITS
from ngsim_graphs.sources.highd.tracks import build_tracks, read_file
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M
from ngsim_graphs.sources.registry import check_locations, choose_source

KEY = ("highd-2", "01")
DEFAULT = BuildConfig()


def tracks_of(tracks_file: Path, config: BuildConfig = DEFAULT) -> tuple[pl.DataFrame, object]:
    read = read_file(tracks_file, config, LIMITS, 0, False)
    return build_tracks(read.recording_rows(KEY).collect(), KEY, config, 0)


def test_front_centre_in_both_directions(tmp_path: Path) -> None:
    tracks, report = tracks_of(two_directions(tmp_path))
    first = tracks.filter(pl.col(s.FRAME_ID) == 5).sort(s.VEHICLE_ID)
    # Vehicle 1, lower lanes (+x): box x = 104 at frame 5, 4 m long: front y = 108; centre
    # y = 19 + 2 / 2 = 20 is 2 m right of the marking at 18.
    # Vehicle 2, upper lanes (-x): box x = 396 is its front: y = 2000 - 396; centre 12 + 1 = 13
    # is 2 m right of (above) the marking at 15.
    assert first.select(s.X_M, s.Y_M).rows() == [(2.0, 108.0), (2.0, 1604.0)]
    assert first[s.HEADING_RAD].to_list() == [0.0, 0.0]
    assert first[s.SPEED_MPS].to_list() == [25.0, 25.0]
    assert first.select(s.LENGTH_M, s.WIDTH_M).rows() == [(4.0, 2.0), (5.0, 2.0)]
    assert (report.vehicles, report.tracks, report.gaps) == (2, 2, 0)


def test_the_grid_keeps_every_fifth_frame_by_number(tmp_path: Path) -> None:
    rows = track_rows(1, range(6, 10), x0=100.0, y=19.0, x_velocity=25.0)  # no frame % 5 == 0
    rows += track_rows(3, range(3, 13), x0=100.0, y=22.5, x_velocity=25.0, laneId=6)
    tracks, report = tracks_of(write_recording(tmp_path, rows, {1: ("Car", 2), 3: ("Car", 2)}))
    assert tracks.select(s.VEHICLE_ID, s.FRAME_ID, s.TIME_S, s.GLOBAL_TIME).rows() == [
        (3, 5, 0.2, 200), (3, 10, 0.4, 400),
    ]  # fmt: skip
    assert tracks[s.Y_M].to_list() == [106.0, 111.0]  # x = 100 + (frame - 3), + 4 m of length
    assert report.grid_rows == 2 and report.rows == 14


def test_a_left_lane_change_lowers_x_in_both_directions(tmp_path: Path) -> None:
    lower = track_rows(1, range(1, 101), x0=100.0, y=22.0, x_velocity=25.0, laneId=6)
    upper = track_rows(2, range(1, 101), x0=400.0, y=9.0, x_velocity=-25.0, laneId=2)
    for i, (a, b) in enumerate(zip(lower, upper, strict=True)):
        a[hs.HIGHD_Y] = 22.0 - 0.02 * i  # up the image: towards the median above the lower lanes
        b[hs.HIGHD_Y] = 9.0 + 0.02 * i  # down the image: towards the median below the upper lanes
    tracks, _ = tracks_of(write_recording(tmp_path, lower + upper, {1: ("Car", 2), 2: ("Car", 1)}))
    for vehicle in (1, 2):
        one = tracks.filter(pl.col(s.VEHICLE_ID) == vehicle)
        assert (one[s.X_M].diff().drop_nulls() < 0).all()
        # 0.1 m to the left per 5 m along travel
        assert one[s.HEADING_RAD].to_list() == pytest.approx([math.atan2(-0.1, 5.0)] * one.height)


def test_lanes_classes_neighbours_and_headways_are_kept(tmp_path: Path) -> None:
    rows = track_rows(
        1, range(1, 11), x0=130.0, y=19.0, x_velocity=25.0, dhw=26.0, thw=1.04, precedingId=3
    )
    rows += track_rows(3, range(1, 11), x0=160.0, y=19.0, x_velocity=25.0, followingId=1)
    rows += track_rows(
        2, range(1, 11), x0=400.0, y=12.0, x_velocity=-20.0, xAcceleration=-1.5, laneId=3
    )
    tracks, _ = tracks_of(
        write_recording(tmp_path, rows, {1: ("Car", 2), 2: ("Truck", 1), 3: ("Car", 2)})
    )
    at_5 = tracks.filter(pl.col(s.FRAME_ID) == 5).sort(s.VEHICLE_ID)
    columns = (s.VEHICLE_ID, s.LANE_ID, s.V_CLASS, s.PRECEDING, s.FOLLOWING, s.SPACE_HEADWAY_M,
               s.TIME_HEADWAY_S, s.SPEED_MPS, s.ACCEL_MPS2)  # fmt: skip
    assert at_5.select(columns).rows() == [
        (1, 5, 2, 3, None, 26.0, 1.04, 25.0, 0.0),
        (2, 3, 3, None, None, None, None, 20.0, 1.5),  # -1.5 m/s^2 along -x: speeding up
        (3, 5, 2, None, 1, None, None, 25.0, 0.0),
    ]


def test_a_frame_gap_splits_the_track(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 21), x0=100.0, y=19.0, x_velocity=25.0)
    rows += track_rows(1, range(31, 51), x0=130.0, y=19.0, x_velocity=25.0)
    tracks, report = tracks_of(write_recording(tmp_path, rows, {1: ("Car", 2)}))
    assert report.gaps == 1 and report.tracks == 2
    assert tracks.group_by(s.SEGMENT, s.TRACK_ID).agg(pl.col(s.FRAME_ID)).sort(s.SEGMENT).rows() == [
        (0, 0, [5, 10, 15, 20]), (1, 1, [35, 40, 45, 50]),
    ]  # fmt: skip


def test_duplicates_are_dropped_and_counted(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 11), x0=100.0, y=19.0, x_velocity=25.0)
    conflict = dict(rows[4], x=150.0)  # frame 5 again, 50 m further: the smaller y_m is kept
    rows = [*rows, dict(rows[9]), conflict]  # frame 10 twice, exactly
    tracks, report = tracks_of(write_recording(tmp_path, rows, {1: ("Car", 2)}))
    assert (report.exact_duplicates, report.conflicting_duplicates) == (1, 1)
    assert tracks[s.Y_M].to_list() == [108.0, 113.0]


def test_rows_beyond_the_limits_are_dropped_counted_and_reported(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 201), x0=100.0, y=19.0, x_velocity=25.0)
    rows[9][hs.HIGHD_X_VELOCITY] = 90.0  # line 11: beyond 70 m/s
    rows[19][hs.HIGHD_X] = ""  # line 21: an empty required field
    path = write_recording(tmp_path, rows, {1: ("Car", 2)})
    report = read_file(path, BuildConfig(), LIMITS, 0, False).report
    assert report.rows_dropped[DropReason.SPEED.value] == 1
    assert report.first_dropped_line == {DropReason.SPEED.value: 11}
    assert (report.rows_read, report.rows_missing_values, report.first_missing_line) == (200, 1, 21)
    with pytest.raises(NgsimInputError, match=r"01_tracks\.csv, line 11: .*--strict"):
        read_file(path, BuildConfig(), LIMITS, 0, True)
    rows[29][hs.HIGHD_X_VELOCITY] = 90.0  # 2 of 199 rows: more than 1 %
    with pytest.raises(NgsimInputError, match=r"2 of 199 rows \(1\.0%\) are implausible"):
        read_file(write_recording(tmp_path, rows, {1: ("Car", 2)}), BuildConfig(), LIMITS, 0, False)


def test_a_track_without_meta_row_and_a_grid_off_the_frames_are_errors(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 4), x0=100.0, y=19.0, x_velocity=25.0)
    rows += track_rows(9, range(1, 4), x0=150.0, y=19.0, x_velocity=25.0)
    path = write_recording(tmp_path, rows, {1: ("Car", 2)})
    with pytest.raises(
        NgsimInputError, match=r"line 5: track id 9 has no row in 01_tracksMeta\.csv"
    ):
        read_file(path, BuildConfig(), LIMITS, 0, False)
    with pytest.raises(
        NgsimInputError, match=r"grid step of 0\.1 s is not a multiple of highD's frame period"
    ):
        read_file(path, BuildConfig(time_step_s=0.1), LIMITS, 0, False)


def test_the_location_filter_names_highd_locations_or_keeps_them_all(tmp_path: Path) -> None:
    path = two_directions(tmp_path, location_id=2)
    assert read_file(path, BuildConfig(), LIMITS, 0, False).recordings == {
        KEY: 0
    }  # default: us-101, i-80
    assert read_file(path, BuildConfig(locations=("highd-2",)), LIMITS, 0, False).recordings == {
        KEY: 0
    }
    other = read_file(path, BuildConfig(locations=("us-101", "highd-3")), LIMITS, 0, False)
    assert (
        other.recordings == {}
        and other.report.rows_other_locations == other.report.rows_read == 600
    )
    with pytest.raises(
        ValueError, match=r"unknown location\(s\) \['highd-x'\]; choose from us-101"
    ):
        check_locations(("us-101", "highd-x"))
    check_locations(("us-101", "highd-7"))  # each a location of some source


def test_detection_from_content(tmp_path: Path) -> None:
    two_directions(tmp_path / "highd")
    ngsim = tmp_path / "ngsim" / "trajectories-0400-0415.txt"
    ngsim.parent.mkdir()
    ngsim.write_text(
        "1 2 1 1113433136100 16.5 35.4 6042842.1 2133117.9 14.5 4.9 2 40.0 0.0 2 0 0 0.0 0.0\n"
    )
    assert choose_source([tmp_path / "highd"])[0].name == "highd"
    assert choose_source([tmp_path / "ngsim"])[0].name == "ngsim"
    both = "hold NGSIM files .* and highD files .*--dataset ngsim or --dataset highd"
    with pytest.raises(NgsimInputError, match=both):
        choose_source([tmp_path])
    source, files, skipped = choose_source([tmp_path], "highd")
    assert (source.name, len(files), [p.name for p in skipped]) == ("highd", 3, [ngsim.name])


def test_a_build_lists_the_three_files_as_inputs(tmp_path: Path) -> None:
    two_directions(tmp_path / "raw", frames=range(1, 1101))  # 44 s: windows of 8.2 s fit
    result = run_build([tmp_path / "raw"], tmp_path / "out", BuildConfig())
    manifest = result.manifest.to_dict()
    assert manifest["dataset"] == "highd"
    inputs = {Path(f["path"]).name: f for f in manifest["inputs"]}
    assert sorted(inputs) == ["01_recordingMeta.csv", "01_tracks.csv", "01_tracksMeta.csv"]
    assert [inputs[n]["rows_read"] for n in sorted(inputs)] == [0, 2200, 0]
    assert all(
        len(f["sha256"]) == 64 and f["recordings"] == ["highd-2/01"] for f in inputs.values()
    )
    assert manifest["counts"]["rows"] == 2200 and sum(manifest["splits"].values()) > 0


# Through the command line: checks that drop rows (counted, reported with the first line) or
# fail the build (one line naming the file; nothing written).


def manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text())


def test_positions_in_other_units_than_the_speeds_fail_the_build(tmp_path: Path) -> None:
    # x in feet: the positions move 3.28 times as fast as xVelocity says (built on earlier
    # versions, exit 0).
    rows = [
        {**row, hs.HIGHD_X: round(row[hs.HIGHD_X] / FEET_TO_M, 3)}
        for row in two_directions_rows(LONG)
    ]
    path = write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", tmp_path / "raw", "--out", out), out, {}, path)
    # shown 25 / 0.3048 = 82.0 m/s against 25: 57.0 apart, 1 + 0.25 * 82.0 = 21.5 allowed, over
    # the 1,090 rows of each vehicle with 5 frames before and after them.
    assert line == (
        f"error: {path}: xVelocity disagrees with the vehicles' motion: the median difference "
        "from the speed their positions show is 57.0 m/s over 2,180 rows (median speed 82.0 m/s, "
        "21.5 allowed); is xVelocity swapped with another column, or in other units than metres "
        "per second (x and y: metres)?"
    )
    # The same motion in metres: it builds, the speeds agree exactly.
    write_recording(tmp_path / "raw", two_directions_rows(LONG), TWO_DIRECTIONS)
    assert invoke("build", tmp_path / "raw", "--out", out).exit_code == 0
    [recording] = manifest(out)["recordings"]
    assert recording["speed_rows_compared"] == 2180
    assert recording["speed_mismatch_mps"] == pytest.approx(0.0, abs=1e-6)


def _against_direction(frames: range) -> list[dict[str, float]]:
    """The rows of two_directions with a vehicle 3 on the lower lanes that tracksMeta says
    drives on the upper ones (direction 1): it moves against its direction, on lines 2202.."""
    rows = two_directions_rows(LONG)
    return rows + track_rows(3, frames, x0=150.0, y=22.5, x_velocity=25.0, laneId=6)


def test_a_vehicle_driving_against_its_direction_is_dropped_and_counted(tmp_path: Path) -> None:
    # On earlier versions it reached the tracks table driving backwards on the other carriageway.
    vehicles = {**TWO_DIRECTIONS, 3: ("Car", 1)}
    path = write_recording(tmp_path / "raw", _against_direction(range(1, 21)), vehicles)
    out = tmp_path / "out"
    result = invoke("build", tmp_path / "raw", "--out", out)
    assert result.exit_code == 0, result.output
    assert (
        "dropped 20 rows: the positions move against the vehicle's driving direction "
        f"(first: {path}, line 2202)." in result.stdout
    )
    reason = DropReason.DIRECTION.value
    assert manifest(out)["counts"]["rows_dropped"][reason] == 20
    tracks_input = next(f for f in manifest(out)["inputs"] if f["path"] == str(path))
    assert tracks_input["first_dropped_line"] == {reason: 2202}
    assert manifest(out)["counts"]["rows"] == 2200
    tracks = pl.read_parquet(out / "tracks" / "highd-2_01.parquet")
    assert sorted(tracks[s.VEHICLE_ID].unique()) == [1, 2]
    strict = invoke("build", tmp_path / "raw", "--out", out, "--overwrite", "--strict")
    assert "line 2202: the positions move against the vehicle's driving direction (--strict" in (
        error_line(strict)
    )
    # 100 rows of 2,300 (4.3 %): more than a build drops.
    write_recording(tmp_path / "raw", _against_direction(range(1, 101)), vehicles)
    before = snapshot(out)
    assert_failed_cleanly(
        invoke("build", tmp_path / "raw", "--out", out, "--overwrite"), out, before, path,
        "100 of 2,300 rows (4.3%) are implausible",
        "100 the positions move against the vehicle's driving direction; the first at line 2202",
    )  # fmt: skip


def test_every_column_that_reaches_the_tracks_table_is_checked(tmp_path: Path) -> None:
    # On earlier versions each of these reached the tracks table (a length of 1e308 m, lane -3).
    rows = two_directions_rows(LONG)
    bad = {
        10: {hs.HIGHD_WIDTH: 1e308},  # line 12 (row i is on line i + 2): 1e308 m long
        20: {hs.HIGHD_HEIGHT: -5.0},
        30: {hs.HIGHD_LANE_ID: -3},  # line 32
        40: {hs.HIGHD_LANE_ID: 300},
        50: {hs.HIGHD_DHW: -1.0, hs.HIGHD_PRECEDING_ID: 2},  # line 52
        60: {hs.HIGHD_THW: 1e300, hs.HIGHD_PRECEDING_ID: 2},
        70: {hs.HIGHD_PRECEDING_ID: -2},
        80: {hs.HIGHD_FOLLOWING_ID: -1},
        90: {hs.HIGHD_DHW: 30.0},  # a headway, but precedingId 0: no leader
    }
    for index, values in bad.items():
        rows[index].update(values)
    path = write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    out = tmp_path / "out"
    result = invoke("build", tmp_path / "raw", "--out", out)
    assert result.exit_code == 0, result.output
    dropped = manifest(out)["counts"]["rows_dropped"]
    size, lane, headway = DropReason.VEHICLE_SIZE, DropReason.LANE, DropReason.HEADWAY
    assert {r: n for r, n in dropped.items() if n} == {
        size.value: 2,
        lane.value: 2,
        headway.value: 5,
    }
    tracks_input = next(f for f in manifest(out)["inputs"] if f["path"] == str(path))
    assert tracks_input["first_dropped_line"] == {size.value: 12, lane.value: 32, headway.value: 52}
    assert f"dropped 5 rows: {DESCRIPTIONS[headway]} (first: {path}, line 52)." in result.stdout
    tracks = pl.read_parquet(out / "tracks" / "highd-2_01.parquet")
    columns = (s.LENGTH_M, s.WIDTH_M, s.LANE_ID, s.PRECEDING, s.FOLLOWING, s.SPACE_HEADWAY_M,
               s.TIME_HEADWAY_S)  # fmt: skip
    low, high = pl.struct(pl.col(columns).min()), pl.struct(pl.col(columns).max())
    ranges = tracks.select(low.alias("low"), high.alias("high"))
    assert [tuple(r.values()) for r in ranges.row(0)] == [
        (4.0, 2.0, 3, None, None, None, None), (5.0, 2.0, 5, None, None, None, None),
    ]  # fmt: skip
