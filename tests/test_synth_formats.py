"""The synthetic files behind `synth` (synth.formats, and synth.folder through it): formats,
quirks, determinism, atomic writes, and the folder's marker and what synth may replace.

Files are parsed here with the csv module and str.split, independently of the project's reader.
"""

from __future__ import annotations

import csv
import io
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from datetime import datetime
from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner, Result

from ngsim_cli.ngsim import app
from ngsim_graphs import schema
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, PACIFIC_DAYLIGHT
from ngsim_graphs.synth import folder
from ngsim_graphs.synth import formats as synthesis
from ngsim_graphs.synth.marker import MARKER_NAME
from ngsim_graphs.synth.traffic import simulate_recording

MINUTES = 0.3
QUOTED_THOUSANDS = re.compile(r'^"-?\d{1,3}(,\d{3})+(\.\d+)?"$')
COMMA_OUTSIDE_QUOTES = re.compile(r',(?=(?:[^"]*"[^"]*")*[^"]*$)')
_simulated: dict[tuple[str, str, float, int], pl.DataFrame] = {}


@pytest.fixture(autouse=True)
def _simulate_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Simulate each recording once per test session; the simulation has its own tests."""

    def cached(recording, minutes, seed):  # noqa: ANN001, ANN202
        key = (recording.location, recording.period, minutes, seed)
        if key not in _simulated:
            _simulated[key] = simulate_recording(recording, minutes, seed)
        return _simulated[key]

    monkeypatch.setattr(synthesis, "simulate_recording", cached)


def _write(tmp_path: Path, raw_format: RawFormat, quirks: bool, recordings: int = 2,
           seed: int = 5) -> list[Path]:  # fmt: skip
    config = SynthConfig(raw_format, recordings, MINUTES, seed, quirks)
    return synthesis.write_synthetic(tmp_path / f"{raw_format.value}-{quirks}", config)


def _csv_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    text = path.read_bytes().decode("utf-8-sig")
    rows = list(csv.reader(io.StringIO(text, newline="")))
    return rows[0], rows[1:]


def _number(field: str) -> float:
    return float(field.strip('"').replace(",", ""))


def _txt_keys(path: Path) -> set[tuple[int, int]]:
    return {(int(line.split()[0]), int(line.split()[1])) for line in path.read_text().splitlines()}


def _csv_keys(path: Path) -> set[tuple[int, int]]:
    return {(int(row[0]), int(row[1])) for row in _csv_rows(path)[1]}


@pytest.mark.slow
def test_txt_plain_round_trips(tmp_path: Path) -> None:
    paths = _write(tmp_path, RawFormat.TXT, quirks=False)
    assert [p.relative_to(tmp_path / "txt-False").as_posix() for p in paths] == [
        "us-101/trajectories-0750am-0805am.txt",
        "i-80/trajectories-0400-0415.txt",
    ]
    text = paths[1].read_text()
    assert text.endswith("  \n") and "\r" not in text
    lines = text.splitlines()
    assert all(line.startswith(" ") and line.endswith(" ") for line in lines)
    assert all(len(line.split()) == 18 for line in lines)
    assert "  " in lines[0].strip()  # fields padded with several spaces
    parsed = pl.DataFrame([line.split() for line in lines], schema=list(ns.TXT_COLUMNS),
                          orient="row").cast(dict(ns.RAW_SCHEMA))  # fmt: skip
    expected = simulate_recording(OFFICIAL_RECORDINGS[1], MINUTES, 5)
    assert parsed.equals(expected.select(ns.TXT_COLUMNS))


def test_txt_quirks_gaps_and_no_final_newline(tmp_path: Path) -> None:
    paths = _write(tmp_path, RawFormat.TXT, quirks=True)
    data = paths[0].read_bytes()
    assert not data.endswith(b"\n") and data.endswith(b" ")
    rows = _txt_keys(paths[0])
    full = simulate_recording(OFFICIAL_RECORDINGS[0], MINUTES, 5)
    assert len(rows) < len(full)
    assert rows < set(zip(full[schema.VEHICLE_ID], full[schema.FRAME_ID], strict=True))


def test_csv_plain_header_and_values(tmp_path: Path) -> None:
    path = _write(tmp_path, RawFormat.CSV, quirks=False)[0]
    data = path.read_bytes()
    assert b"\r" not in data and data.endswith(b"\n") and b'"' not in data
    header, rows = _csv_rows(path)
    assert tuple(header) == ns.PERIOD_CSV_HEADER
    assert all(len(row) == 24 for row in rows)
    assert all(row[14:20] == [""] * 6 for row in rows)  # O_Zone .. Movement empty
    expected = simulate_recording(OFFICIAL_RECORDINGS[0], MINUTES, 5)
    assert len(rows) == len(expected)
    assert [_number(v) for v in rows[10][:14]] == pytest.approx(list(expected.row(10)[:14]))


def test_csv_quirks_header_variants_crlf_and_gaps(tmp_path: Path) -> None:
    path = _write(tmp_path, RawFormat.CSV, quirks=True)[0]
    data = path.read_bytes()
    assert data.count(b"\r\n") == data.count(b"\n") > 100
    header, rows = _csv_rows(path)
    assert header[0] == "vehicle_id" and header[5] == "LOCAL_Y" and header[8] == "v_Length"
    assert [name.lower() for name in header] == [n.lower() for n in ns.PERIOD_CSV_HEADER]
    by_vehicle = Counter(int(row[0]) for row in rows)
    total = {int(row[0]): int(row[2]) for row in rows}
    assert any(by_vehicle[v] < total[v] for v in by_vehicle)  # Total_Frames kept across the gap


def test_same_gaps_in_every_format(tmp_path: Path) -> None:
    txt = _txt_keys(_write(tmp_path, RawFormat.TXT, quirks=True)[1])
    csv_keys = _csv_keys(_write(tmp_path, RawFormat.CSV, quirks=True)[1])
    portal = _write(tmp_path, RawFormat.PORTAL, quirks=True)[0]
    _, rows = _csv_rows(portal)
    portal_keys = {(int(_number(r[0])), int(_number(r[1]))) for r in rows if r[-1] == "i-80"}
    assert txt == csv_keys == portal_keys


def test_portal_plain(tmp_path: Path) -> None:
    path = _write(tmp_path, RawFormat.PORTAL, quirks=False)[0]
    assert path.name == folder.PORTAL_FILE_NAME
    data = path.read_bytes()
    assert data.startswith(b"Vehicle_ID,") and b"\r" not in data and b'"' not in data
    header, rows = _csv_rows(path)
    assert tuple(header) == ns.PORTAL_HEADER
    assert Counter(row[-1] for row in rows).keys() == {"us-101", "i-80"}
    assert all(len(row) == 25 and row[14:20] == [""] * 6 and row[4] != "" for row in rows)
    assert len({tuple(row) for row in rows}) == len(rows)
    keys = [(row[-1], int(row[0]), int(row[1])) for row in rows]
    assert keys == sorted(keys, key=lambda k: (k[0] != "us-101", k[1], k[2]))


@pytest.fixture(scope="module")
def quirky_portal(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list[list[str]]]:
    out = tmp_path_factory.mktemp("portal")
    config = SynthConfig(RawFormat.PORTAL, recordings=3, minutes=MINUTES, seed=5, quirks=True)
    path = synthesis.write_synthetic(out, config)[0]
    return path.read_bytes(), _csv_rows(path)[1]


def test_portal_quirks_bom_crlf_and_thousands(quirky_portal: tuple[bytes, list]) -> None:
    data, rows = quirky_portal
    assert data.startswith(synthesis.BOM + b"Vehicle_ID,Frame_ID,")
    assert data.count(b"\r\n") == data.count(b"\n")
    lines = data.decode("utf-8-sig").split("\r\n")[1:5000]
    fields = [COMMA_OUTSIDE_QUOTES.split(line) for line in lines]
    assert all(len(row) == 25 for row in fields)
    assert all(QUOTED_THOUSANDS.match(row[3]) for row in fields)  # "1,118,846,..."
    assert b',"9,999.99",' in data
    for row in fields:
        for field in row[:24]:
            if field.startswith('"'):
                assert QUOTED_THOUSANDS.match(field) and _number(field) >= 1000
            elif field:
                assert abs(float(field)) < 1000
    assert len(rows) > len(lines)


def test_portal_quirks_order_duplicates_and_empty_fields(quirky_portal: tuple[bytes, list]) -> None:
    _, rows = quirky_portal
    global_y = [_number(row[7]) for row in rows]
    assert global_y == sorted(global_y)
    # The two us-101 periods interleave: their frame-0 times alternate along the file.
    frame0 = [_number(r[3]) - 100 * _number(r[1]) for r in rows if r[-1] == "us-101"]
    assert len(set(frame0)) == 2
    assert sum(a != b for a, b in zip(frame0, frame0[1:], strict=False)) > 100
    counts = Counter(tuple(row) for row in rows)
    assert sum(n - 1 for n in counts.values()) >= 3  # exact duplicates
    by_key: dict[tuple, list[list[str]]] = {}
    for row in rows:
        by_key.setdefault((row[-1], row[3], row[0], row[1]), []).append(row)
    variants = [group for group in by_key.values() if len({tuple(r) for r in group}) > 1]
    larger_y = [g for g in variants if all(r[4] for r in g)]
    assert len(larger_y) >= 3
    for group in larger_y:
        local_y = sorted({_number(r[5]) for r in group})
        assert 0.5 - 1e-6 <= local_y[-1] - local_y[0] <= 3.0 + 1e-6
    empty_x = [row for row in rows if row[4] == ""]
    assert len(empty_x) >= 3
    assert all(len(by_key[(r[-1], r[3], r[0], r[1])]) >= 2 for r in empty_x)


def test_portal_quirks_foreign_location(quirky_portal: tuple[bytes, list]) -> None:
    _, rows = quirky_portal
    foreign = [row for row in rows if row[-1] == "lankershim"]
    assert 1000 <= len(foreign) <= 10_000
    frame0_ms = _number(foreign[0][3]) - 100 * _number(foreign[0][1])
    start = datetime.fromtimestamp(frame0_ms / 1000, PACIFIC_DAYLIGHT)
    assert (start.date().isoformat(), start.hour) == ("2005-06-16", 8)
    assert 27 <= start.minute <= 28


@pytest.mark.slow
def test_same_config_same_bytes_other_seed_other_bytes(tmp_path: Path) -> None:
    _simulated.clear()  # end to end, through the simulation
    config = SynthConfig(RawFormat.PORTAL, recordings=1, minutes=0.1, seed=2, quirks=True)
    first = synthesis.write_synthetic(tmp_path / "a", config)[0].read_bytes()
    second = synthesis.write_synthetic(tmp_path / "b", config)[0].read_bytes()
    other = SynthConfig(RawFormat.PORTAL, recordings=1, minutes=0.1, seed=3, quirks=True)
    third = synthesis.write_synthetic(tmp_path / "c", other)[0].read_bytes()
    assert first == second != third


def test_progress_per_recording_and_no_partial_files(tmp_path: Path) -> None:
    messages: list[str] = []
    config = SynthConfig(RawFormat.CSV, recordings=2, minutes=MINUTES, seed=5)
    synthesis.write_synthetic(tmp_path, config, messages.append)
    assert len(messages) == 2 and "us-101" in messages[0] and "i-80" in messages[1]
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == [
        "SYNTHETIC.md",
        "trajectories-0400-0415.csv",
        "trajectories-0750am-0805am.csv",
    ]


def test_a_short_recording_keeps_its_periods_name_and_says_so(tmp_path: Path) -> None:
    """--minutes 0.3 writes `trajectories-0400-0415.txt`, as a build will name the recording (by
    its start time), and synth says so in its output and its marker; 15 minutes says nothing."""
    result = CliRunner(env={"COLUMNS": "300"}).invoke(
        app, ["synth", str(tmp_path / "raw"), "--recordings", "2", "--minutes", str(MINUTES)]
    )
    assert result.exit_code == 0, result.output
    note = (
        f"each recording runs {MINUTES:g} minutes from the start of its official period and is "
        "named after that 15-minute period (e.g. 0400-0415) in its file's name and a build's "
        "report: a build tells a recording by its start time"
    )
    assert result.output.splitlines()[-1] == f"Note: {note}."
    assert f"\n{note[0].upper()}{note[1:]}.\n" in (tmp_path / "raw" / MARKER_NAME).read_text()
    assert (tmp_path / "raw" / "i-80" / "trajectories-0400-0415.txt").is_file()
    first_ms = int((tmp_path / "raw" / "i-80" / "trajectories-0400-0415.txt").open().readline()
                   .split()[3])  # fmt: skip
    start_ms = OFFICIAL_RECORDINGS[1].start_epoch_ms  # 4:00 pm, frame 0 within 30 s of it
    assert start_ms - 30_000 <= first_ms <= start_ms + 1000 * 60 * MINUTES
    assert folder.period_note(SynthConfig(RawFormat.PORTAL, minutes=2)).endswith(
        "(e.g. 0400-0415) in a build's report: a build tells a recording by its start time"
    )
    assert folder.period_note(SynthConfig(minutes=15)) is None
    assert folder.period_note(SynthConfig(RawFormat.HIGHD, minutes=2)) is None


def test_interrupted_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(handle, rows, quirks):  # noqa: ANN001, ANN202
        handle.write(b"half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(synthesis, "_write_txt", fail)
    config = SynthConfig(RawFormat.TXT, recordings=1, minutes=MINUTES, seed=5)
    with pytest.raises(KeyboardInterrupt):
        synthesis.write_synthetic(tmp_path, config)
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


# --- the folder synth writes: through the command line ---------------------------------------

SYNTH = ("--recordings", "2", "--minutes", "0.05", "--format", "txt")
FIRST, SECOND = (f"trajectories-{r.period}.txt" for r in OFFICIAL_RECORDINGS[:2])


def invoke(*args: object) -> Result:
    return CliRunner().invoke(app, [str(a) for a in args])


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def test_a_marker_that_only_lists_a_file_does_not_make_it_synths(tmp_path: Path) -> None:
    """A SYNTHETIC.md naming real data (copied, or written by hand) lists no sha256 that synth
    recorded: synth replaces nothing in that folder."""
    folder = tmp_path / "ngsim"
    real = folder / "us-101" / FIRST
    real.parent.mkdir(parents=True)
    real.write_text("real data\n")
    (folder / MARKER_NAME).write_text(f"# Synthetic data\n\nFiles:\n\n- us-101/{FIRST}\n")
    before = files(folder)
    result = invoke("synth", folder, *SYNTH)
    assert result.exit_code == 1 and result.stderr == (
        f"error: {folder / MARKER_NAME}: is not a marker that synth wrote (or was edited since: "
        "it lists no file with its sha256): the folder is not replaced; move it away or choose "
        "another folder\n"
    )
    assert files(folder) == before and siblings(folder) == []


def test_synth_never_writes_through_a_link(tmp_path: Path) -> None:
    """A link in a folder of synth's, at the partial name of one of its files, leads to a file
    of yours: synth refuses the folder and the file stays as it was."""
    folder = tmp_path / "raw"
    assert invoke("synth", folder, *SYNTH).exit_code == 0
    victim = tmp_path / "mine.txt"
    victim.write_text("mine\n")
    (folder / "us-101" / f".{FIRST}.partial").symlink_to(victim)
    result = invoke("synth", folder, *SYNTH, "--seed", "1")
    assert result.exit_code == 1 and result.stderr.startswith(
        f"error: {folder / 'us-101' / f'.{FIRST}.partial'}: not written by synth"
    )
    assert victim.read_text() == "mine\n"


def _second_file_begun(folder: Path) -> bool:
    """Whether synth writes its second file, wherever it writes it (a folder it renames while
    it is looked into: not yet)."""
    try:
        return any(SECOND in p.name for p in folder.parent.rglob("*"))
    except FileNotFoundError:
        return False


def _run_synth_until_second_file(folder: Path) -> subprocess.Popen:
    """`ngsim-graphs synth` in a process of its own, stopped once its first file is written
    whole (the second is being written, wherever that is)."""
    program = "import sys; from ngsim_cli.entry import ngsim_graphs; ngsim_graphs()"
    arguments = ["synth", str(folder), "--recordings", "2", "--minutes", "1"]
    process = subprocess.Popen(
        [sys.executable, "-c", program, *arguments], stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while not _second_file_begun(folder):
        assert process.poll() is None, process.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    return process


@pytest.mark.slow
@pytest.mark.parametrize("how", ["kill -9", "Ctrl-C"])
def test_a_stopped_synth_leaves_nothing_that_looks_complete(tmp_path: Path, how: str) -> None:
    folder = tmp_path / "raw"
    process = _run_synth_until_second_file(folder)
    process.send_signal(signal.SIGKILL if how == "kill -9" else signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    if how == "Ctrl-C":
        assert (process.returncode, stderr) == (
            130,
            f"interrupted; nothing written ({folder} is as it was)\n",
        )
        assert siblings(folder) == []
    assert not folder.exists()  # no first file, complete but of an unfinished run
    again = invoke("synth", folder, "--recordings", "1", "--minutes", "0.05")
    assert again.exit_code == 0, again.output
    assert sorted(files(folder)) == [MARKER_NAME, f"us-101/{FIRST}"] and siblings(folder) == []
