"""`ngsim-graphs build` and `stats` through typer's CliRunner: exit codes, messages, no leftovers.

Every bad input must give a non-zero exit, one error line on stderr naming the file (and the line
where it applies), nothing on stdout, and no build output: `--out` is absent afterwards (or
exactly as it was), and no hidden `.NAME.partial-*` / `.NAME.old-*` sibling remains.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import straight_track, write_period_csv, write_portal, write_txt
from typer.testing import CliRunner, Result

from ngsim_cli.ngsim import app
from ngsim_graphs import schema as s

# A wide terminal so that table cells are not cut; errors are checked on a narrow one (they must
# stay one line however long the path is).
WIDE = {"COLUMNS": "200"}
NARROW = {"COLUMNS": "60"}


def invoke(*args: object, env: dict[str, str] = WIDE) -> Result:
    return CliRunner(env=env).invoke(app, [str(a) for a in args])


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under `root` (relative path -> bytes); empty when `root` does not exist."""
    if not root.exists():
        return {}
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def error_line(result: Result) -> str:
    """The single non-blank stderr line of a handled failure."""
    assert result.exit_code != 0, result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)  # handled, no crash
    assert result.stdout == ""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    return lines[0]


def assert_failed_cleanly(
    result: Result, out: Path, before: dict[str, bytes], path: Path, *fragments: str
) -> str:
    line = error_line(result)
    assert str(path) in line
    for fragment in fragments:
        assert fragment in line, line
    if before:
        assert snapshot(out) == before
    else:
        assert not out.exists()
    assert leftovers(out) == []
    return line


@pytest.fixture
def rows() -> list[dict]:
    """Two vehicles of us-101 0750am, frames 10..39: 60 rows, 2 tracks, 30 grid rows (0.2 s)."""
    return straight_track(1, range(10, 40), x_ft=6.0, lane_id=1) + straight_track(
        2, range(10, 40), x_ft=18.0, speed_fps=40.0
    )


def _rewrite_csv(path: Path, edit: Callable[[list[list[str]]], None]) -> Path:
    table = list(csv.reader(io.StringIO(path.read_text())))
    edit(table)
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerows(table)
    path.write_text(buffer.getvalue())
    return path


# --- bad inputs ------------------------------------------------------------------------------


def test_missing_column(tmp_path: Path, rows: list[dict]) -> None:
    header = tuple(name for name in s.PERIOD_CSV_HEADER if name != "Local_Y")
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    assert_failed_cleanly(result, out, {}, path, "line 1", "missing column Local_Y")


def test_missing_column_hint_does_not_suggest_another_required_column(
    tmp_path: Path, rows: list[dict]
) -> None:
    header = tuple(name for name in s.PERIOD_CSV_HEADER if name != "Local_Y")
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    line = error_line(invoke("build", path, "--out", tmp_path / "out"))
    assert "local_x" not in line.lower()


def test_misspelled_column_names_the_found_header(tmp_path: Path, rows: list[dict]) -> None:
    header = tuple("Lcal_Y" if name == "Local_Y" else name for name in s.PERIOD_CSV_HEADER)
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    line = assert_failed_cleanly(result, out, {}, path, "line 1", "missing column Local_Y")
    assert "'lcal_y'" in line.lower() and "misspelled?" in line


def test_misspelled_column_hint_keeps_the_file_spelling(tmp_path: Path, rows: list[dict]) -> None:
    header = tuple("Lcal_Y" if name == "Local_Y" else name for name in s.PERIOD_CSV_HEADER)
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    assert "'Lcal_Y'" in error_line(invoke("build", path, "--out", tmp_path / "out"))


@pytest.mark.parametrize("fmt", ["csv", "txt", "portal"])
def test_non_numeric_value_names_line_and_column(
    tmp_path: Path, rows: list[dict], fmt: str
) -> None:
    rows[6] = {**rows[6], s.LOCAL_Y: "abc"}  # data row 7
    if fmt == "txt":
        path, line_no = write_txt(tmp_path / "a.txt", rows), 7
    elif fmt == "csv":
        path, line_no = write_period_csv(tmp_path / "a.csv", rows), 8  # after the header
    else:
        path, line_no = write_portal(tmp_path / "a.csv", rows), 8  # BOM + CRLF change nothing
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    assert_failed_cleanly(
        result, out, {}, path, f"line {line_no}:", "column Local_Y", "'abc' is not a number"
    )


def test_non_numeric_value_line_counts_blank_lines(tmp_path: Path, rows: list[dict]) -> None:
    rows[6] = {**rows[6], s.LOCAL_Y: "abc"}
    path = write_period_csv(tmp_path / "a.csv", rows)
    lines = path.read_text().split("\n")
    lines.insert(3, "")  # a blank line 4 moves the bad row from line 8 to line 9
    path.write_text("\n".join(lines))
    out = tmp_path / "out"
    assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, "line 9:", "Local_Y")


def test_truncated_last_line_csv(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", rows)
    text = path.read_text()
    last_start = text.rstrip("\n").rfind("\n") + 1
    path.write_text(text[: last_start + 25])  # header + 59 full rows + a cut 61st line
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    assert_failed_cleanly(result, out, {}, path, "line 61:", "5 fields where the header has 24 (truncated line?)")


def test_truncated_last_line_txt(tmp_path: Path, rows: list[dict]) -> None:
    path = write_txt(tmp_path / "a.txt", rows)
    text = path.read_text()
    path.write_text(text[: text.rfind("\n") + 1 + 40])  # 59 full rows + a cut 60th line
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    assert_failed_cleanly(result, out, {}, path, "line 60:", "where 18 were expected")


@pytest.mark.parametrize("name", ["a.csv", "a.txt"])
def test_empty_file(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(b"")
    out = tmp_path / "out"
    assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, "empty file")


@pytest.mark.parametrize("writer", [write_period_csv, write_portal])
def test_header_only_csv(tmp_path: Path, writer: Callable[[Path, list], Path]) -> None:
    path = writer(tmp_path / "a.csv", [])
    out = tmp_path / "out"
    assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, "no data rows")


def test_directory_without_ngsim_files(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "README.txt").write_text("NGSIM trajectories, downloaded from the portal.\nSee below.\n")
    out = tmp_path / "out"
    result = invoke("build", raw, "--out", out)
    assert_failed_cleanly(result, out, {}, raw, "no NGSIM trajectory files")


@pytest.mark.parametrize(
    ("name", "content"),
    [("a.json", '{"vehicles": [1, 2, 3]}\n'), ("a.csv", "a,b,c\n1,2,3\n4,5,6\n")],
)
def test_file_of_another_format(tmp_path: Path, name: str, content: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, {}, path, "line 1:", "not an NGSIM trajectory file")


def test_path_that_does_not_exist(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.csv"
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, {}, path, "no such file or directory")


def test_portal_without_chosen_locations_lists_what_it_holds(
    tmp_path: Path, rows: list[dict]
) -> None:
    path = write_portal(tmp_path / "portal.csv", rows, locations="lankershim")
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(
        result, out, {}, path, "none of the chosen locations (us-101, i-80)", "it holds: lankershim"
    )


def test_row_with_more_fields_than_header(tmp_path: Path, rows: list[dict]) -> None:
    path = _rewrite_csv(write_period_csv(tmp_path / "a.csv", rows), lambda t: t[4].append("7"))
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, {}, path, "line 5:", "25 fields where the header has 24 (an unquoted comma?)")


def test_row_with_fewer_fields_than_header_mid_file(tmp_path: Path, rows: list[dict]) -> None:
    cut_line_6 = lambda table: table.__setitem__(5, table[5][:8])  # noqa: E731
    path = _rewrite_csv(write_period_csv(tmp_path / "a.csv", rows), cut_line_6)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, {}, path, "line 6:", "8 fields where the header has 24")


def test_bad_second_input_leaves_previous_build(tmp_path: Path, rows: list[dict]) -> None:
    good = write_txt(tmp_path / "good.txt", rows)
    out = tmp_path / "out"
    assert invoke("build", good, "--out", out).exit_code == 0
    before = snapshot(out)
    bad = tmp_path / "bad.txt"
    bad.write_text(good.read_text()[:-30])
    result = invoke("build", good, bad, "--out", out, "--overwrite")
    assert_failed_cleanly(result, out, before, bad, "line 60:")


# --- successful builds -----------------------------------------------------------------------


def _table_row(stdout: str, label: str) -> list[str]:
    line = next(line for line in stdout.splitlines() if label in line)
    return [cell.strip() for cell in line.split("│")[1:-1]]


def test_build_prints_summary_table(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    # location, period, rows (10 Hz), dups (exact), conflicts, gaps, tracks, grid rows (0.2 s)
    assert _table_row(result.stdout, "0750am-0805am") == [
        "us-101", "0750am-0805am", "60", "0", "0", "0", "2", "30"
    ]  # fmt: skip
    summary = "60 rows read, 0 of other locations, 0 with empty required fields dropped."
    assert summary in result.stdout
    assert (out / "manifest.json").is_file()
    assert (out / "tracks" / "us-101_0750am-0805am.parquet").is_file()
    assert leftovers(out) == []


def test_build_reports_skipped_files_of_a_directory(tmp_path: Path, rows: list[dict]) -> None:
    raw = tmp_path / "raw"
    write_txt(raw / "trajectories-0750am-0805am.txt", rows)
    (raw / "README.txt").write_text("Not data.\n")
    result = invoke("build", raw, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    assert f"skipped (not NGSIM): {(raw / 'README.txt').resolve()}" in result.stdout


def test_build_into_non_empty_directory_needs_overwrite(tmp_path: Path, rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", rows)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    (out / "sub").mkdir()
    (out / "sub" / "x.bin").write_bytes(b"\x00\x01")
    before = snapshot(out)

    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, before, out, "not empty", "--overwrite")

    result = invoke("build", path, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert "manifest.json" in snapshot(out)
    assert "notes.txt" not in snapshot(out) and "sub/x.bin" not in snapshot(out)
    assert "tracks/us-101_0750am-0805am.parquet" in snapshot(out)
    assert leftovers(out) == []


# --- stats -----------------------------------------------------------------------------------


@pytest.fixture
def finished_build(tmp_path: Path, rows: list[dict]) -> Path:
    out = tmp_path / "out"
    result = invoke("build", write_txt(tmp_path / "a.txt", rows), "--out", out)
    assert result.exit_code == 0, result.output
    return out


def test_stats_table(finished_build: Path) -> None:
    result = invoke("stats", finished_build)
    assert result.exit_code == 0, result.output
    # recording, vehicles, tracks, rows 0.2 s
    row = _table_row(result.stdout, "us-101 0750am-0805am")
    assert row == ["us-101 0750am-0805am", "2", "2", "30"]


def test_stats_json(finished_build: Path) -> None:
    result = invoke("stats", finished_build, "--json")
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)  # stdout holds one JSON document and nothing else
    assert document["counts"] == {
        "rows_read": 60,
        "rows_other_locations": 0,
        "rows_missing_values": 0,
        "rows": 60,
        "exact_duplicates": 0,
        "conflicting_duplicates": 0,
        "gaps": 0,
        "tracks": 2,
        "grid_rows": 30,
    }
    [recording] = document["recordings"]
    assert (recording["location"], recording["period"]) == ("us-101", "0750am-0805am")
    assert (recording["vehicles"], recording["tracks"], recording["grid_rows"]) == (2, 2, 30)


def test_stats_without_manifest(tmp_path: Path) -> None:
    folder = tmp_path / "half"
    (folder / "tracks").mkdir(parents=True)
    for flag in ((), ("--json",)):
        line = error_line(invoke("stats", folder, *flag, env=NARROW))
        assert str(folder) in line and "not a finished build" in line and "manifest.json" in line


def test_stats_on_missing_directory(tmp_path: Path) -> None:
    line = error_line(invoke("stats", tmp_path / "nowhere"))
    assert str(tmp_path / "nowhere") in line and "not a directory" in line


@pytest.mark.parametrize(
    ("text", "fragment"),
    [('{"format_version": 1,\n', "line 2: unreadable manifest"), ('{"format_version": 99}', "99")],
)
def test_stats_on_bad_manifest(finished_build: Path, text: str, fragment: str) -> None:
    manifest = finished_build / "manifest.json"
    manifest.write_text(text)
    line = error_line(invoke("stats", finished_build))
    assert str(manifest) in line and fragment in line


# --- help ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        ((), ("build", "stats", "synth")),
        (("build",), ("--out", "--locations", "--overwrite")),
        (("stats",), ("--json",)),
        (("synth",), ("--format", "--recordings", "--minutes", "--seed", "--quirks")),
    ],
)
def test_help(args: tuple[str, ...], expected: tuple[str, ...]) -> None:
    result = invoke(*args, "--help")
    assert result.exit_code == 0, result.output
    assert "Usage" in result.stdout
    for word in expected:
        assert word in result.stdout
