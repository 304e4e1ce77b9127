"""`run_build` end to end on tiny hand-made inputs: manifest, tracks table, atomic output."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, replace
from pathlib import Path

import polars as pl
import pyarrow.parquet as pq
import pytest
from conftest import (
    US101_FIRST,
    US101_SECOND,
    make_row,
    straight_track,
    write_period_csv,
    write_portal,
    write_txt,
)
from highd_fixtures import two_directions
from polars.testing import assert_frame_equal
from test_cli_ngsim import invoke

from ngsim_graphs import layout
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.lock import lock_path, partial_path
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.plausibility import DROP_REASONS, LIMITS
from ngsim_graphs.synth.formats import write_synthetic

FT = 0.3048
# Windows of 3 grid steps (2 of history, 1 of future): the tiny inputs here give samples, and a
# build without samples is an error.
SHORT = BuildConfig(history_steps=2, future_steps=1)
FIRST = "0750am-0805am"
SECOND = "0805am-0820am"


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under `root` (relative path -> bytes)."""
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def parquet_bytes(root: Path) -> dict[str, bytes]:
    return {name: data for name, data in snapshot(root).items() if name.endswith(".parquet")}


def hidden_siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def tracks(out: Path, period: str = FIRST) -> pl.DataFrame:
    return pl.read_parquet(layout.tracks_path(out, "us-101", period))


@pytest.fixture
def portal_rows() -> list[dict]:
    """us-101 0750am in a portal file, counts worked out by hand.

    Vehicle 1: frames 10..39 without 20 and 21 (28 rows, one gap: two tracks, grid frames
    10..18 and 22..38, 5 + 9 rows). Vehicle 2: frames 10..39 (30 rows, 15 grid rows), plus an exact
    copy of its frame 15 and a conflicting frame 16 (Local_Y 1000 ft further; the rule keeps the
    smaller Local_Y, the original). Vehicle 3: one row with an empty Local_Y (dropped). One
    lankershim row (another location). 62 rows in the file.
    """
    v1 = straight_track(1, [f for f in range(10, 40) if f not in (20, 21)], x_ft=6.0, lane_id=1)
    v2 = straight_track(2, range(10, 40), x_ft=18.0, speed_fps=40.0)
    exact = dict(v2[5])
    conflicting = {**v2[6], ns.LOCAL_Y: v2[6][ns.LOCAL_Y] + 1000.0}
    empty = make_row(3, 10, **{ns.LOCAL_Y: None})  # type: ignore[arg-type]
    other = make_row(9, 10)
    rows = v1 + v2 + [exact, conflicting, empty, other]
    return [*zip(rows, ["us-101"] * (len(rows) - 1) + ["lankershim"], strict=True)]


def _write(path: Path, rows_with_locations: list[tuple[dict, str]]) -> Path:
    rows, names = zip(*rows_with_locations, strict=True)
    return write_portal(path, list(rows), locations=list(names))


def test_manifest(tmp_path: Path, portal_rows: list) -> None:
    raw = _write(tmp_path / "portal.csv", portal_rows)
    out = tmp_path / "out"
    result = run_build([raw], out, SHORT)

    on_disk = json.loads((out / "manifest.json").read_text())
    assert on_disk == json.loads(json.dumps(result.manifest.to_dict()))
    assert layout.read_manifest(out).to_dict() == on_disk
    assert on_disk["format_version"] == layout.FORMAT_VERSION == 4
    assert on_disk["config"] == json.loads(json.dumps(SHORT.to_dict()))
    assert on_disk["config"]["locations"] == ["us-101", "i-80"]
    assert (on_disk["config"]["d_sense_m"], on_disk["config"]["d_min_m"], on_disk["config"]["split"]) == (
        50.0, 25.0, "vehicle",
    )  # fmt: skip
    # the limits its source applied, beside the config: NGSIM's; the hash covers both
    assert on_disk["limits"] == asdict(LIMITS) and on_disk["limits"]["max_frame_id"] == 72_000
    settings = {**on_disk["config"], "limits": on_disk["limits"]}
    canonical = json.dumps(settings, sort_keys=True, separators=(",", ":"))
    assert on_disk["config_hash"] == hashlib.sha256(canonical.encode()).hexdigest()

    [source] = on_disk["inputs"]
    assert source["path"] == str(raw)
    assert source["raw_format"] == "portal"
    assert source["size_bytes"] == raw.stat().st_size == len(raw.read_bytes())
    assert source["sha256"] == hashlib.sha256(raw.read_bytes()).hexdigest()
    assert source["recordings"] == [f"us-101/{FIRST}"]
    assert (source["rows_read"], source["rows_other_locations"], source["rows_missing_values"]) == (
        62, 1, 1
    )  # fmt: skip

    assert on_disk["counts"] == {
        "rows_read": 62,
        "rows_other_locations": 1,
        "rows_missing_values": 1,
        # every shared reason and NGSIM's own
        "rows_dropped": dict.fromkeys([*(r.value for r in s.DropReason), *DROP_REASONS], 0),
        "rows": 60,  # 62 - lankershim - empty Local_Y
        "exact_duplicates": 1,
        "conflicting_duplicates": 1,
        "position_jumps": 0,
        "gaps": 1,
        "tracks": 3,
        "grid_rows": 29,  # 5 + 9 + 15
        "proximity_edges": 14,  # vehicle 1's 14 steps, each beside vehicle 2 within 25 m
        "samples": 3,  # one 3-step window per track (stride 8 s)
        "cslstm_rows": None,  # the aigem protocol: no CS-LSTM rows
    }
    # Vehicle split: largest Vehicle_ID 2, cuts at round(1.4) = 1 and round(1.6) = 2.
    assert on_disk["splits"] == {"train": 2, "val": 1, "test": 0}
    assert len(on_disk["warnings"]) == 1 and on_disk["warnings"][0].startswith(
        "the test split is empty"
    )
    [recording] = on_disk["recordings"]
    assert recording["location"] == "us-101" and recording["period"] == FIRST
    assert recording["vehicles"] == 2
    assert (
        on_disk["files"][f"tracks/us-101_{FIRST}.parquet"]["sha256"]
        == hashlib.sha256(layout.tracks_path(out, "us-101", FIRST).read_bytes()).hexdigest()
    )
    assert result.files[0].sha256 == source["sha256"]


def test_config_hash_changes_with_config(tmp_path: Path, portal_rows: list) -> None:
    raw = _write(tmp_path / "portal.csv", portal_rows)
    a = run_build([raw], tmp_path / "a", SHORT).manifest
    b = run_build([raw], tmp_path / "b", replace(SHORT, min_heading_speed_mps=1.0)).manifest
    c = run_build([raw], tmp_path / "c", SHORT).manifest
    assert a.config_hash == c.config_hash != b.config_hash


def test_tracks_table(tmp_path: Path, portal_rows: list) -> None:
    out = tmp_path / "out"
    run_build([_write(tmp_path / "portal.csv", portal_rows)], out, SHORT)
    table = tracks(out)
    assert table.schema == s.TRACKS_SCHEMA
    written = sorted(p.name for p in (out / layout.TRACKS_DIR).iterdir())
    assert written == [f"us-101_{FIRST}.parquet"]

    v1_frames = [*range(10, 20, 2), *range(22, 40, 2)]
    assert table[s.VEHICLE_ID].to_list() == [1] * 14 + [2] * 15
    assert table[s.SEGMENT].to_list() == [0] * 5 + [1] * 9 + [0] * 15
    assert table[s.TRACK_ID].to_list() == [0] * 5 + [1] * 9 + [2] * 15
    assert table[s.FRAME_ID].to_list() == v1_frames + list(range(10, 40, 2))
    assert table[s.TIME_S].to_list() == pytest.approx([0.1 * f for f in table[s.FRAME_ID]])

    first = table.row(0, named=True)  # vehicle 1 at frame 10: y = 30 ft/s * 1 s
    assert first[s.X_M] == pytest.approx(6 * FT)
    assert first[s.Y_M] == pytest.approx(30 * FT)
    assert first[s.SPEED_MPS] == pytest.approx(30 * FT)
    assert first[s.GLOBAL_TIME] == US101_FIRST.start_epoch_ms - 7_000 + 1_000
    assert first[s.LENGTH_M] == pytest.approx(15 * FT) and first[s.WIDTH_M] == pytest.approx(6 * FT)
    # NGSIM's "none" sentinels became null
    assert first[s.PRECEDING] is None and first[s.TIME_HEADWAY_S] is None
    assert first[s.SPACE_HEADWAY_M] is None

    # the conflicting duplicate of vehicle 2 at frame 16 lost: y = 40 ft/s * 1.6 s = 64 ft
    v2_16 = table.filter((pl.col(s.VEHICLE_ID) == 2) & (pl.col(s.FRAME_ID) == 16))
    assert v2_16[s.Y_M].to_list() == pytest.approx([64 * FT])
    # straight along +y: heading 0 everywhere
    assert table[s.HEADING_RAD].abs().max() == pytest.approx(0.0, abs=1e-9)


def test_same_build_twice_gives_identical_parquet(tmp_path: Path, portal_rows: list) -> None:
    raw = _write(tmp_path / "portal.csv", portal_rows)
    shuffled = _write(tmp_path / "shuffled.csv", portal_rows[::-1])  # NGSIM rows come unsorted
    run_build([raw], tmp_path / "a", SHORT)
    run_build([raw], tmp_path / "b", SHORT)
    run_build([shuffled], tmp_path / "c", SHORT)
    a = parquet_bytes(tmp_path / "a")
    assert list(a) == [
        "samples/test.parquet",
        "samples/train.parquet",
        "samples/val.parquet",
        f"tracks/us-101_{FIRST}.parquet",
    ]
    assert parquet_bytes(tmp_path / "b") == a
    assert parquet_bytes(tmp_path / "c") == a


@pytest.mark.parametrize("jobs", [1, 2])
def test_failure_mid_build_leaves_previous_build(
    tmp_path: Path, portal_rows: list, jobs: int
) -> None:
    good = _write(tmp_path / "a_good.csv", portal_rows)
    out = tmp_path / "out"
    run_build([good], out, SHORT)
    before = snapshot(out)

    bad = tmp_path / "b_bad.txt"
    write_txt(bad, straight_track(5, range(10, 20)))
    bad.write_text(bad.read_text()[:-40])  # the last line cut off
    seen: list[str] = []
    with pytest.raises(NgsimInputError, match=r"b_bad\.txt, line 10: "):
        run_build(
            [good, bad], out, SHORT, True, lambda w, *_: seen.append(w), jobs=jobs
        )  # the error of a worker process comes back whole
    if jobs == 1:
        assert seen == ["reading a_good.csv", "reading b_bad.txt"]  # the good file staged first
    assert snapshot(out) == before
    assert hidden_siblings(out) == []


def test_failure_mid_build_leaves_no_output(tmp_path: Path, portal_rows: list) -> None:
    good = _write(tmp_path / "a_good.csv", portal_rows)
    bad = write_period_csv(tmp_path / "b_bad.csv", [])
    out = tmp_path / "out"
    with pytest.raises(NgsimInputError, match="no data rows"):
        run_build([good, bad], out, SHORT)
    assert not out.exists()
    assert hidden_siblings(out) == []


def test_leftover_partial_directory_is_cleaned_up(tmp_path: Path, portal_rows: list) -> None:
    """A killed build's, named by the lock file it left; one no lock names is not ours."""
    raw = _write(tmp_path / "portal.csv", portal_rows)
    out = tmp_path / "out"
    token = "a" * 32
    lock_path(out).write_text(f"ngsim-graphs lock {token} 123\n")
    for killed in (partial_path(out, token), tmp_path / ".out.partial-123"):
        (killed / layout.TRACKS_DIR).mkdir(parents=True)
        (killed / layout.TRACKS_DIR / "half.parquet").write_bytes(b"PAR1")
    result = run_build([raw], out, SHORT)
    assert result.manifest.counts.tracks == 3
    assert hidden_siblings(out) == [".out.partial-123"]
    assert [f for f in sorted(snapshot(out)) if not f.startswith("arrays/")] == [
        "manifest.json",
        "samples/test.parquet",
        "samples/train.parquet",
        "samples/val.parquet",
        f"tracks/us-101_{FIRST}.parquet",
    ]


def test_periods_of_one_portal_file_are_separate_recordings(tmp_path: Path) -> None:
    """Vehicles 1..20 in two us-101 periods, frames 10..19 in both (a recording needs 20
    vehicles): not one set of vehicles with duplicates."""
    first = [r for v in range(1, 21) for r in straight_track(v, range(10, 20), x_ft=6.0)]
    second = [
        r
        for v in range(1, 21)
        for r in straight_track(v, range(10, 20), x_ft=30.0, start_ms=US101_SECOND.start_epoch_ms)
    ]
    first = [{**r, s.LANE_ID: 1} for r in first]
    second = [{**r, s.LANE_ID: 3} for r in second]
    raw = write_portal(tmp_path / "portal.csv", first + second)
    out = tmp_path / "out"
    result = run_build([raw], out, SHORT)

    keys = [(r.location, r.period) for r in result.recordings]
    assert keys == [("us-101", FIRST), ("us-101", SECOND)]
    for r in result.recordings:
        assert (r.rows, r.exact_duplicates, r.conflicting_duplicates, r.gaps) == (200, 0, 0, 0)
        assert (r.vehicles, r.tracks, r.grid_rows) == (20, 20, 100)
    assert result.files[0].recordings == (f"us-101/{FIRST}", f"us-101/{SECOND}")

    a, b = tracks(out, FIRST), tracks(out, SECOND)
    assert a[s.TRACK_ID].unique().sort().to_list() == list(range(20))
    assert b[s.TRACK_ID].unique().sort().to_list() == list(range(20, 40))
    assert a[s.PERIOD].unique().to_list() == [FIRST] and b[s.PERIOD].unique().to_list() == [SECOND]
    assert a[s.X_M].to_list() == pytest.approx([6 * FT] * 100)
    assert b[s.X_M].to_list() == pytest.approx([30 * FT] * 100)
    assert b[s.GLOBAL_TIME][0] - a[s.GLOBAL_TIME][0] == 15 * 60 * 1000


def test_csv_and_txt_of_the_same_data_give_identical_tracks(
    tmp_path: Path, two_vehicle_rows: list[dict]
) -> None:
    inputs = {
        "csv": write_period_csv(tmp_path / "trajectories-0750am-0805am.csv", two_vehicle_rows),
        "txt": write_txt(tmp_path / "trajectories-0750am-0805am.txt", two_vehicle_rows),
        "portal": write_portal(tmp_path / "portal.csv", two_vehicle_rows),
    }
    results = {name: run_build([p], tmp_path / name, SHORT) for name, p in inputs.items()}
    reference = tracks(tmp_path / "csv")
    assert reference.height == 30 and reference[s.TRACK_ID].n_unique() == 2
    for name, result in results.items():
        assert result.files[0].raw_format == name
        assert_frame_equal(tracks(tmp_path / name), reference)
        assert parquet_bytes(tmp_path / name) == parquet_bytes(tmp_path / "csv")
        assert result.manifest.counts == results["csv"].manifest.counts


def test_one_recording_from_two_files(tmp_path: Path) -> None:
    """Per-period files of one recording (here one vehicle each) are staged into one recording."""
    a = write_txt(tmp_path / "raw" / "a.txt", straight_track(1, range(10, 20)))
    b = write_period_csv(tmp_path / "raw" / "b.csv", straight_track(2, range(10, 20), x_ft=30.0))
    out = tmp_path / "out"
    # the directory and a file inside it: each file is read once
    result = run_build([tmp_path / "raw", a], out, SHORT)
    assert [f.path for f in result.files] == [str(a.resolve()), str(b.resolve())]
    [recording] = result.recordings
    counts = (recording.rows, recording.vehicles, recording.tracks, recording.grid_rows)
    assert counts == (20, 2, 2, 10)
    assert tracks(out)[s.VEHICLE_ID].to_list() == [1] * 5 + [2] * 5


def assert_built_alike(tmp_path: Path, *orders: list[Path]) -> list[Path]:
    """Build the inputs in each order through the CLI; every file of every build, the manifest
    included, byte for byte the first's (but build.log). Returns the builds."""
    outs = [tmp_path / f"out{i}" for i in range(len(orders))]
    for inputs, out in zip(orders, outs, strict=True):
        result = invoke("build", *inputs, "--out", out, "--jobs", "1")
        assert result.exit_code == 0, result.output
    first = snapshot(outs[0])
    assert any(name.endswith(".npy") for name in first)
    assert first.pop(layout.BUILD_LOG)  # each build's own log: its times (and its inputs' order)
    for out in outs[1:]:
        again = snapshot(out)
        assert again.pop(layout.BUILD_LOG)
        assert again == first
    return outs


def test_the_same_inputs_in_another_order_give_the_same_build(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    write_synthetic(raw, SynthConfig(raw_format=s.RawFormat.CSV, recordings=2, minutes=0.3, seed=4))
    a, b = sorted(raw.rglob("*.csv"))  # i-80's file, then us-101's
    out, _, _ = assert_built_alike(tmp_path, [a, b], [b, a], [raw])
    inputs = layout.read_manifest(out).inputs
    assert [f.path for f in inputs] == [str(a.resolve()), str(b.resolve())]


def test_a_conflicting_duplicate_across_files_is_kept_alike_in_any_order(tmp_path: Path) -> None:
    """Vehicle 1 at frame 100 in both files, 0.5 ft apart: whichever file comes first, the row
    that sorts first by (Local_Y, Local_X, ...) is kept (`cleaning.CONFLICT_ORDER`)."""
    frames = range(0, 200)
    x = write_period_csv(
        tmp_path / "x.csv", straight_track(1, frames) + straight_track(2, frames, x_ft=30.0)
    )
    moved = make_row(1, 100, local_x_ft=18.5, local_y_ft=300.0)
    lane_4 = straight_track(3, frames, x_ft=42.0, lane_id=4)  # 42 ft: lane 4's (36..48 ft)
    y = write_period_csv(tmp_path / "y.csv", [moved, *lane_4])
    out, _ = assert_built_alike(tmp_path, [x, y], [y, x])
    counts = layout.read_manifest(out).counts
    assert (counts.exact_duplicates, counts.conflicting_duplicates) == (0, 1)
    at_100 = tracks(out).filter((pl.col(s.VEHICLE_ID) == 1) & (pl.col(s.FRAME_ID) == 100))
    assert at_100[s.X_M].to_list() == [pytest.approx(18.0 * FT)]


def test_highd_recordings_named_by_any_of_their_files_in_any_order(tmp_path: Path) -> None:
    first = two_directions(tmp_path / "one", number=1)
    second = two_directions(tmp_path / "two", number=2)
    meta = [second.with_name("02_recordingMeta.csv"), first.with_name("01_tracksMeta.csv")]
    assert_built_alike(tmp_path, [first, second], meta)


# A small build's contents, as today's code writes it: a refactoring must leave them as they are.
# Parquet is compared by its values (its bytes carry the writing library's version); the arrays
# by their bytes; the manifest but for the paths, the software versions and the Parquet checksums.
# After a deliberate change of the output, write the digest anew with UPDATE_BUILD_DIGEST=1.
BUILD_DIGEST = Path(__file__).parent / "fixtures" / "build-digest.txt"


def _content_digest(build: Path, name: str) -> str:
    path = build / name
    if name.endswith(".parquet"):
        table = pq.read_table(path)
        fields = [(f.name, str(f.type)) for f in table.schema]
        text = json.dumps([fields, table.to_pydict()], default=str)
    elif name == layout.MANIFEST_NAME:
        manifest = json.loads(path.read_text())
        for key in ("software", "synthetic_inputs", "manifest_sha256"):
            manifest.pop(key)
        for entry in manifest["inputs"]:
            entry.pop("path")
        for file, entry in manifest["files"].items():
            if file.endswith(".parquet"):
                manifest["files"][file] = sorted(set(entry) - {"bytes", "sha256", "sampled_sha256"})
        text = json.dumps(manifest, sort_keys=True)
    else:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    return hashlib.sha256(text.encode()).hexdigest()


def test_a_small_build_is_what_it_was(tmp_path: Path) -> None:
    """One recording of half a minute, synthetic, built with the defaults."""
    raw = tmp_path / "raw"
    write_synthetic(raw, SynthConfig(recordings=1, minutes=0.5, seed=3))
    out = tmp_path / "build"
    run_build([raw], out, BuildConfig(), jobs=1)
    names = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    found = "".join(f"{_content_digest(out, name)}  {name}\n" for name in names)
    if os.environ.get("UPDATE_BUILD_DIGEST") == "1":
        BUILD_DIGEST.write_text(found)
        pytest.skip(f"wrote {BUILD_DIGEST}")
    assert found.splitlines() == BUILD_DIGEST.read_text().splitlines()
