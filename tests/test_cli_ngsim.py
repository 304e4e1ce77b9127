"""`ngsim-graphs build` and `stats` through typer's CliRunner: exit codes, messages, no leftovers.

Every bad input must give a non-zero exit, one error line on stderr naming the file (and the line
where it applies), nothing on stdout, and no build output: `--out` is absent afterwards (or
exactly as it was), and no hidden `.NAME.partial-*` / `.NAME.old-*` sibling remains.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import polars as pl
import pytest
from conftest import straight_track, write_period_csv, write_portal, write_txt
from typer.testing import CliRunner, Result

from ngsim_cli import progress as progress_module
from ngsim_cli.ngsim import app
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.plotting import PLOT_NAMES
from ngsim_graphs.schema import SplitMode
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.plausibility import DROP_REASONS
from ngsim_graphs.synth.formats import write_synthetic

# A wide terminal so that table cells are not cut; errors are checked on a narrow one (they must
# stay one line however long the path is).
WIDE = {"COLUMNS": "200"}
NARROW = {"COLUMNS": "60"}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


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
def long_rows() -> list[dict]:
    """Two vehicles of us-101 0750am, frames 10..91: 164 rows, 2 tracks of 41 grid steps each,
    so one 8.2 s window (sample) each; by the vehicle split vehicle 1 trains, vehicle 2 validates."""
    return straight_track(1, range(10, 92), x_ft=6.0, lane_id=1) + straight_track(
        2, range(10, 92), x_ft=18.0, speed_fps=40.0
    )


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
    header = tuple(name for name in ns.PERIOD_CSV_HEADER if name != "Local_Y")
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    assert_failed_cleanly(result, out, {}, path, "line 1", "missing column Local_Y")


def test_missing_column_hint_does_not_suggest_another_required_column(
    tmp_path: Path, rows: list[dict]
) -> None:
    header = tuple(name for name in ns.PERIOD_CSV_HEADER if name != "Local_Y")
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    line = error_line(invoke("build", path, "--out", tmp_path / "out"))
    assert "local_x" not in line.lower()


def test_misspelled_column_names_the_found_header(tmp_path: Path, rows: list[dict]) -> None:
    header = tuple("Lcal_Y" if name == "Local_Y" else name for name in ns.PERIOD_CSV_HEADER)
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, env=NARROW)
    line = assert_failed_cleanly(result, out, {}, path, "line 1", "missing column Local_Y")
    assert "'lcal_y'" in line.lower() and "misspelled?" in line


def test_misspelled_column_hint_keeps_the_file_spelling(tmp_path: Path, rows: list[dict]) -> None:
    header = tuple("Lcal_Y" if name == "Local_Y" else name for name in ns.PERIOD_CSV_HEADER)
    path = write_period_csv(tmp_path / "a.csv", rows, header=header)
    assert "'Lcal_Y'" in error_line(invoke("build", path, "--out", tmp_path / "out"))


@pytest.mark.parametrize("fmt", ["csv", "txt", "portal"])
def test_non_numeric_value_names_line_and_column(
    tmp_path: Path, rows: list[dict], fmt: str
) -> None:
    rows[6] = {**rows[6], ns.LOCAL_Y: "abc"}  # data row 7
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
    rows[6] = {**rows[6], ns.LOCAL_Y: "abc"}
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
    assert_failed_cleanly(
        result, out, {}, path, "line 61:", "5 fields where the header has 24 (truncated line?)"
    )


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
    assert_failed_cleanly(
        result, out, {}, path, "line 5:", "25 fields where the header has 24 (an unquoted comma?)"
    )


def test_row_with_fewer_fields_than_header_mid_file(tmp_path: Path, rows: list[dict]) -> None:
    cut_line_6 = lambda table: table.__setitem__(5, table[5][:8])  # noqa: E731
    path = _rewrite_csv(write_period_csv(tmp_path / "a.csv", rows), cut_line_6)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, {}, path, "line 6:", "8 fields where the header has 24")


def test_bad_second_input_leaves_previous_build(tmp_path: Path, long_rows: list[dict]) -> None:
    good = write_txt(tmp_path / "good.txt", long_rows)
    out = tmp_path / "out"
    assert invoke("build", good, "--out", out).exit_code == 0
    before = snapshot(out)
    bad = tmp_path / "bad.txt"
    bad.write_text(good.read_text()[:-30])
    result = invoke("build", good, bad, "--out", out, "--overwrite")
    assert_failed_cleanly(result, out, before, bad, "line 164:")


# --- successful builds -----------------------------------------------------------------------


def _table_row(stdout: str, label: str) -> list[str]:
    line = next(line for line in stdout.splitlines() if label in line)
    return [cell.strip() for cell in line.split("│")[1:-1]]


def _table_rows(stdout: str, *first_cells: str) -> list[list[str]]:
    """The body rows of every table whose first cells are `first_cells`."""
    rows = [[cell.strip() for cell in line.split("│")[1:-1]] for line in stdout.splitlines()]
    return [row for row in rows if tuple(row[: len(first_cells)]) == first_cells]


def test_build_prints_summary_table(tmp_path: Path, long_rows: list[dict]) -> None:
    path = write_period_csv(tmp_path / "a.csv", long_rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    # location, period, rows (10 Hz), dups (exact), conflicts, gaps, tracks, grid rows (0.2 s),
    # samples train / val / test (one 8.2 s window per vehicle)
    assert _table_row(result.stdout, "0750am-0805am") == [
        "us-101", "0750am-0805am", "164", "0", "0", "0", "2", "82", "1", "1", "0"
    ]  # fmt: skip
    summary = "164 rows read, 0 of other locations, 0 with empty required fields dropped."
    assert summary in result.stdout
    assert (
        "samples: 1 train, 1 val, 0 test (2 in all; shares 50% / 50% / 0%: the vehicle split cuts "
        "each recording's Vehicle_IDs at 70% and 80% of its largest, not its samples, and "
        "vehicles give different numbers of samples: the last IDs entered last, and the "
        "recording's end cuts their tracks short)." in result.stdout
    )
    # Largest Vehicle_ID 2: cuts at round(1.4) = 1 and round(1.6) = 2, nothing left for test.
    assert "warning: the test split is empty: the vehicle split" in result.stderr
    assert (out / "manifest.json").is_file()
    assert (out / "tracks" / "us-101_0750am-0805am.parquet").is_file()
    assert leftovers(out) == []


def test_a_narrow_terminal_or_a_pipe_cuts_no_value(tmp_path: Path, long_rows: list[dict]) -> None:
    # On main an 80-column terminal cut the table's numbers ("52…") and a pipe broke lines
    # inside paths.
    path = write_txt(tmp_path / ("a-long-folder-name-" * 4) / "a.txt", long_rows)
    terminal = {"COLUMNS": "80", "TTY_COMPATIBLE": "1", "NO_COLOR": "1"}
    for env in (terminal, NARROW):
        out = tmp_path / "out"
        result = invoke("build", path, "--out", out, "--overwrite", env=env)
        assert result.exit_code == 0, result.output
        assert "…" not in result.stdout
        assert _table_row(result.stdout, "0750am-0805am") == [
            "us-101", "0750am-0805am", "164", "0", "0", "0", "2", "82", "1", "1", "0"
        ]  # fmt: skip
        assert "warning: the test split is empty" in result.stderr
        assert "rows read, 0 of other locations, 0 with empty required fields dropped.\n" in (
            result.stdout
        )


def test_build_reports_skipped_files_of_a_directory(tmp_path: Path, long_rows: list[dict]) -> None:
    raw = tmp_path / "raw"
    write_txt(raw / "trajectories-0750am-0805am.txt", long_rows)
    (raw / "README.txt").write_text("Not data.\n")
    result = invoke("build", raw, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    assert f"skipped (not NGSIM): {(raw / 'README.txt').resolve()}" in result.stderr
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["skipped_files"] == [str((raw / "README.txt").resolve())]


def test_a_damaged_first_line_does_not_skip_a_file(tmp_path: Path, long_rows: list[dict]) -> None:
    # On main one damaged character in a .txt's first line skipped the file as "not NGSIM": its
    # recording was lost, exit 0, and the manifest did not name the file.
    raw = tmp_path / "raw"
    write_txt(raw / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    damaged = write_txt(raw / "i-80" / "trajectories-0400-0415.txt", long_rows)
    text = damaged.read_text()
    at = text.index(".") - 1  # a digit of the first line's first decimal number
    damaged.write_text(text[:at] + "O" + text[at + 1 :])
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", raw, "--out", out), out, {}, damaged, "line 1: column", "is not a number"
    )


def test_a_csv_whose_header_is_damaged_is_refused(tmp_path: Path, long_rows: list[dict]) -> None:
    raw = tmp_path / "raw"
    write_txt(raw / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    damaged = write_period_csv(raw / "i-80" / "trajectories-0400-0415.csv", long_rows)
    lines = damaged.read_text().splitlines(keepends=True)
    damaged.write_text("\x00garbled\n" + "".join(lines[1:]))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", raw, "--out", out), out, {}, damaged,
        "line 1: the first line is no header of NGSIM's columns", "header damaged or missing",
    )  # fmt: skip


def test_build_into_non_empty_directory_needs_overwrite(
    tmp_path: Path, long_rows: list[dict]
) -> None:
    path = write_period_csv(tmp_path / "a.csv", long_rows)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    (out / "sub").mkdir()
    (out / "sub" / "x.bin").write_bytes(b"\x00\x01")
    before = snapshot(out)

    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, before, out, "not empty")
    # Not a build: --overwrite does not make it ours to delete.
    result = invoke("build", path, "--out", out, "--overwrite")
    assert_failed_cleanly(result, out, before, out, "notes.txt", "not a build")

    (out / "notes.txt").unlink()
    (out / "sub" / "x.bin").unlink()
    (out / "sub").rmdir()
    assert invoke("build", path, "--out", out).exit_code == 0  # an empty directory is fine
    result = invoke("build", path, "--out", out)
    assert_failed_cleanly(result, out, snapshot(out), out, "--overwrite")
    assert invoke("build", path, "--out", out, "--overwrite").exit_code == 0  # a build is ours
    assert "tracks/us-101_0750am-0805am.parquet" in snapshot(out)
    assert leftovers(out) == []


# --- stats -----------------------------------------------------------------------------------


@pytest.fixture
def finished_build(tmp_path: Path, long_rows: list[dict]) -> Path:
    out = tmp_path / "out"
    result = invoke("build", write_txt(tmp_path / "a.txt", long_rows), "--out", out)
    assert result.exit_code == 0, result.output
    return out


def test_stats_table(finished_build: Path) -> None:
    result = invoke("stats", finished_build)
    assert result.exit_code == 0, result.output
    # recording, vehicles, tracks, rows 0.2 s, samples train / val / test
    row = _table_row(result.stdout, "us-101 0750am-0805am")
    assert row == ["us-101 0750am-0805am", "2", "2", "82", "1", "1", "0"]
    # 82 grid rows: 41 steps of vehicle 1 at 9.144 m/s (30 ft/s) and 41 of vehicle 2 at 40 ft/s
    assert _table_row(result.stdout, "speed m/s")[:2] == [
        "speed m/s",
        f"{(30 + 40) / 2 * 0.3048:.2f}",
    ]
    # one sample per vehicle; the other vehicle is its one target, recorded for the whole future
    assert _table_rows(result.stdout, "train", "1")[0] == ["train", "1", "50.0%", "1", "1 (100.0%)"]
    assert _table_rows(result.stdout, "test", "0")[0][:5] == ["test", "0", "0.0%", "0", "0 (-)"]
    # 16 steps, both vehicles at each: 32 nodes, 32 ego<->actor edges, 2 x 15 temporal edges
    assert _table_rows(result.stdout, "train", "nodes")[0][2:] == [
        "32.0",
        "32",
        "32.0",
        "32.0",
        "32.0",
        "32",
    ]
    assert _table_rows(result.stdout, "train", "temporal edges")[0][2] == "30.0"
    assert _table_row(result.stdout, "limits.max_speed_mps") == ["limits.max_speed_mps", "70.0"]
    assert _table_rows(result.stdout, "read") == [["read", "164", "100.0%"]]
    assert _table_rows(result.stdout, "exact duplicates") == [["exact duplicates", "0", "0.0%"]]
    # the build's warning is said again, on stderr
    assert result.stderr.startswith("warning: the test split is empty: the vehicle split")


def test_stats_json(finished_build: Path) -> None:
    result = invoke("stats", finished_build, "--json")
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)  # stdout holds one JSON document and nothing else
    assert document["counts"] == {
        "rows_read": 164,
        "rows_other_locations": 0,
        "rows_missing_values": 0,
        # the shared reasons and NGSIM's own
        "rows_dropped": dict.fromkeys([*(r.value for r in s.DropReason), *DROP_REASONS], 0),
        "rows": 164,
        "exact_duplicates": 0,
        "conflicting_duplicates": 0,
        "position_jumps": 0,
        "gaps": 0,
        "tracks": 2,
        "grid_rows": 82,
        # 12 ft apart sideways and f ft along y at frame f: within 25 m up to frame 81, so at the
        # 36 grid frames 10, 12, ..., 80
        "proximity_edges": 36,
        "samples": 2,
        "cslstm_rows": None,  # the aigem protocol: no CS-LSTM rows
    }
    [recording] = document["recordings"]
    assert (recording["location"], recording["period"]) == ("us-101", "0750am-0805am")
    assert (recording["vehicles"], recording["tracks"], recording["grid_rows"]) == (2, 2, 82)
    assert document["samples"] == {"train": 1, "val": 1, "test": 0}
    assert document["graph_size"]["test"]["n_nodes"] == {
        "count": 0, "mean": None, "std": None, "min": None, "p5": None, "p50": None, "p95": None, "max": None
    }  # fmt: skip
    assert document["targets"]["test"] == {
        "targets": 0,
        "full_future": 0,
        "full_future_share": None,
    }
    assert document["targets"]["train"] == {
        "targets": 1,
        "full_future": 1,
        "full_future_share": 1.0,
    }
    assert document["kinematics"]["speed_mps"]["count"] == 82
    assert document["plots"] == []


def test_stats_plots_of_a_build_with_an_empty_split(finished_build: Path, tmp_path: Path) -> None:
    result = invoke("stats", finished_build, "--json", "--plots", tmp_path / "plots")
    assert result.exit_code == 0, result.output
    paths = [Path(p) for p in json.loads(result.stdout)["plots"]]
    assert len(paths) == 5 and all(p.read_bytes().startswith(PNG_SIGNATURE) for p in paths)


def test_stats_plots_into_a_file(finished_build: Path, tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.write_text("mine\n")
    line = error_line(invoke("stats", finished_build, "--plots", target))
    assert str(target) in line and "cannot write plots" in line


def test_stats_plots_never_replace_a_file_that_is_not_ours(
    finished_build: Path, tmp_path: Path
) -> None:
    """A heading.png of the user's stops the call before anything is written, as `aigem evaluate
    --plots` does (one rule: plots.json lists the pictures that are ours to replace)."""
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("my notes\n")
    (folder / "heading.png").write_text("my own heading.png, not a plot\n")
    before = snapshot(folder)
    result = invoke("stats", finished_build, "--plots", folder)
    assert result.exit_code == 1
    assert error_line(result) == (
        f"error: {folder / 'heading.png'}: exists and was not written by `ngsim-graphs stats "
        "--plots`; move it or choose another --plots folder"
    )
    assert snapshot(folder) == before
    (folder / "heading.png").rename(folder / "my-heading.png")
    for _ in range(2):  # the second call replaces the first's pictures: they are ours
        result = invoke("stats", finished_build, "--plots", folder)
        assert result.exit_code == 0, result.output
    pictures = [f"{name}.png" for name in PLOT_NAMES]
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["notes.txt", "my-heading.png", "plots.json", *pictures]
    )
    assert json.loads((folder / "plots.json").read_text())["pictures"] == sorted(pictures)
    assert (folder / "notes.txt").read_text() == "my notes\n"


def test_stats_without_manifest(tmp_path: Path) -> None:
    folder = tmp_path / "half"
    (folder / "tracks").mkdir(parents=True)
    for flag in ((), ("--json",)):
        line = error_line(invoke("stats", folder, *flag, env=NARROW))
        assert str(folder) in line and "an unfinished build" in line and "manifest.json" in line


def test_stats_on_missing_directory(tmp_path: Path) -> None:
    line = error_line(invoke("stats", tmp_path / "nowhere"))
    assert str(tmp_path / "nowhere") in line and "no such build directory" in line


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
        (
            ("build",),
            (
                "--out",
                "--locations",
                "--overwrite",
                "--stride-s",
                "--d-sense-m",
                "--d-min-m",
                "--split",
                "vehicle|time|random",
                "--seed",
                "--ego-target",
                "--no-ego-target",
            ),
        ),
        (("stats",), ("--json", "--plots")),
        (("synth",), ("--format", "--recordings", "--minutes", "--seed", "--quirks")),
    ],
)
def test_help(args: tuple[str, ...], expected: tuple[str, ...]) -> None:
    result = invoke(*args, "--help")
    assert result.exit_code == 0, result.output
    assert "Usage" in result.stdout
    for word in expected:
        assert word in result.stdout


# --- build options and stats on synthetic traffic --------------------------------------------


@pytest.fixture(scope="module")
def synthetic_raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """30 s of one synthetic recording: a few hundred samples, enough windows in every split."""
    raw = tmp_path_factory.mktemp("synthetic") / "raw"
    write_synthetic(raw, SynthConfig(recordings=1, minutes=0.5, seed=3))
    return raw


@pytest.fixture(scope="module")
def synthetic_build(synthetic_raw: Path) -> Path:
    out = synthetic_raw.parent / "default"
    result = invoke("build", synthetic_raw, "--out", out)
    assert result.exit_code == 0, result.output
    return out


def _manifest(build: Path) -> dict:
    return json.loads((build / "manifest.json").read_text())


def _samples(build: Path, split: str) -> pl.DataFrame:
    return pl.read_parquet(build / "samples" / f"{split}.parquet")


def test_build_prints_samples_per_split(synthetic_raw: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = invoke("build", synthetic_raw, "--out", out)
    assert result.exit_code == 0, result.output
    manifest = _manifest(out)
    [recording] = manifest["recordings"]
    per_split = [f"{recording['samples'][split]:,}" for split in ("train", "val", "test")]
    assert _table_row(result.stdout, recording["period"])[-3:] == per_split
    totals = manifest["splits"]
    assert all(n > 0 for n in totals.values())
    line = f"samples: {totals['train']:,} train, {totals['val']:,} val, {totals['test']:,} test"
    n = manifest["counts"]["samples"]
    shares = " / ".join(f"{round(100 * totals[split] / n)}%" for split in ("train", "val", "test"))
    assert f"{line} ({n:,} in all; shares {shares}: the vehicle split cuts" in result.stdout


RANDOM_D_MIN_0 = (
    "--stride-s",
    "4",
    "--d-sense-m",
    "40",
    "--d-min-m",
    "0",
    "--split",
    "random",
    "--seed",
    "3",
)


def test_build_options_reach_the_config(synthetic_raw: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert invoke("build", synthetic_raw, "--out", out, *RANDOM_D_MIN_0).exit_code == 0
    config = _manifest(out)["config"]
    assert (config["stride_s"], config["d_sense_m"], config["d_min_m"]) == (4.0, 40.0, 0.0)
    assert (config["split"], config["seed"], config["ego_is_target"]) == ("random", 3, False)
    # d_min = 0: no actor-actor edges, so each of the K_H steps has 2 edges per actor (ego excluded)
    for split in ("train", "val", "test"):
        samples = _samples(out, split)
        assert samples.height > 0
        assert (
            samples["n_spatial_edges"] == 2 * (samples["n_nodes"] - config["history_steps"])
        ).all()
    # the same seed gives the same split, table for table
    again = tmp_path / "again"
    assert invoke("build", synthetic_raw, "--out", again, *RANDOM_D_MIN_0).exit_code == 0
    for split in ("train", "val", "test"):
        assert _samples(again, split).equals(_samples(out, split))


def test_random_split_depends_on_the_seed(synthetic_raw: Path, tmp_path: Path) -> None:
    first, second = tmp_path / "first", tmp_path / "second"
    assert (
        invoke("build", synthetic_raw, "--out", first, "--split", "random", "--seed", "3").exit_code
        == 0
    )
    assert (
        invoke(
            "build", synthetic_raw, "--out", second, "--split", "random", "--seed", "4"
        ).exit_code
        == 0
    )
    assert not _samples(first, "train").equals(_samples(second, "train"))
    assert _manifest(first)["counts"]["samples"] == _manifest(second)["counts"]["samples"]


def test_ego_target_adds_one_target_per_sample(
    synthetic_build: Path, synthetic_raw: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    assert invoke("build", synthetic_raw, "--out", out, "--ego-target").exit_code == 0
    assert _manifest(out)["config"]["ego_is_target"] is True
    for split in ("train", "val", "test"):
        with_ego, without = _samples(out, split), _samples(synthetic_build, split)
        assert with_ego["sample_id"].equals(without["sample_id"])
        assert (with_ego["n_targets"] == without["n_targets"] + 1).all()


@pytest.mark.parametrize(
    ("option", "value", "fragment"),
    [
        ("--stride-s", "0.3", "--stride-s must be a positive multiple"),
        ("--stride-s", "0", "--stride-s must be a positive multiple"),
        ("--d-sense-m", "-1", "--d-sense-m must be a finite number > 0, not -1"),
        ("--heading-smoothing-s", "-1", "--heading-smoothing-s must be a finite number >= 0"),
        ("--d-min-m", "-0.5", "--d-min-m must be a finite number >= 0, not -0.5"),
    ],
)
def test_invalid_build_option(
    tmp_path: Path, rows: list[dict], option: str, value: str, fragment: str
) -> None:
    path = write_txt(tmp_path / "a.txt", rows)
    out = tmp_path / "out"
    result = invoke("build", path, "--out", out, option, value, env=NARROW)
    line = error_line(result)
    assert result.exit_code == 2 and fragment in line
    assert not out.exists() and leftovers(out) == []


def test_stats_of_a_synthetic_build(synthetic_build: Path) -> None:
    result = invoke("stats", synthetic_build)
    assert result.exit_code == 0, result.output
    manifest = _manifest(synthetic_build)
    splits = manifest["splits"]
    graphs = sum(min(300, n) for n in splits.values())
    for title in ("Recordings", "Splits", "Graph size (all samples, exact)", "Kinematics", "Scaler",
                  "Build config", f"Spatial in-degree per node (from {graphs:,} sampled graphs)"):  # fmt: skip
        assert title in result.stdout
    assert _table_rows(result.stdout, "train", f"{splits['train']:,}")  # the Splits table
    nodes = _samples(synthetic_build, "val")["n_nodes"]
    [row] = _table_rows(result.stdout, "val", "nodes")  # mean, min, p5, p50, p95, max
    assert row[2:4] == [f"{nodes.mean():.1f}", f"{nodes.min()}"] and row[-1] == f"{nodes.max()}"


def test_stats_json_and_plots(synthetic_build: Path, tmp_path: Path) -> None:
    plots = tmp_path / "plots"
    result = invoke("stats", synthetic_build, "--json", "--plots", plots, "--degree-graphs", "20")
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)  # the plots' paths are in the document, not printed
    assert document["samples"] == _manifest(synthetic_build)["splits"]
    assert {split: d["sampled_graphs"] for split, d in document["node_degree"].items()} == {
        split: min(20, n) for split, n in document["samples"].items()
    }
    names = ["nodes_per_graph", "spatial_edges_per_graph", "node_degree", "speed", "heading"]
    assert document["plots"] == [str(plots / f"{name}.png") for name in names]
    for path in document["plots"]:
        data = Path(path).read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 5_000
    table = invoke("stats", synthetic_build, "--plots", plots)
    assert [line for line in table.stdout.splitlines() if line.startswith("wrote ")] == [
        f"wrote {path}" for path in document["plots"]
    ]


def _drop_a_column(text: str) -> str:
    return "\n".join(" ".join(line.split()[:10] + line.split()[11:]) for line in text.splitlines())


def _add_a_column(text: str) -> str:
    return "\n".join(f"{line}   7" for line in text.splitlines())


@pytest.mark.parametrize(
    ("damage", "fragments"),
    [
        (_drop_a_column, ("line 1:", "holds 17 whitespace-separated numbers", "hold 18")),
        (_add_a_column, ("line 1:", "holds 19 whitespace-separated numbers", "column missing")),
        (lambda text: text[:30], ("line 1:", "no line end: is the file cut short?")),
        (lambda text: "", ("empty file",)),
    ],
    ids=["column-dropped", "extra-column", "cut-in-line-1", "zero-bytes"],
)
def test_a_damaged_file_beside_a_good_one_fails_the_build(
    tmp_path: Path, long_rows: list[dict], damage: Callable[[str], str], fragments: tuple[str, ...]
) -> None:
    # On main each of these was "skipped (not NGSIM)" and the build made the other recording,
    # exit 0: the damaged file's recording was lost.
    raw = tmp_path / "raw"
    write_txt(raw / "i-80" / "trajectories-0400-0415.txt", long_rows)
    damaged = write_txt(raw / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    damaged.write_text(damage(damaged.read_text()))
    out = tmp_path / "out"
    assert_failed_cleanly(invoke("build", raw, "--out", out), out, {}, damaged, *fragments)
    # Alone in its folder, the error names the file, not the folder.
    (raw / "i-80" / "trajectories-0400-0415.txt").unlink()
    assert_failed_cleanly(invoke("build", raw, "--out", out), out, {}, damaged, *fragments)


def test_a_file_of_numbers_under_any_name_is_not_skipped(
    tmp_path: Path, long_rows: list[dict]
) -> None:
    raw = tmp_path / "raw"
    write_txt(raw / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    other = raw / "us-101" / "part2.txt"
    other.write_text(
        _drop_a_column((raw / "us-101" / "trajectories-0750am-0805am.txt").read_text())
    )
    out = tmp_path / "out"
    assert_failed_cleanly(invoke("build", raw, "--out", out), out, {}, other, "holds 17")


def _built(result: Result, out: Path) -> dict:
    assert result.exit_code == 0, result.output
    return json.loads((out / "manifest.json").read_text())


def _same_build(one: dict, other: dict) -> None:
    """The same samples and files, byte for byte: only the inputs' names differ."""
    for key in ("files", "counts", "recordings", "splits", "scaler", "synthetic"):
        assert one[key] == other[key], key


def test_gzip_inputs_build_as_the_plain_file(tmp_path: Path, long_rows: list[dict]) -> None:
    # On main a .txt gzip'd under its own name was "skipped (not NGSIM)" (exit 0, its recording
    # lost), and a .txt.gz was not even listed.
    plain = write_txt(tmp_path / "plain" / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    expected = _built(invoke("build", plain.parent, "--out", tmp_path / "o0"), tmp_path / "o0")
    for i, name in enumerate(
        ["trajectories-0750am-0805am.txt", "trajectories-0750am-0805am.txt.gz"]
    ):
        packed = tmp_path / f"raw{i}" / "us-101" / name
        packed.parent.mkdir(parents=True)
        packed.write_bytes(gzip.compress(plain.read_bytes()))
        out = tmp_path / f"o{i + 1}"
        built = _built(invoke("build", packed.parent.parent, "--out", out), out)
        _same_build(built, expected)
        assert [entry["path"] for entry in built["inputs"]] == [str(packed.resolve())]
        assert built["skipped_files"] == []


def test_a_zip_builds_the_samples_of_its_files(tmp_path: Path, long_rows: list[dict]) -> None:
    # On main `build NGSIM.zip` said "not an NGSIM trajectory file".
    plain = write_txt(tmp_path / "plain" / "us-101" / "trajectories-0750am-0805am.txt", long_rows)
    expected = _built(invoke("build", plain.parent, "--out", tmp_path / "o0"), tmp_path / "o0")
    inner = io.BytesIO()  # a zip inside the zip, as the portal's per-location zips hold
    with zipfile.ZipFile(inner, "w", zipfile.ZIP_DEFLATED) as zipped:
        zipped.write(plain, "0750am-0805am/trajectories-0750am-0805am.txt")
    archive = tmp_path / "US-101-LosAngeles-CA.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zipped:
        zipped.writestr("US-101-LosAngeles-CA/vehicle-trajectory-data.zip", inner.getvalue())
        zipped.writestr("US-101-LosAngeles-CA/aerial-ortho-photos/a.jpg", PNG_SIGNATURE)
    out = tmp_path / "o1"
    result = invoke("build", archive, "--out", out)
    built = _built(result, out)
    _same_build(built, expected)
    member = f"{archive}/US-101-LosAngeles-CA/vehicle-trajectory-data.zip"
    inputs = [f"{member}/0750am-0805am/trajectories-0750am-0805am.txt"]
    assert [entry["path"] for entry in built["inputs"]] == inputs
    photo = f"{archive}/US-101-LosAngeles-CA/aerial-ortho-photos/a.jpg"
    assert built["skipped_files"] == [photo]
    assert f"skipped (not NGSIM): {photo}" in result.stderr
    assert not list(out.rglob("*.txt"))  # the unpacked copies went with the staging


def test_a_damaged_file_in_a_zip_is_named_by_the_zip(tmp_path: Path, long_rows: list[dict]) -> None:
    plain = write_txt(tmp_path / "a.txt", long_rows)
    archive = tmp_path / "NGSIM.zip"
    with zipfile.ZipFile(archive, "w") as zipped:
        zipped.writestr("us-101/trajectories-0750am-0805am.txt", _drop_a_column(plain.read_text()))
    out = tmp_path / "out"
    assert_failed_cleanly(
        invoke("build", archive, "--out", out), out, {}, Path(f"{archive}/us-101/trajectories-0750am-0805am.txt"),
        "line 1:", "holds 17",
    )  # fmt: skip
    archive.write_bytes(archive.read_bytes()[:-30])  # cut short: its directory is lost
    assert_failed_cleanly(
        invoke("build", archive, "--out", out), out, {}, archive, "cannot read this zip file"
    )
    twice = tmp_path / "twice.zip"  # two members of one name, as an appended zip holds
    with zipfile.ZipFile(twice, "w") as zipped, pytest.warns(UserWarning, match="Duplicate"):
        zipped.writestr("a.txt", plain.read_text())
        zipped.writestr("a.txt", plain.read_text())
    assert_failed_cleanly(
        invoke("build", twice, "--out", out), out, {}, Path(f"{twice}/a.txt"), "a member of this name twice"
    )  # fmt: skip


def test_build_into_a_log_prints_each_stage_after_its_time(
    tmp_path: Path, long_rows: list[dict], monkeypatch: pytest.MonkeyPatch
) -> None:
    """stderr is not a terminal here (a log): no bar, but a line at each stage's end (and within
    it every PLAIN_PROGRESS_INTERVAL_S, out of reach here), each after its wall-clock time; a
    quick build too."""
    monkeypatch.setattr(progress_module, "PLAIN_PROGRESS_INTERVAL_S", 1e9)
    path = write_period_csv(tmp_path / "a.csv", long_rows)
    result = invoke("build", path, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    progress = [line for line in result.stderr.splitlines() if " elapsed" in line]
    assert all(re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d ", line) for line in progress)
    said = [re.sub(r", \d:\d\d:\d\d elapsed$", "", line[20:]) for line in progress]
    assert said == [
        "reading input files: 1/1 (100%)",
        "cleaning recordings: 1/1 (100%)",
        "building recordings: 1/1 (100%)",
        "writing samples: 1/1 (100%)",
    ]
    assert "\x1b" not in result.stderr


def test_the_build_says_why_the_shares_are_not_the_splits_fractions() -> None:
    from ngsim_cli.build_view import split_words

    assert split_words(BuildConfig(split=SplitMode.TIME)) == (
        "the time split cuts each recording's windows at 70% and 80% by present time, and drops "
        "those within a window after each cut"
    )
    assert split_words(BuildConfig(split=SplitMode.RANDOM)) == (
        "the random split draws 70% / 10% / 20% of the ego tracks, not of the samples, and "
        "tracks give different numbers of samples"
    )
    assert split_words(BuildConfig(split_fractions=(0.6, 0.2, 0.2))).startswith(
        "the vehicle split cuts each recording's Vehicle_IDs at 60% and 80% of its largest"
    )
