"""`ngsim-graphs build` on inputs with stray and implausible rows: counted, reported, dropped one
by one, or a one-line error (too many of them, --strict, swapped columns, no samples at all)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import polars as pl
import pytest
from conftest import I80_FIRST, make_row, set_budget, write_period_csv, write_portal, write_txt
from test_cli_ngsim import assert_failed_cleanly, invoke, snapshot

from ngsim_graphs import schema as s
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.plausibility import NgsimDrop
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS

N_VEHICLES, N_FRAMES = 10, 100


@pytest.fixture
def rows() -> list[dict]:
    """Vehicles 1..10 of us-101 0750am, frames 0..99 each (1,000 rows; row i is vehicle
    i // 100 + 1 at frame i % 100). Each spans 50 grid steps, one 8.2 s window: 10 samples,
    by the vehicle split 7 train, 1 val, 2 test. Lanes 1..5 (v % 5 + 1), each vehicle at its
    lane's centre (12 ft apart), 40 ft between rows of five."""
    return [
        make_row(
            v,
            f,
            local_x_ft=6.0 + 12.0 * (v % 5),
            local_y_ft=40.0 * (v // 5) + 3.5 * f,
            v_vel_fps=35.0,
            lane_id=v % 5 + 1,
        )
        for v in range(1, N_VEHICLES + 1)
        for f in range(N_FRAMES)
    ]


def manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text())


def test_one_stray_global_time_costs_one_row_not_the_recording(
    tmp_path: Path, rows: list[dict]
) -> None:
    # Row 150 (vehicle 2, frame 50) 100 ms late: today's main lost the whole recording to it.
    rows[150] = {**rows[150], s.GLOBAL_TIME: rows[150][s.GLOBAL_TIME] + 100}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    reason = NgsimDrop.GLOBAL_TIME.value
    assert "dropped 1 row: Global_Time off its recording" in result.stdout
    assert f"(first: {path}, line 151)." in result.stdout
    counts = manifest(out)["counts"]
    assert counts["rows_dropped"][reason] == 1 and counts["rows"] == 999
    assert manifest(out)["inputs"][0]["first_dropped_line"] == {reason: 151}
    # The dropped row splits vehicle 2's record at a frame gap (frames 0..49 and 51..99, 25 grid
    # steps each, too short for a window): 9 of the 10 samples remain.
    assert (counts["gaps"], counts["tracks"], counts["samples"]) == (1, 11, 9)


def test_stray_rows_beyond_the_share_fail_the_build(tmp_path: Path, rows: list[dict]) -> None:
    for i in range(5, 1000, 50):  # 20 rows, 2 %
        rows[i] = {**rows[i], s.GLOBAL_TIME: rows[i][s.GLOBAL_TIME] + 100}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        "20 of 1,000 rows (2.0%) are implausible", "20 Global_Time off its recording", "line 6",
    )  # fmt: skip


def test_implausible_rows_are_counted_per_reason(tmp_path: Path, rows: list[dict]) -> None:
    rows[120] = {**rows[120], ns.V_VEL: 1e308}
    rows[230] = {**rows[230], ns.V_VEL: -3.0}
    rows[340] = {**rows[340], ns.V_ACC: 400.0}
    rows[450] = {**rows[450], ns.LOCAL_Y: rows[450][ns.LOCAL_Y] + 3_280.0}  # a kilometre away
    rows[560] = make_row(6, -2, local_x_ft=18.0)  # a negative Frame_ID (an IndexError on main)
    rows[670] = {**rows[670], ns.LOCAL_X: 1e7}
    path, out = (
        write_period_csv(tmp_path / "trajectories-0750am-0805am.csv", rows),
        tmp_path / "out",
    )
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    dropped = manifest(out)["counts"]["rows_dropped"]
    assert dropped == {
        DropReason.FRAME_ID.value: 1,
        DropReason.VEHICLE_ID.value: 0,
        DropReason.POSITION.value: 1,
        DropReason.SPEED.value: 2,
        DropReason.ACCELERATION.value: 1,
        NgsimDrop.GLOBAL_TIME.value: 0,
        DropReason.POSITION_OUTLIER.value: 1,
        DropReason.VEHICLE_SIZE.value: 0,
        DropReason.LANE.value: 0,
        NgsimDrop.VEHICLE_CLASS.value: 0,
        DropReason.HEADWAY.value: 0,
        DropReason.DIRECTION.value: 0,
    }
    # Lines: the header is line 1, so row i is on line i + 2.
    assert manifest(out)["inputs"][0]["first_dropped_line"] == {
        DropReason.FRAME_ID.value: 562,
        DropReason.POSITION.value: 672,
        DropReason.SPEED.value: 122,
        DropReason.ACCELERATION.value: 342,
    }
    [recording] = manifest(out)["recordings"]
    assert recording["first_outlier"] == {"file": str(path), "line": 452}
    assert (
        f"dropped 2 rows: v_Vel negative or above the speed limit (first: {path}, line 122)."
        in result.stdout
    )
    assert (
        f"dropped 1 row: position jumps away from the neighbouring frames (first: {path}, line 452)."
        in result.stdout
    )
    assert manifest(out)["counts"]["rows"] == 995  # 1,000 - 5 dropped before cleaning
    stats = invoke("stats", out)
    cells = [[c.strip() for c in line.split("│")[1:-1]] for line in stats.stdout.splitlines()]
    assert ["speed out of range", "2", "0.2%"] in cells
    assert ["position outlier", "1", "0.1%"] in cells


def test_impossible_values_beside_the_motion_never_reach_the_tracks(
    tmp_path: Path, rows: list[dict]
) -> None:
    # On main these five rows reached the tracks table: length 3e307 m, width -1.5 m, lane -3,
    # class 9, a time headway of -1e300 s.
    edits = {
        120: {ns.V_LENGTH: 1e308},
        230: {ns.V_WIDTH: -5.0},
        340: {s.LANE_ID: -3},
        450: {s.V_CLASS: 9},
        560: {ns.TIME_HEADWAY: -1e300},
    }
    for i, edit in edits.items():
        rows[i] = {**rows[i], **edit}
    path = write_period_csv(tmp_path / "trajectories-0750am-0805am.csv", rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    inputs = manifest(out)["inputs"][0]
    assert inputs["first_dropped_line"] == {
        DropReason.VEHICLE_SIZE.value: 122,
        DropReason.LANE.value: 342,
        NgsimDrop.VEHICLE_CLASS.value: 452,
        DropReason.HEADWAY.value: 562,
    }
    assert inputs["rows_dropped"][DropReason.VEHICLE_SIZE.value] == 2
    assert "dropped 2 rows: v_Length or v_Width not above 0" in result.stdout
    tracks = pl.read_parquet(out / "tracks" / "us-101_0750am-0805am.parquet")
    assert tracks.select(
        pl.col(s.LENGTH_M).max(), pl.col(s.WIDTH_M).min(), pl.col(s.LANE_ID).min(),
        pl.col(s.V_CLASS).max(), pl.col(s.TIME_HEADWAY_S).min(),
    ).row(0) == (pytest.approx(15.0 * 0.3048), pytest.approx(6.0 * 0.3048), 1, 2, None)  # fmt: skip


def _i80(rows: list[dict]) -> list[dict]:
    """The same rows in i-80 0400-0415."""
    shift = I80_FIRST.start_epoch_ms - rows[0][s.GLOBAL_TIME] + 100 * rows[0][s.FRAME_ID]
    return [{**row, s.GLOBAL_TIME: row[s.GLOBAL_TIME] + shift} for row in rows]


def _swap_position_and_acceleration(row: dict) -> dict:
    return {**row, ns.GLOBAL_X: row[ns.V_ACC], ns.V_ACC: row[ns.GLOBAL_X]}


@pytest.mark.parametrize(
    ("damage", "fragment"),
    [
        (lambda row: {**row, ns.V_VEL: 300.0}, "1,000 v_Vel negative or above the speed limit"),
        (lambda row: {**row, s.FRAME_ID: row[s.FRAME_ID] + 80_000}, "1,000 Frame_ID out of range"),
        (lambda row: {**row, s.VEHICLE_ID: 0}, "1,000 Vehicle_ID below 1"),
        (_swap_position_and_acceleration, "1,000 v_Acc above the acceleration limit"),
    ],
)
def test_a_file_none_of_whose_rows_is_usable_is_an_error(
    tmp_path: Path, rows: list[dict], damage, fragment: str
) -> None:
    # On main such a file vanished as "rows of other locations"; the build went on without it.
    damaged = [damage(row) for row in rows]
    good = write_txt(tmp_path / "raw" / "i-80" / "trajectories-0400-0415.txt", _i80(rows))
    bad = write_txt(tmp_path / "raw" / "us-101" / "trajectories-0750am-0805am.txt", damaged)
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", good.parent.parent, "--out", out), out, {}, bad,
        "no row of it can be used", fragment, "the first at line 1",
    )  # fmt: skip


@pytest.mark.parametrize(
    ("write", "cut", "line", "value"),
    [
        (write_txt, 1, 1_000, "'9999.9'"),  # Time_Headway 9999.99 cut to 9999.9
        (write_period_csv, 3, 1_001, "'9999'"),
        (write_portal, 2, 1_001, "'us-1'"),  # the Location us-101 cut to us-1
    ],
)
def test_a_file_cut_inside_its_last_field_is_refused(
    tmp_path: Path, rows: list[dict], write, cut: int, line: int, value: str
) -> None:
    # On main such a file was read: its cut row kept a shortened value or, in the portal file,
    # became a row of "other locations".
    path = write(tmp_path / "trajectories-0750am-0805am.csv", rows)
    whole = path.read_bytes().rstrip()
    path.write_bytes(whole[:-cut])
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        f"line {line}: the file ends inside its last field ({value} where", "is it truncated?",
    )  # fmt: skip
    path.write_bytes(whole)  # whole, without a final line end: read
    assert invoke("build", path, "--out", out).exit_code == 0


def test_a_group_of_whole_vehicles_on_its_own_clock_is_a_recording(tmp_path: Path) -> None:
    # A real Peachtree export: two groups of vehicles whose Global_Time - 100 * Frame_ID differ by
    # 11.7 s, each consistent. On main the smaller was "Global_Time off its recording" and the
    # build failed (23.8 % of the rows implausible).
    start = OFFICIAL_RECORDINGS[0].start_epoch_ms + 3_620_000  # no official period: a label
    rows = [
        make_row(
            v, f, local_x_ft=6.0 + 12.0 * (v % 5), local_y_ft=40.0 * (v // 5) + 3.5 * f,
            v_vel_fps=35.0, start_ms=start + (11_700 if v > 25 else 0), lane_id=v % 5 + 1,
        )
        for v in range(1, 49)
        for f in range(N_FRAMES)
    ]  # fmt: skip
    rows[7] = {**rows[7], s.GLOBAL_TIME: rows[7][s.GLOBAL_TIME] + 11_700}  # one stray row
    path, out = write_portal(tmp_path / "p.csv", rows, "peachtree"), tmp_path / "out"
    result = invoke("build", path, "--out", out, "--locations", "peachtree")
    assert result.exit_code == 0, result.output
    names = [r["name"] for r in manifest(out)["recordings"]]
    assert names == ["peachtree_0850-0850", "peachtree_0850-0850-2"]  # both from 08:50 PDT
    assert [r["vehicles"] for r in manifest(out)["recordings"]] == [25, 23]
    assert manifest(out)["counts"]["rows_dropped"][NgsimDrop.GLOBAL_TIME.value] == 1
    note = (
        f"{path}: peachtree/0850-0850-2: 23 vehicles (2,300 rows) keep a frame clock of their "
        "own, Global_Time - 100 * Frame_ID +11.7 s from peachtree/0850-0850's: a recording of "
        "their own, not stray rows"
    )
    assert manifest(out)["warnings"][0] == note
    assert f"warning: {note}" in result.stderr


def test_strict_fails_on_the_first_dropped_row(tmp_path: Path, rows: list[dict]) -> None:
    rows[340] = {**rows[340], ns.V_ACC: 400.0}
    rows[450] = {**rows[450], ns.LOCAL_Y: rows[450][ns.LOCAL_Y] + 3_280.0}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    assert invoke("build", path, "--out", out).exit_code == 0  # without --strict: dropped
    before = snapshot(out)
    result = invoke("build", path, "--out", out, "--overwrite", "--strict")
    assert_failed_cleanly(
        result, out, before, path, "line 341: v_Acc above the acceleration limit (--strict"
    )
    rows[340] = {**rows[340], ns.V_ACC: 0.0}  # only the position outlier is left
    write_txt(path, rows)
    result = invoke("build", path, "--out", out, "--overwrite", "--strict")
    assert_failed_cleanly(result, out, before, path, "line 451: position jumps away")


def test_swapped_speed_and_acceleration_headers(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "trajectories-0750am-0805am.csv", rows)
    header, body = path.read_text().split("\n", 1)
    swapped = header.replace("v_Vel", "SPEED").replace("v_Acc", "v_Vel").replace("SPEED", "v_Acc")
    path.write_text(f"{swapped}\n{body}")
    out = tmp_path / "out"
    # Every value is inside the row limits (an acceleration of 35 ft/s^2 is 10.7 m/s^2, a speed
    # of 0): only the speed the positions show (10.7 m/s) gives the swap away.
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "v_Vel disagrees with the vehicles' motion",
        "10.7 m/s",
    )  # fmt: skip


def test_all_odd_frame_ids_are_an_error_that_says_why(tmp_path: Path, rows: list[dict]) -> None:
    odd = [
        {
            **r,
            s.FRAME_ID: 2 * r[s.FRAME_ID] + 1,
            s.GLOBAL_TIME: r[s.GLOBAL_TIME] + 100 * (r[s.FRAME_ID] + 1),
        }
        for r in rows
    ]
    odd = [{**r, ns.LOCAL_Y: r[ns.LOCAL_Y] + 3.5 * (r[s.FRAME_ID] // 2 + 1)} for r in odd]
    path, out = write_txt(tmp_path / "a.txt", odd), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "no samples", "none of the 1,000 rows kept",
        "Frame_ID is a multiple of 2",
    )  # fmt: skip


def test_short_tracks_are_an_error_that_says_why(tmp_path: Path, rows: list[dict]) -> None:
    short = [r for r in rows if r[s.FRAME_ID] < 60]  # 30 grid steps per vehicle
    path, out = write_portal(tmp_path / "p.csv", short), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "no samples: no track spans a whole window of 41",
        "the longest has 30 steps",
    )  # fmt: skip


def test_a_stray_vehicle_id_does_not_decide_the_vehicle_split(
    tmp_path: Path, rows: list[dict]
) -> None:
    # On main one row of vehicle 1 renamed 99,999 moved the cuts to 69,999 and 79,999: every
    # other ego trained, val and test were empty, and no warning named the recording.
    rows[2] = {**rows[2], s.VEHICLE_ID: 99_999}  # on the grid (an even frame)
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    # Cuts at round(0.7 * 10) = 7 and 8: vehicles 1..7 train, 8 validates, 9 and 10 test.
    assert manifest(out)["splits"] == {"train": 7, "val": 1, "test": 2}
    assert manifest(out)["warnings"] == [
        "us-101/0750am-0805am: Vehicle_ID 99,999 lies far above the others (the largest of which "
        "is 10): the vehicle split ignores it and cuts at 7 and 8"
    ]
    assert f"warning: {manifest(out)['warnings'][0]}" in result.stderr


def test_a_recording_without_validation_samples_is_named(tmp_path: Path, rows: list[dict]) -> None:
    few = [row for row in _i80(rows) if row[s.VEHICLE_ID] <= 3]  # cuts at 2 and 2: no val
    write_txt(tmp_path / "raw" / "a.txt", rows)
    write_txt(tmp_path / "raw" / "b.txt", few)
    out = tmp_path / "out"
    result = invoke("build", tmp_path / "raw", "--out", out)
    assert result.exit_code == 0, result.output
    assert manifest(out)["splits"] == {"train": 9, "val": 1, "test": 3}
    [warning] = manifest(out)["warnings"]
    assert warning.startswith("the val split has no sample of i-80/0400-0415: the vehicle split")
    assert warning.endswith(
        "i-80/0400-0415 gives it 0 of 3: its largest Vehicle_ID is 3, so the cuts lie at 2 and 2"
    )


def test_a_whole_number_column_with_a_fraction(tmp_path: Path, rows: list[dict]) -> None:
    rows[7] = {**rows[7], s.FRAME_ID: "7.5"}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out),
        out,
        {},
        path,
        "line 8: column Frame_ID: '7.5' is not a whole number",
    )


def test_cr_only_line_ends(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "raw" / "a.csv", rows)
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r"))
    out = tmp_path / "out"
    for given in (path, path.parent):  # named, or found in a folder: not skipped as "not NGSIM"
        assert_failed_cleanly(
            invoke("build", given, "--out", out), out, {}, path, "line 1:", "CR alone"
        )


def test_truncated_quoted_field_names_its_line(tmp_path: Path, rows: list[dict]) -> None:
    path = write_portal(tmp_path / "p.csv", rows)  # quoted thousands: "1,118,846,993,000"
    lines = path.read_bytes().split(b"\r\n")
    cut = lines[40][: lines[40].index(b'"') + 3]  # ...,"1,1
    path.write_bytes(b"\r\n".join([*lines[:40], cut, *lines[41:]]))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "line 41:", "quoted field is not closed"
    )


def test_a_quote_left_open_before_a_long_line_is_the_error_on_threads(
    tmp_path: Path, rows: list[dict], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Read a line a chunk, four chunks at once: the open quote of line 4 is the error, as one
    thread meets it, not the line too long (line 6) in a chunk read while line 4's was parsed;
    the out folder is not made."""
    set_budget(monkeypatch, text_chunk_bytes=100)
    monkeypatch.setattr(pl, "thread_pool_size", lambda: 4)
    path = write_portal(tmp_path / "p.csv", rows)
    lines = path.read_bytes().split(b"\r\n")
    cut = lines[3][: lines[3].index(b'"') + 3]
    path.write_bytes(b"\r\n".join([*lines[:3], cut, lines[4], b"0" * 5_000, *lines[5:]]))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "line 4:", "quoted field is not closed"
    )


# --- defects found by bench/fuzz_inputs.py ----------------------------------------------------


def test_a_unit_separator_byte_is_named_with_its_line(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", rows)
    lines = path.read_bytes().split(b"\n")
    with_separator = lines[4].replace(b",15,", b",1\x1f5,", 1)  # line 5: 0x1F inside v_Length
    # With a short line 2 too, the reader counts fields line by line (where 0x1F cut lines).
    short = lines[1].rsplit(b",", 1)[0]
    path.write_bytes(b"\n".join([lines[0], short, *lines[2:4], with_separator, *lines[5:]]))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "line 2:", "23 fields"
    )
    path.write_bytes(b"\n".join([*lines[:4], with_separator, *lines[5:]]))
    line = assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, "line 5:")
    assert "column v_length:" in line and "is not a number" in line
    txt = write_txt(tmp_path / "b.txt", rows[:50] + [{**rows[50], s.LANE_ID: "2\x1f"}] + rows[51:])
    assert_failed_cleanly(
        invoke("build", txt, "--out", out), out, {}, txt, "line 51:", "control character (0x1F)"
    )


@pytest.mark.parametrize("chunk_bytes", [1_024, 16 * 1024 * 1024])
def test_a_line_longer_than_any_row_is_named_unread(
    tmp_path: Path, rows: list[dict], monkeypatch: pytest.MonkeyPatch, chunk_bytes: int
) -> None:
    """e06's 2.5 GB line of zeros took 5 GB of memory before its error: a line is read only up
    to the bound, in chunks of the reader's size (smaller than the bound, or far larger)."""
    set_budget(monkeypatch, text_chunk_bytes=chunk_bytes)
    path, out = write_txt(tmp_path / "trajectories-0750am-0805am.txt", rows), tmp_path / "out"
    lines = path.read_bytes().split(b"\n")
    path.write_bytes(b"\n".join([*lines[:60], b"0" * (1 << 20)]))  # no line end: cut short
    line = assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path)
    assert line == (
        f"error: {path}, line 61: a line longer than 4,096 bytes, which no trajectory row is "
        "(binary data? no line ends?)"
    )
    path.write_bytes(b"\n".join([*lines[:30], b" 0" * 2_049, *lines[30:]]))  # 4,098 bytes
    assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, "line 31: a line")


def test_every_row_without_a_required_value_names_the_file(
    tmp_path: Path, rows: list[dict]
) -> None:
    path = write_period_csv(
        tmp_path / "trajectories-0750am-0805am.csv", [{**r, s.GLOBAL_TIME: None} for r in rows]
    )
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        "every one of its 1,000 rows has an empty required field", "Global_Time", "line 2",
    )  # fmt: skip


def test_a_column_twice_in_the_header(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", rows)
    header, body = path.read_text().split("\n", 1)
    path.write_text(header.replace("O_Zone", "Lane_ID", 1) + "\n" + body)
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "line 1: column Lane_ID appears twice"
    )


def test_text_after_a_closing_quote_names_its_line(tmp_path: Path, rows: list[dict]) -> None:
    path = write_portal(tmp_path / "p.csv", rows)
    lines = path.read_bytes().split(b"\r\n")
    lines[9] = lines[9].replace(b'",', b'"C6,', 1)  # line 10: "1,118,846,994,100"C6
    path.write_bytes(b"\r\n".join(lines))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path, "line 10: malformed quoting"
    )


def test_an_empty_location_column_is_said(tmp_path: Path, rows: list[dict]) -> None:
    path = write_portal(tmp_path / "p.csv", rows, locations="")
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out),
        out,
        {},
        path,
        "it holds: 1,000 rows with an empty Location",
    )


def test_a_displaced_burst_is_dropped_and_a_displaced_stretch_is_said(
    tmp_path: Path, rows: list[dict]
) -> None:
    # Vehicle 6 (rows 500..599): frames 40 and 41 displaced 500 ft, frames 70..99 displaced too.
    for i in (540, 541, *range(570, 600)):
        rows[i] = {**rows[i], ns.LOCAL_Y: rows[i][ns.LOCAL_Y] + 500.0}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    assert (
        f"dropped 2 rows: position jumps away from the neighbouring frames (first: {path}, line 541)."
        in result.stdout
    )
    assert "split tracks at 1 position jump of more than 10 m between frames." in result.stdout
    counts = manifest(out)["counts"]
    assert (
        counts["rows_dropped"][DropReason.POSITION_OUTLIER.value],
        counts["position_jumps"],
    ) == (2, 1)


def test_files_of_locations_left_out_are_not_checked(tmp_path: Path, rows: list[dict]) -> None:
    i80 = [
        make_row(v, f, v_vel_fps=35.0, local_y_ft=3.5 * f, start_ms=I80_FIRST.start_epoch_ms)
        for v in (1, 2)
        for f in range(100)
    ]
    i80[30] = {**i80[30], ns.V_VEL: -5.0}  # implausible, but of i-80
    i80[60] = {**i80[60], s.GLOBAL_TIME: i80[60][s.GLOBAL_TIME] + 100}  # a stray, of i-80 too
    raw = tmp_path / "raw"
    write_txt(raw / "trajectories-0750am-0805am.txt", rows)
    write_txt(raw / "trajectories-0400-0415.txt", i80)
    out = tmp_path / "out"
    result = invoke("build", raw, "--out", out, "--locations", "us-101", "--strict")
    assert result.exit_code == 0, result.output
    counts = manifest(out)["counts"]
    assert counts["rows_other_locations"] == 200 and sum(counts["rows_dropped"].values()) == 0
    assert counts["rows_read"] == counts["rows_other_locations"] + counts["rows"] == 1_200


@pytest.mark.parametrize(
    ("write", "line"), [(write_txt, 501), (write_period_csv, 502), (write_portal, 502)]
)
def test_a_row_of_another_location_is_a_stray_not_a_recording(
    tmp_path: Path, rows: list[dict], write, line: int
) -> None:
    # One i-80 0400 row inserted among us-101 0750am's (the portal's saying us-101): on main a
    # recording i-80/0400-0415 of 1 row, not counted, nothing said.
    rows.insert(500, {**_i80(rows)[0], s.VEHICLE_ID: 41})
    path = write(tmp_path / "raw" / "us-101" / "trajectories-0750am-0805am.csv", rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    assert "dropped 1 row: Global_Time off its recording" in result.stdout
    assert f"(first: {path}, line {line})." in result.stdout
    built = manifest(out)
    assert [r["name"] for r in built["recordings"]] == ["us-101_0750am-0805am"]
    assert built["counts"]["rows_dropped"][NgsimDrop.GLOBAL_TIME.value] == 1
    assert built["counts"]["rows"] == 1_000


@pytest.mark.parametrize(
    "write", [write_txt, write_period_csv, partial(write_portal, locations="i-80")]
)
def test_one_vehicle_an_hour_off_is_counted_as_stray_rows_not_a_recording(
    tmp_path: Path, write
) -> None:
    # e03: 25 vehicles of i-80 0400 (frames 0..99, five lanes) and vehicle 26's 20 rows with
    # Global_Time an hour late: they name i-80's 0500-0515, which no other group holds; on main
    # a recording of 1 vehicle, nothing counted. One vehicle is no recording: 20 stray rows.
    rows = [
        make_row(
            v, f, local_x_ft=6.0 + 12.0 * (v % 5), local_y_ft=40.0 * (v // 5) + 3.5 * f,
            v_vel_fps=35.0, start_ms=I80_FIRST.start_epoch_ms, lane_id=v % 5 + 1,
        )
        for v in range(1, 27)
        for f in range(100 if v < 26 else 20)
    ]  # fmt: skip
    for row in rows[2500:]:
        row[s.GLOBAL_TIME] += 3_600_000
    path = write(tmp_path / "raw" / "i-80" / "trajectories-0400-0415.csv", rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    line = 2501 if write is write_txt else 2502
    assert "dropped 20 rows: Global_Time off its recording" in result.stdout
    assert f"(first: {path}, line {line})." in result.stdout
    built = manifest(out)
    assert [r["name"] for r in built["recordings"]] == ["i-80_0400-0415"]
    assert built["counts"]["rows_dropped"][NgsimDrop.GLOBAL_TIME.value] == 20
    assert built["counts"]["rows"] == 2_500


def test_an_optional_column_empty_in_every_row_is_said(tmp_path: Path, rows: list[dict]) -> None:
    # Time_Headway emptied in every row (d6: swapped with the empty O_Zone): the rows are kept,
    # and a warning names the file and the column, in the manifest too.
    path = write_period_csv(tmp_path / "a.csv", [{**row, ns.TIME_HEADWAY: None} for row in rows])
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    warning = f"{path}: column Time_Headway is empty in every row"
    assert warning in result.stderr
    assert [w for w in manifest(out)["warnings"] if w.startswith(warning)] != []
    assert manifest(out)["counts"]["rows"] == 1_000
    tracks = pl.read_parquet(out / "tracks" / "us-101_0750am-0805am.parquet")
    assert tracks[s.TIME_HEADWAY_S].null_count() == tracks.height


def test_no_warning_where_the_optional_columns_hold_values(
    tmp_path: Path, rows: list[dict]
) -> None:
    rows = [{**row, ns.SPACE_HEADWAY: None} for row in rows[:-1]] + rows[-1:]  # one value left
    path, out = write_period_csv(tmp_path / "a.csv", rows), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    assert "empty in every row" not in result.stderr and manifest(out)["warnings"] == []


def test_local_x_swapped_with_space_headway_is_refused(tmp_path: Path, rows: list[dict]) -> None:
    # d3: each vehicle in its lane (Lane_ID v % 5 + 1, Local_X at its centre), 120 ft behind its
    # leader; Local_X and Space_Headway swapped in every row: each value plausible, every lane's
    # vehicles 36.6 m from the left edge.
    rows = [{**row, ns.SPACE_HEADWAY: 120.0} for row in rows]
    good = write_txt(tmp_path / "good" / "a.txt", rows)
    assert invoke("build", good, "--out", tmp_path / "built").exit_code == 0
    swapped = [
        {**r, ns.LOCAL_X: r[ns.SPACE_HEADWAY], ns.SPACE_HEADWAY: r[ns.LOCAL_X]} for r in rows
    ]
    path, out = write_txt(tmp_path / "a.txt", swapped), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        "recording us-101/0750am-0805am: its lateral positions are not where its lanes are",
        "5 of 5 lanes have their median Local_X more than a lane width outside the lane",
        "(lane 1: 36.6 m, the lane at 0.0 to 3.7 m)",
    )  # fmt: skip


@pytest.mark.parametrize(
    ("column", "written", "name"),
    [(ns.V_ACC, "-1,2", "v_Acc"), (ns.V_ACC, "0,5", "v_Acc"), (ns.V_ACC, "1,,5", "v_Acc"),
     (ns.LOCAL_X, ",25", "Local_X")],
)  # fmt: skip
def test_a_comma_that_separates_no_thousands_is_refused(
    tmp_path: Path, rows: list[dict], column: str, written: str, name: str
) -> None:
    # i50 e13: every comma was stripped, so that v_Acc '-1,2' (a decimal comma) was read as -12
    # ft/s² and Local_X ',25' as 25 ft, with nothing said.
    rows[7] = {**rows[7], column: written}
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        f"line 8: column {name}: {written!r} is not a number",
    )  # fmt: skip


# --- i50: a file cut at a line end (a partial copy or download) -------------------------------


def _cut_after(path: Path, rows_kept: int) -> None:
    """Keep the header (of a CSV) and the first `rows_kept` rows, each line with its line end."""
    lines = path.read_bytes().splitlines(keepends=True)
    header = int(path.suffix == ".csv")
    path.write_bytes(b"".join(lines[: header + rows_kept]).rstrip(b"\r\n") + b"\n")


def _cut_warning(path: Path, out: Path, cut: bool) -> str | None:
    """The build's one warning naming `path` (on stderr and in the manifest alike), if `cut`."""
    result = invoke("build", path, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    warnings = [w for w in manifest(out)["warnings"] if w.startswith(f"{path}: ")]
    assert [f"warning: {w}" for w in warnings] == [
        line for line in result.stderr.splitlines() if line.startswith(f"warning: {path}: ")
    ]
    assert len(warnings) == int(cut), warnings
    return warnings[0] if warnings else None


@pytest.mark.parametrize(
    ("write", "suffix", "line"), [(write_txt, "txt", 950), (write_period_csv, "csv", 951),
                                  (write_portal, "csv", 951)]
)  # fmt: skip
def test_a_file_cut_inside_a_vehicle_is_said(
    tmp_path: Path, rows: list[dict], write, suffix: str, line: int
) -> None:
    # i50 e02: read in silence. Vehicles 1..10 of frames 0..99 (Total_Frames 100) in NGSIM's
    # order; cut after row 950, vehicle 10 at frame 49. The whole file, its last vehicle with
    # a gap inside (frames 40..49 lost, Total_Frames counting them, as in NGSIM), is no cut.
    gap = [row for row in rows if not (row[s.VEHICLE_ID] == 10 and 40 <= row[s.FRAME_ID] < 50)]
    path, out = write(tmp_path / f"trajectories-0750am-0805am.{suffix}", gap), tmp_path / "out"
    assert _cut_warning(path, out, cut=False) is None
    path = write(path, rows)
    _cut_after(path, 950)
    assert _cut_warning(path, out, cut=True) == (
        f"{path}: its last vehicle, 10 of us-101/0750am-0805am (line {line}), spans frames 0 "
        "to 49: 50 frames where its Total_Frames says 100, while the other 9 vehicles span all "
        "of theirs: is the file cut short (a partial copy or download)? Any vehicle after it is "
        "missing from the build"
    )
    assert manifest(out)["counts"]["rows_read"] == 950


def test_a_file_cut_between_two_vehicles_is_said(tmp_path: Path, rows: list[dict]) -> None:
    # Cut after vehicle 9, whole: nothing is short of its Total_Frames, but vehicle 5 names
    # vehicle 10 as its Preceding (v + 5: its lane, 40 ft ahead), and no vehicle above 9 is in
    # the file.
    leader = {ns.SPACE_HEADWAY: 40.0, ns.TIME_HEADWAY: 40.0 / 35.0}
    rows = [
        {**row, s.PRECEDING: row[s.VEHICLE_ID] + 5, **leader} if row[s.VEHICLE_ID] <= 5 else row
        for row in rows
    ]
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    assert _cut_warning(path, out, cut=False) is None  # vehicle 10 is in the file
    _cut_after(path, 900)
    assert _cut_warning(path, out, cut=True) == (
        f"{path}: its last vehicle, 9 of us-101/0750am-0805am (line 900), is whole, but the "
        "rows of its recording name vehicles up to 10 as Preceding or Following, and none above "
        "9 is in the file: is the file cut short (a partial copy or download)? Any vehicle after "
        "it is missing from the build"
    )


def test_a_portal_query_of_a_time_window_is_no_cut(tmp_path: Path) -> None:
    # A query of the portal, "Frame_ID between 40 and 159", in the portal's order: vehicle v
    # drives frames 10 v .. 10 v + 149 (Total_Frames 150), so that the window cuts the record
    # of every one of them, the last (vehicle 10, frames 100..159) too.
    rows = [
        make_row(
            v,
            f,
            6.0 + 12.0 * (v % 5),
            3.5 * f - 30.0 * v,
            35.0,
            total_frames=150,
            lane_id=v % 5 + 1,
        )  # fmt: skip
        for v in range(1, 11)
        for f in range(10 * v, 10 * v + 150)
        if 40 <= f < 160
    ]
    path, out = write_portal(tmp_path / "query.csv", rows), tmp_path / "out"
    assert _cut_warning(path, out, cut=False) is None
    assert manifest(out)["counts"]["samples"] > 0


@pytest.mark.parametrize("lane", [0, 3])
def test_one_lane_id_in_every_row_is_refused(tmp_path: Path, rows: list[dict], lane: int) -> None:
    # e07: Lane_ID one value in every row, vehicles 12 ft apart across five lanes (Local_X 6 to
    # 54 ft): lane 0 is no freeway lane the lane check judges, and lane 3's median Local_X, the
    # road's middle, lies in lane 3; but one lane cannot hold rows 14.6 m apart.
    path, out = (
        write_txt(tmp_path / "a.txt", [{**r, s.LANE_ID: lane} for r in rows]),
        tmp_path / "out",
    )
    assert_failed_cleanly(
        invoke("build", path, "--out", out), out, {}, path,
        f"a.txt: recording us-101/0750am-0805am: Lane_ID is {lane} in 100.0% of its 1,000 rows, "
        "whose Local_X spread over 14.6 m (4.0 lane widths: 1.8 to 16.5 m, the 5th and 95th "
        "percentiles): one lane cannot hold them; is Lane_ID one value in every row, or another "
        "column's?",
    )  # fmt: skip
