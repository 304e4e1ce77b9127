"""highD files: telling the three kinds apart, finding a recording's files, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import straight_track, write_txt
from highd_fixtures import (
    LONG,
    LOWER_MARKINGS,
    TWO_DIRECTIONS,
    UPPER_MARKINGS,
    csv_text,
    track_rows,
    two_directions,
    two_directions_rows,
    write_recording,
)
from test_cli_ngsim import assert_failed_cleanly, invoke

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.files import (
    find_highd_files,
    read_recording_meta,
    read_tracks,
    read_tracks_meta,
    sniff_highd,
)
from ngsim_graphs.sources.highd.geometry import LIMITS
from ngsim_graphs.sources.highd.schema import HighdFile


def test_the_header_tells_the_three_files_apart(tmp_path: Path) -> None:
    tracks = two_directions(tmp_path)
    assert sniff_highd(tracks) is HighdFile.TRACKS
    assert sniff_highd(tmp_path / "01_tracksMeta.csv") is HighdFile.TRACKS_META
    assert sniff_highd(tmp_path / "01_recordingMeta.csv") is HighdFile.RECORDING_META
    ngsim = tmp_path / "trajectories-0400-0415.txt"
    ngsim.write_text("1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert sniff_highd(ngsim) is None and sniff_highd(empty) is None


def test_a_folder_gives_each_recording_s_three_files_and_skips_the_rest(tmp_path: Path) -> None:
    two_directions(tmp_path / "data", number=1)
    two_directions(tmp_path / "data", number=2)
    (tmp_path / "data" / "README.txt").write_text("highD sample\n")
    orphan = tmp_path / "data" / "03_recordingMeta.csv"
    orphan.write_text((tmp_path / "data" / "01_recordingMeta.csv").read_text())
    files, skipped = find_highd_files([tmp_path])
    names = [p.name for p in files]
    assert names == ["01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv",
                     "02_tracks.csv", "02_tracksMeta.csv", "02_recordingMeta.csv"]  # fmt: skip
    assert sorted(p.name for p in skipped) == ["03_recordingMeta.csv", "README.txt"]


def test_a_named_file_brings_its_recording(tmp_path: Path) -> None:
    two_directions(tmp_path)
    files, _ = find_highd_files([tmp_path / "01_tracksMeta.csv"])
    assert [p.name for p in files] == ["01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"]


def test_a_missing_meta_file_is_an_error_naming_it(tmp_path: Path) -> None:
    tracks = two_directions(tmp_path)
    (tmp_path / "01_tracksMeta.csv").unlink()
    with pytest.raises(NgsimInputError, match=r"01_tracks\.csv: no 01_tracksMeta\.csv beside it"):
        find_highd_files([tmp_path])
    with pytest.raises(NgsimInputError, match="no 01_tracksMeta.csv beside it"):
        find_highd_files([tracks])


def test_a_tracks_file_needs_its_recording_number_in_its_name(tmp_path: Path) -> None:
    tracks = two_directions(tmp_path)
    renamed = tracks.rename(tmp_path / "tracks.csv")
    with pytest.raises(NgsimInputError, match=r"must be named NN_tracks\.csv"):
        find_highd_files([renamed])


def test_a_missing_column_is_named_with_a_hint(tmp_path: Path) -> None:
    header = tuple("xVelocty" if c == hs.HIGHD_X_VELOCITY else c for c in hs.HIGHD_TRACKS_HEADER)
    path = tmp_path / "01_tracks.csv"
    path.write_text(csv_text(header, [{hs.HIGHD_FRAME: 1, hs.HIGHD_ID: 1}]))
    with pytest.raises(
        NgsimInputError,
        match=r"line 1: missing column xVelocity \(found 'xVelocty': misspelled\?\)",
    ):
        read_tracks(path)


def test_a_bad_number_names_the_file_the_line_and_the_column(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 6), x0=100.0, y=19.0, x_velocity=25.0)
    rows[3][hs.HIGHD_X] = "10O.5"  # a letter O: line 5 (the header is line 1)
    path = tmp_path / "01_tracks.csv"
    path.write_text(csv_text(hs.HIGHD_TRACKS_HEADER, rows))
    with pytest.raises(
        NgsimInputError, match=r"01_tracks\.csv, line 5: column x: '10O\.5' is not a number"
    ):
        read_tracks(path)
    rows[3][hs.HIGHD_X] = 100.0
    rows[1][hs.HIGHD_FRAME] = 2.5
    path.write_text(csv_text(hs.HIGHD_TRACKS_HEADER, rows))
    with pytest.raises(
        NgsimInputError, match=r"line 3: column frame: '2\.5' is not a whole number"
    ):
        read_tracks(path)


def test_empty_header_only_and_truncated_files_are_errors(tmp_path: Path) -> None:
    path = tmp_path / "01_tracks.csv"
    path.write_text("")
    with pytest.raises(NgsimInputError, match="empty file"):
        read_tracks(path)
    path.write_text(",".join(hs.HIGHD_TRACKS_HEADER) + "\n")
    with pytest.raises(NgsimInputError, match="no data rows"):
        read_tracks(path)
    text = csv_text(
        hs.HIGHD_TRACKS_HEADER, track_rows(1, range(1, 4), x0=100.0, y=19.0, x_velocity=25.0)
    )
    short = text[: text.rindex(",", 0, len(text) - 12)]  # the last line cut short
    path.write_text(short + "\n")
    with pytest.raises(
        NgsimInputError, match=r"line 4: \d+ fields where the header has 25 \(truncated line\?\)"
    ):
        read_tracks(path)
    path.write_text(short)
    with pytest.raises(NgsimInputError, match=r"line 4: the last line has no line end"):
        read_tracks(path)


def test_recording_meta_gives_id_location_and_markings(tmp_path: Path) -> None:
    two_directions(tmp_path, number=7, location_id=3)
    meta = read_recording_meta(tmp_path / "07_recordingMeta.csv", LIMITS)
    assert (meta.recording_id, meta.location_id) == (7, 3)
    assert meta.upper_markings_m == (8.0, 11.5, 15.0) and meta.lower_markings_m == (
        18.0,
        21.5,
        25.0,
    )


def test_recording_meta_must_be_25_hz_with_increasing_markings(tmp_path: Path) -> None:
    rows = track_rows(1, range(1, 4), x0=100.0, y=19.0, x_velocity=25.0)
    write_recording(tmp_path, rows, {1: ("Car", 2)}, frame_rate=30)
    with pytest.raises(
        NgsimInputError, match=r"line 2: frameRate 30: highD recordings run at 25 Hz"
    ):
        read_recording_meta(tmp_path / "01_recordingMeta.csv", LIMITS)
    path = tmp_path / "01_recordingMeta.csv"
    path.write_text(path.read_text().replace("30", "25").replace("8.0;11.5;15.0", "8.0;x;15.0"))
    with pytest.raises(
        NgsimInputError, match=r"line 2: column upperLaneMarkings: '8\.0;x;15\.0': 'x' is not a num"
    ):
        read_recording_meta(path, LIMITS)
    path.write_text(path.read_text().replace("8.0;x;15.0", "8.0;15.0;11.5"))
    with pytest.raises(
        NgsimInputError, match=r"upperLaneMarkings: '8\.0;15\.0;11\.5' is not a list of increasing"
    ):
        read_recording_meta(path, LIMITS)


@pytest.mark.parametrize(
    ("vehicle", "message"),
    [
        (("Bus", 2), "a class other than Car or Truck"),
        (("Car", 3), "a drivingDirection other than 1 or 2"),
    ],
)
def test_tracks_meta_errors_name_the_line(
    tmp_path: Path, vehicle: tuple[str, int], message: str
) -> None:
    rows = track_rows(1, range(1, 4), x0=100.0, y=19.0, x_velocity=25.0)
    write_recording(tmp_path, rows, {1: ("Car", 2), 2: vehicle})
    with pytest.raises(NgsimInputError, match=rf"01_tracksMeta\.csv, line 3: holds {message}"):
        read_tracks_meta(tmp_path / "01_tracksMeta.csv")


def test_tracks_meta_maps_classes_to_ngsim_codes(tmp_path: Path) -> None:
    two_directions(tmp_path)
    meta = read_tracks_meta(tmp_path / "01_tracksMeta.csv")
    assert meta.rows() == [(1, 2, 2, 300), (2, 3, 1, 300)]  # id, v_class, direction, numFrames


# Through the command line: one error line naming the file, the line and the column; no output.


@pytest.mark.parametrize(
    ("column", "markings", "problem"),
    [
        (hs.HIGHD_LOWER_LANE_MARKINGS, "1e308;2e308", "'1e308' lies beyond the position limit"),
        (hs.HIGHD_LOWER_LANE_MARKINGS, "nan;1;2", "'nan' is not a finite number"),
        (hs.HIGHD_LOWER_LANE_MARKINGS, "-inf;0;1", "'-inf' is not a finite number"),
        (hs.HIGHD_UPPER_LANE_MARKINGS, "1e308;2e308", "'1e308' lies beyond the position limit"),
        (hs.HIGHD_UPPER_LANE_MARKINGS, "8.0;11.5;19.0", "upperLaneMarkings end at image y 19"),
    ],
)
def test_build_refuses_implausible_lane_markings(
    tmp_path: Path, column: str, markings: str, problem: str
) -> None:
    # On earlier versions 1e308;2e308 built, every x_m -1e308; nan or -inf ended in a traceback.
    two_directions(tmp_path / "raw", frames=LONG)
    meta = tmp_path / "raw" / "01_recordingMeta.csv"
    default = ";".join(map(str, UPPER_MARKINGS if "upper" in column else LOWER_MARKINGS))
    meta.write_text(meta.read_text().replace(default, markings))
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", tmp_path / "raw", "--out", out), out, {}, meta)
    assert line.startswith(f"error: {meta}, line 2: ")
    assert problem in line and column in line


def test_a_highd_line_longer_than_any_row_is_named(tmp_path: Path) -> None:
    tracks = two_directions(tmp_path / "raw")
    lines = tracks.read_bytes().split(b"\n")
    tracks.write_bytes(b"\n".join([*lines[:4], b"1," * 3_000, *lines[4:]]))
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", tmp_path / "raw", "--out", out), out, {}, tracks)
    assert line == (
        f"error: {tracks}, line 5: a line longer than 4,096 bytes, which no trajectory row is "
        "(binary data? no line ends?)"
    )


def _damage_header(path: Path, column: str) -> None:
    """One name of the header misspelled: its last letter replaced by 'x'."""
    header, body = path.read_text().split("\n", 1)
    names = header.split(",")
    names[names.index(column)] = column[:-1] + "x"
    path.write_text(",".join(names) + "\n" + body)


@pytest.mark.parametrize(
    ("kind", "column"),
    [
        (HighdFile.TRACKS, hs.HIGHD_X_VELOCITY),
        (HighdFile.TRACKS, hs.HIGHD_LANE_ID),
        (HighdFile.TRACKS_META, hs.HIGHD_DRIVING_DIRECTION),
        (HighdFile.RECORDING_META, hs.HIGHD_FRAME_RATE),
    ],
)
@pytest.mark.parametrize("with_ngsim", [False, True])
def test_a_damaged_header_is_refused_naming_the_column(
    tmp_path: Path, kind: HighdFile, column: str, with_ngsim: bool
) -> None:
    # On earlier versions a folder search skipped recording 02 (its tracks file as "not NGSIM")
    # and built recording 01 alone, exit 0; beside NGSIM files, the highD files were skipped.
    raw = tmp_path / "raw"
    two_directions(raw, frames=LONG, number=1)
    two_directions(raw, frames=LONG, number=2)
    if with_ngsim:
        write_txt(raw / "trajectories-0750am-0805am.txt", straight_track(1, range(10, 92)))
    damaged = raw / f"02_{kind.value}.csv"
    _damage_header(damaged, column)
    message = f"missing column {column} (found '{column[:-1]}x': misspelled?)"
    for named in (raw, damaged):
        out = tmp_path / "out"
        line = assert_failed_cleanly(invoke("build", named, "--out", out), out, {}, damaged)
        assert line == f"error: {damaged}, line 1: {message}"


@pytest.mark.parametrize(
    ("kind", "cut"),
    [
        (HighdFile.TRACKS, 2),  # laneId 12 of the last row would read 1
        (HighdFile.TRACKS_META, 2),  # numLaneChanges empty, its field still there
        (HighdFile.RECORDING_META, 6),  # lowerLaneMarkings 18.0;21.5 (25.0 lost)
    ],
)
def test_a_file_cut_inside_its_last_field_is_refused(
    tmp_path: Path, kind: HighdFile, cut: int
) -> None:
    # On earlier versions each built (exit 0): the cut keeps the number of fields.
    rows = two_directions_rows(LONG)
    rows[-1][hs.HIGHD_LANE_ID] = 12
    write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    path = tmp_path / "raw" / f"01_{kind.value}.csv"
    text = path.read_bytes()
    path.write_bytes(text[:-cut])
    last_line = text.count(b"\n")
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", tmp_path / "raw", "--out", out), out, {}, path)
    assert (
        line
        == f"error: {path}, line {last_line}: the last line has no line end: the file is cut short"
    )
    path.write_bytes(text)  # intact again: it builds
    assert invoke("build", tmp_path / "raw", "--out", out).exit_code == 0


@pytest.mark.parametrize(("lines_kept", "expected"), [(1 + 1100 + 600, (2, 600, 1100, "")),
                                                     (1 + 700, (1, 700, 1100, " (and 1 more track)"))])  # fmt: skip
def test_a_tracks_file_cut_at_a_line_end_is_refused(
    tmp_path: Path, lines_kept: int, expected: tuple[int, int, int, str]
) -> None:
    """Whole lines lost at the end: tracksMeta's numFrames tells (earlier versions built the
    rest, exit 0)."""
    write_recording(tmp_path / "raw", two_directions_rows(LONG), TWO_DIRECTIONS)
    path = tmp_path / "raw" / "01_tracks.csv"
    text = path.read_text()
    path.write_text("".join(text.splitlines(keepends=True)[:lines_kept]))
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", tmp_path / "raw", "--out", out), out, {}, path)
    track, rows, frames, more = expected
    assert line == (
        f"error: {path}: track {track} has {rows:,} rows where 01_tracksMeta.csv says "
        f"{frames:,} (numFrames){more}: cut short?"
    )


def test_an_optional_column_empty_in_every_row_is_said(tmp_path: Path) -> None:
    rows = [{**row, hs.HIGHD_X_ACCELERATION: ""} for row in two_directions_rows(LONG)]
    path = write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    out = tmp_path / "out"
    result = invoke("build", tmp_path / "raw", "--out", out)
    assert result.exit_code == 0, result.output
    warning = f"{path}: column xAcceleration is empty in every row"
    assert warning in result.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert [w for w in manifest["warnings"] if w.startswith(warning)] != []


def test_a_neighbour_id_that_is_not_whole_is_refused(tmp_path: Path) -> None:
    # xAcceleration swapped with rightAlongsideId: the ids are accelerations (line 4's -0.25).
    rows = two_directions_rows(LONG)
    for i, row in enumerate(rows):
        row[hs.HIGHD_X_ACCELERATION], row["rightAlongsideId"] = 0, -0.25 if i == 2 else 0
    path = write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", tmp_path / "raw", "--out", out), out, {}, path,
        "line 4: column rightAlongsideId: '-0.25' is not a whole number",
    )  # fmt: skip


def test_a_lateral_column_of_one_value_is_refused(tmp_path: Path) -> None:
    # d2: y = 0 in every row: each vehicle's centre 1 m from the image's top, outside every lane.
    rows = [{**row, hs.HIGHD_Y: 0} for row in two_directions_rows(LONG)]
    path = write_recording(tmp_path / "raw", rows, TWO_DIRECTIONS)
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", tmp_path / "raw", "--out", out), out, {}, path,
        "recording highd-2/01: its lateral positions are not where its lanes are",
        "2 of 2 lanes have their median y more than a lane width outside the lane",
        "(lane 3: 1.0 m, the lane at 11.5 to 15.0 m)",
    )  # fmt: skip
