"""Format detection and parsing of each NGSIM format, each quirk, and each kind of bad input."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from conftest import make_row, set_budget, straight_track, write_period_csv, write_portal, write_txt

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim import files
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.files import ROW, read_raw_file
from ngsim_graphs.sources.ngsim.formats import find_raw_files, sniff_format

US = ("us-101", "i-80")


@pytest.fixture(autouse=True, params=["in memory", "through a scratch folder, line by line"])
def reading(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """Every test twice: the file parsed whole in memory, and as a build parses it, a chunk of
    its text at a time into a scratch folder; 100-byte chunks, shorter than a line, make a
    chunk of each line (and of the header): the same rows, line numbers and errors."""
    if request.param != "in memory":
        set_budget(monkeypatch, text_chunk_bytes=100)
        scratch = tmp_path / "scratch"
        monkeypatch.setitem(
            globals(),
            "read_raw_file",
            lambda path, locations: files.read_raw_file(path, locations, scratch),
        )
    return request.param


def values(path: Path) -> list[tuple]:
    return read_raw_file(path, US).frame.drop(ROW, s.LOCATION).collect().rows()


def test_each_format_is_detected_from_content_not_name(tmp_path: Path) -> None:
    rows = straight_track(1, range(3))
    # Names that lie about the format: detection must read the first line.
    portal = write_portal(tmp_path / "a.txt", rows)
    period = write_period_csv(tmp_path / "b.txt", rows)
    text = write_txt(tmp_path / "c.csv", rows)
    assert sniff_format(portal) is RawFormat.PORTAL
    assert sniff_format(period) is RawFormat.CSV
    assert sniff_format(text) is RawFormat.TXT


def test_three_formats_parse_to_the_same_values(tmp_path: Path) -> None:
    rows = straight_track(7, range(4), speed_fps=45.5) + [make_row(8, 2, local_y_ft=1156.25)]
    portal = values(write_portal(tmp_path / "p.csv", rows, quirks=True))
    period = values(write_period_csv(tmp_path / "c.csv", rows))
    text = values(write_txt(tmp_path / "t.txt", rows))
    assert portal == period == text
    assert text[-1][:2] == (8, 2)
    assert text[-1][ns.TXT_COLUMNS.index(ns.LOCAL_Y)] == 1156.25


def test_portal_quirks_bom_crlf_and_quoted_thousands(tmp_path: Path) -> None:
    path = write_portal(tmp_path / "p.csv", [make_row(1, 5, local_y_ft=1156.0, v_vel_fps=9.5)])
    raw = path.read_bytes()
    assert raw.startswith(b"\xef\xbb\xbf") and b"\r\n" in raw and b'"1,156"' in raw
    frame = read_raw_file(path, US).frame.collect()
    assert frame[ns.LOCAL_Y].to_list() == [1156.0]
    assert frame[ns.TIME_HEADWAY].to_list() == [9999.99]  # was "9,999.99"
    assert frame[s.GLOBAL_TIME].dtype == ns.RAW_SCHEMA[s.GLOBAL_TIME]
    assert frame[s.LOCATION].to_list() == ["us-101"]


def test_header_spelling_and_case_variants(tmp_path: Path) -> None:
    header = tuple(
        {"v_length": "v_Length", "Vehicle_ID": "VEHICLE_ID", "Local_Y": "local_y"}.get(h, h)
        for h in ns.PERIOD_CSV_HEADER
    )
    path = write_period_csv(
        tmp_path / "c.csv", straight_track(3, range(2)), header=header, crlf=True
    )
    frame = read_raw_file(path, US).frame.collect()
    assert frame[s.VEHICLE_ID].to_list() == [3, 3]
    assert frame[ns.V_LENGTH].to_list() == [15.0, 15.0]


def test_text_with_padding_blank_lines_and_no_final_newline(tmp_path: Path) -> None:
    path = write_txt(tmp_path / "t.txt", straight_track(2, range(3)), final_newline=False)
    lines = path.read_text().split("\n")
    path.write_text("\n".join([lines[0], "", "   ", *lines[1:]]))
    assert not path.read_bytes().endswith(b"\n")
    raw = read_raw_file(path, US)
    assert raw.rows_read == 3
    assert raw.frame.collect()[s.FRAME_ID].to_list() == [0, 1, 2]
    assert raw.frame.collect()[ROW].to_list() == [0, 3, 4]  # line numbers stay true to the file


def test_chunks_that_start_with_blank_lines_keep_line_numbers_true(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reading: str
) -> None:
    """A blank line (CRLF) after every other row, and chunks cut just before each blank line
    in turn (its first chunk ends there, so a later one starts with it): every row keeps its
    line's number."""
    if reading == "in memory":
        pytest.skip("chunks only")
    path = write_period_csv(tmp_path / "c.csv", straight_track(2, range(6)), crlf=True)
    lines = path.read_bytes().split(b"\r\n")
    path.write_bytes(b"\r\n".join(line + b"\r\n" * (i % 2) for i, line in enumerate(lines)))
    whole = files.read_raw_file(path, US).frame.collect()
    assert whole[ROW].to_list() == [0, 2, 3, 5, 6, 8]  # blank lines after rows 0, 2 and 4
    data = path.read_bytes()
    blank_starts = [i + 2 for i in range(len(data)) if data.startswith(b"\r\n\r\n", i)]
    assert len(blank_starts) == 4  # after rows 0, 2 and 4, and one at the end
    for size in blank_starts:
        set_budget(monkeypatch, text_chunk_bytes=size)
        scratch = tmp_path / f"scratch-{size}"
        assert files.read_raw_file(path, US, scratch).frame.collect().equals(whole)


def test_chunks_parsed_on_threads_give_one_thread_s_rows_and_first_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reading: str
) -> None:
    """Chunks (a line each) parsed on four threads: the rows of one thread, and a quote left
    open in an early chunk is the error, not the line too long that a later chunk, read while
    the early one was parsed, holds."""
    if reading == "in memory":
        pytest.skip("chunks only")
    path = write_portal(tmp_path / "p.csv", straight_track(1, range(30)), quirks=True)
    by_one = {}
    for threads in (1, 4):
        monkeypatch.setattr(pl, "thread_pool_size", lambda n=threads: n)  # threads.in_order
        by_one[threads] = read_raw_file(path, US).frame.collect()
        assert by_one[threads].height == 30
    assert by_one[4].equals(by_one[1])
    lines = path.read_bytes().split(b"\r\n")
    cut = lines[3][: lines[3].index(b'"') + 3]  # line 4: ...,"1,1
    path.write_bytes(b"\r\n".join([*lines[:3], cut, lines[4], b"0" * 5_000, *lines[5:]]))
    with pytest.raises(NgsimInputError, match=r"p\.csv, line 4: a quoted field is not closed"):
        read_raw_file(path, US)


def test_empty_fields_become_null(tmp_path: Path) -> None:
    rows = [make_row(1, 0), make_row(1, 1, v_acc=None, local_x=None)]
    frame = read_raw_file(write_portal(tmp_path / "p.csv", rows), US).frame.collect()
    assert frame[ns.V_ACC].to_list() == [0.0, None]
    assert frame[ns.LOCAL_X].to_list() == [18.0, None]


def test_location_filter_counts_and_keeps_chosen(tmp_path: Path) -> None:
    rows = [make_row(1, 0), make_row(1, 1), make_row(2, 0)]
    path = write_portal(tmp_path / "p.csv", rows, locations=["us-101", "lankershim", "i-80"])
    raw = read_raw_file(path, ("us-101",))
    assert raw.rows_read == 3 and raw.rows_other_locations == 2
    assert raw.locations_found == ("i-80", "lankershim", "us-101")
    assert raw.frame.collect()[s.LOCATION].to_list() == ["us-101"]


def test_file_without_chosen_locations_names_those_it_holds(tmp_path: Path) -> None:
    path = write_portal(tmp_path / "p.csv", [make_row(1, 0)], locations="peachtree")
    with pytest.raises(
        NgsimInputError, match=r"p\.csv: holds none of the chosen.*it holds: peachtree"
    ):
        read_raw_file(path, US)


def test_malformed_number_names_line_and_column(tmp_path: Path) -> None:
    rows = straight_track(1, range(4))
    rows[2][ns.V_VEL] = "3O.5"  # letter O for zero
    for path, line in (
        (write_portal(tmp_path / "p.csv", rows), 4),
        (write_txt(tmp_path / "t.txt", rows), 3),
    ):
        with pytest.raises(NgsimInputError) as err:
            read_raw_file(path, US)
        assert str(err.value) == f"{path}, line {line}: column v_Vel: '3O.5' is not a number"


@pytest.mark.parametrize("suffix", ["csv", "txt"])
def test_truncated_last_line(tmp_path: Path, suffix: str) -> None:
    rows = straight_track(1, range(3))
    path = tmp_path / f"cut.{suffix}"
    (write_period_csv if suffix == "csv" else write_txt)(path, rows)
    data = path.read_bytes().rstrip(b"\r\n")
    path.write_bytes(data[: len(data) - 40])
    with pytest.raises(NgsimInputError, match=r"cut\.\w+, line [34]: .*(truncated|fields)"):
        read_raw_file(path, US)


def test_more_fields_than_header_is_an_error(tmp_path: Path) -> None:
    path = write_period_csv(tmp_path / "c.csv", straight_track(1, range(3)))
    lines = path.read_text().splitlines()
    lines[2] += ",7"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        NgsimInputError,
        match=r"c\.csv, line 3: 25 fields where the header has 24 \(an unquoted comma\?\)",
    ):
        read_raw_file(path, US)


def test_missing_and_misspelled_columns(tmp_path: Path) -> None:
    header = tuple("Lcal_Y" if h == "Local_Y" else h for h in ns.PERIOD_CSV_HEADER)
    path = write_period_csv(tmp_path / "c.csv", [make_row(1, 0)], header=header)
    with pytest.raises(NgsimInputError, match=r"line 1: missing column Local_Y \(found 'Lcal_Y'"):
        read_raw_file(path, US)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "empty file"),
        (b"\xef\xbb\xbf\r\n  \r\n", "empty file"),
        (b'{"not": "ngsim"}\n', "not an NGSIM trajectory file"),
        (b"a,b,c\n1,2,3\n", "not an NGSIM trajectory file"),
        (b"1 2 3 4\n", "not an NGSIM trajectory file"),
    ],
)
def test_files_that_are_not_ngsim(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "x.csv"
    path.write_bytes(content)
    with pytest.raises(NgsimInputError, match=message):
        read_raw_file(path, US)


def test_directory_search_skips_other_files(tmp_path: Path) -> None:
    good = write_txt(tmp_path / "us-101" / "trajectories-0750am-0805am.txt", [make_row(1, 0)])
    (tmp_path / "README.txt").write_text("Read me first.\n")
    (tmp_path / "photo.jpg").write_bytes(b"\xff\xd8")
    files, skipped = find_raw_files([tmp_path])
    assert files == [good.resolve()]
    assert skipped == [tmp_path / "README.txt"]


def test_directory_without_ngsim_files(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("nothing here\n")
    with pytest.raises(NgsimInputError, match="no NGSIM trajectory files"):
        find_raw_files([tmp_path])
    with pytest.raises(NgsimInputError, match="no such file"):
        find_raw_files([tmp_path / "missing.csv"])


def test_whole_numbers_written_with_a_point_are_integers(tmp_path: Path) -> None:
    # Some exports write integer columns as floats ("2.0"); only a fraction is wrong.
    pointed = [{**make_row(1, f, lane_id="2.0"), s.FRAME_ID: f"{f}.0"} for f in range(3)]
    plain = [make_row(1, f) for f in range(3)]
    assert values(write_txt(tmp_path / "t.txt", pointed)) == values(
        write_txt(tmp_path / "u.txt", plain)
    )
    pointed[2] = {**pointed[2], s.LANE_ID: "2.5"}
    with pytest.raises(
        NgsimInputError, match=r"t\.txt, line 3: column Lane_ID: '2\.5' is not a whole"
    ):
        read_raw_file(write_txt(tmp_path / "t.txt", pointed), US)


@pytest.mark.parametrize("write", [write_txt, write_period_csv])
def test_thousands_separators_are_stripped(tmp_path: Path, write) -> None:
    # The portal's way (1-3 digits, then groups of exactly 3), in a .txt too; a CSV quotes them.
    rows = straight_track(1, range(2))
    rows[1] = {
        **rows[1],
        s.GLOBAL_TIME: f"{rows[1][s.GLOBAL_TIME]:,}",  # 1,118,846,993,100
        ns.GLOBAL_X: "-1,234.5",
        ns.SPACE_HEADWAY: "1,156",
        ns.TIME_HEADWAY: "9,999.99",
    }
    frame = read_raw_file(write(tmp_path / f"a.{write.__name__}", rows), US).frame.collect()
    columns = [s.GLOBAL_TIME, ns.GLOBAL_X, ns.SPACE_HEADWAY, ns.TIME_HEADWAY]
    assert frame.select(columns).row(1) == (1_118_846_993_100, -1234.5, 1156.0, 9999.99)


@pytest.mark.parametrize(
    "written",
    ["-1,2", "0,5", "1,,5", ",25", "1,23", "1,2345", "1234,567", "1,234,56", "1,234e2", "1,"],
)
def test_a_comma_that_separates_no_thousands_is_not_a_number(tmp_path: Path, written: str) -> None:
    # Every comma was stripped: '-1,2' (a decimal comma) read as -12, ',25' as 25.
    rows = straight_track(1, range(3))
    rows[1] = {**rows[1], ns.V_ACC: written}
    path = write_txt(tmp_path / "t.txt", rows)
    with pytest.raises(NgsimInputError) as err:
        read_raw_file(path, US)
    assert str(err.value) == f"{path}, line 2: column v_Acc: {written!r} is not a number"
