"""`build --protocol cs-lstm`: the samples are CS-LSTM's kept rows on the 0.2 s grid, held to the
plain-loop reference of the script (cslstm_reference) on a hand-made recording and on a quirky
synthetic one; the ego is the only target; `aigem fit` and `evaluate` run on such a build and
say under which protocol the numbers were made; options without meaning there are refused."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import US101_FIRST, make_row, set_budget, write_txt
from cslstm_reference import reference_kept, reference_split
from test_cli_ngsim import assert_failed_cleanly, error_line, invoke
from typer.testing import CliRunner

from ngsim_graphs import layout
from ngsim_graphs import schema as s
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.graphs import induce_graphs
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import Protocol, RawFormat, SplitMode
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.tracks import read_file_recordings
from ngsim_graphs.synth.formats import write_synthetic

F = np.float32
CSLSTM = BuildConfig(protocol=Protocol.CS_LSTM)
OUTLIER = (4, 60)  # vehicle, frame: a row displaced by 200 ft, which cleaning drops


def _vehicle(vehicle: int, frames: list[int], lane: int, y0_ft: float) -> list[dict]:
    """Straight along +y at 30 ft/s in `lane` (12 ft wide), at y0 + 3 ft per frame."""
    return [
        make_row(vehicle, f, local_x_ft=12.0 * lane - 6.0, local_y_ft=y0_ft + 3.0 * f, lane_id=lane)
        for f in frames
    ]


def script_recording() -> list[dict]:
    """Ten vehicles of us-101 0750am (txt), built to reach each rule:
    - 1, 2, 7, 8, 9, 10: frames a..a+89, kept at a+30..a+87: 58 rows, 29 on the even grid;
    - 3: frames 10..99 without 50..54 (a gap, two tracks): its 31st row is frame 40, kept 40..49
      and 55..97: 53 rows, 26 even; the track after the gap starts at step 28, so its samples'
      earliest history steps have no ego;
    - 4: frames 0..79, frame 60 displaced by 200 ft (a position outlier, dropped, which also
      splits the track): kept 30..77, 48 rows, 24 even, of which frame 60 has no track;
    - 5: frames 0..89 with frames 0, 2 and 40 repeated (conflicting duplicates): its 31st row is
      frame 28, kept 28..87, 61 rows, 30 even (frame 40 once); the sample at step 14 starts at
      step -1;
    - 6: frames 20..39, 20 rows: under 31, the script would stop; left out.
    The script keeps 510 rows, 254 on the grid, 1 without a track (OUTLIER): 253 samples. The
    largest id is 10: train 1..7, val 8 (round(8.0)), test 9, 10.
    """
    rows = []
    for vehicle, first, lane, y0 in ((1, 0, 1, 200), (2, 5, 2, 240), (7, 0, 3, 220)):
        rows += _vehicle(vehicle, list(range(first, first + 90)), lane, y0)
    for vehicle, first, lane, y0 in ((8, 3, 1, 160), (9, 0, 2, 300), (10, 8, 3, 120)):
        rows += _vehicle(vehicle, list(range(first, first + 90)), lane, y0)
    rows += _vehicle(3, [f for f in range(10, 100) if not 50 <= f < 55], 3, 170)
    four = _vehicle(4, list(range(80)), 2, 140)
    four[60] = {**four[60], ns.LOCAL_Y: four[60][ns.LOCAL_Y] + 200.0}
    rows += four
    five = _vehicle(5, list(range(90)), 1, 260)
    for frame in (0, 2, 40):
        five.append({**five[frame], ns.LOCAL_Y: five[frame][ns.LOCAL_Y] + 2.5})
    rows += five
    rows += _vehicle(6, list(range(20, 40)), 3, 300)
    return rows


def reference_population(table: np.ndarray) -> tuple[set[tuple[int, int, str]], int]:
    """(the script's kept rows on the even grid as (vehicle, frame, split), kept rows in all),
    by the plain-loop reference: `table` (n, 5) [vehicle, frame, x, y, lane] of one recording.
    The edge filter per vehicle (its rows only, in frame order, stable), the split by the
    script's rule: float32 products, MATLAB's round."""
    order = sorted(range(len(table)), key=lambda i: (table[i, 0], table[i, 1]))
    table = table[order].astype(F)
    largest = table[:, 0].max()
    population, kept_rows = set(), 0
    for vehicle in np.unique(table[:, 0]):
        own = table[table[:, 0] == vehicle]
        for row, kept in zip(own, reference_kept(own), strict=True):
            kept_rows += kept
            if kept and int(row[1]) % 2 == 0:
                population.add((int(vehicle), int(row[1]), reference_split(vehicle, largest)))
    return population, kept_rows


def _table(rows: list[dict]) -> np.ndarray:
    columns = (s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_X, ns.LOCAL_Y, s.LANE_ID)
    return np.array([[r[c] for c in columns] for r in rows], dtype=np.float64)


def build_samples(build: Path) -> set[tuple[int, int, str]]:
    """(ego vehicle, present Frame_ID, split) of every sample of a build."""
    found = set()
    for split in ("train", "val", "test"):
        table = pl.read_parquet(layout.samples_path(build, split))
        assert table[s.START_STEP].to_list() == (table[s.PRESENT_STEP] - 15).to_list()
        for vehicle, step in table.select(s.EGO_VEHICLE_ID, s.PRESENT_STEP).iter_rows():
            found.add((vehicle, 2 * step, split))
    return found


def track_frames(build: Path) -> set[tuple[int, int]]:
    """(vehicle, Frame_ID) of every row of a build's tracks tables."""
    tracks = open_build(build).tracks().select(s.VEHICLE_ID, s.FRAME_ID).collect()
    return set(tracks.iter_rows())


@pytest.fixture(scope="module")
def script_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("protocol")
    write_txt(root / "raw" / "trajectories-0750am-0805am.txt", script_recording())
    run_build([root / "raw"], root / "build", CSLSTM)
    return root / "build"


def test_samples_are_the_scripts_kept_rows_on_the_grid(script_build: Path) -> None:
    population, kept = reference_population(_table(script_recording()))
    assert (kept, len(population)) == (510, 254)
    tracked = track_frames(script_build)
    unmatched = {(v, f) for v, f, _ in population if (v, f) not in tracked}
    assert unmatched == {OUTLIER}
    assert build_samples(script_build) == {row for row in population if row[:2] not in unmatched}
    manifest = open_build(script_build).manifest
    assert manifest.config.protocol is Protocol.CS_LSTM
    counts = manifest.to_dict()["counts"]
    assert counts["cslstm_rows"] == {"kept": 510, "too_short": 20, "on_grid": 254, "unmatched": 1}
    assert counts["samples"] == 253 and counts["rows_dropped"]["position_outlier"] == 1
    # train: vehicles 1, 2, 7 (29 each), 3 (26), 4 (24 - 1), 5 (30); val: 8; test: 9, 10
    assert manifest.splits == {"train": 166, "val": 29, "test": 58}
    [recording] = manifest.recordings
    assert recording.cslstm_rows == manifest.counts.cslstm_rows


def test_the_ego_is_the_only_target_and_its_future_is_its_track(script_build: Path) -> None:
    build = open_build(script_build)
    position = {
        (track, frame): (x, y)
        for track, frame, x, y in build.tracks()
        .select(s.TRACK_ID, s.FRAME_ID, s.X_M, s.Y_M)
        .collect()
        .iter_rows()
    }
    masked_after_end, no_next_step = 0, set()
    for split in ("train", "val", "test"):
        samples = build.samples(split)
        batch = build.graphs(split, np.arange(samples.height))
        assert samples[s.N_TARGETS].to_list() == [1] * samples.height
        assert (batch.node_sample[batch.target_node] == np.arange(samples.height)).all()
        assert batch.node_is_ego[batch.target_node].all()
        assert (batch.node_step[batch.target_node] == 15).all()
        rows = samples.select(
            s.EGO_TRACK_ID, s.PRESENT_STEP, s.ORIGIN_X_M, s.ORIGIN_Y_M, s.EGO_VEHICLE_ID
        )
        for i, (track, present, ox, oy, vehicle) in enumerate(rows.iter_rows()):
            for f in range(25):
                frame = 2 * (present + 1 + f)
                recorded = (track, frame) in position
                assert batch.target_mask[i, f] == recorded
                if recorded:
                    x, y = position[(track, frame)]
                    assert batch.target_xy[i, f].tolist() == [x - ox, y - oy]
                else:
                    masked_after_end += 1
            if not batch.target_mask[i, 0]:
                no_next_step.add((vehicle, 2 * present))
    assert masked_after_end > 1000  # rows kept up to 0.2 s before their vehicle's last frame
    # The script keeps a row when its vehicle goes on for 0.2 s; our tracks end at the gap of
    # vehicle 3 (frames 50..54) and at the outlier of vehicle 4 (frame 60).
    assert no_next_step == {(3, 48), (4, 58)}


def test_history_without_the_ego_has_no_nodes(script_build: Path) -> None:
    """Where the ego's track starts after the window does (vehicle 3 after its gap, vehicle 5 at
    step 14, vehicle 4 after its outlier), the steps before it hold no node; the others hold
    what the aigem rules give with the ego included as target, from the track's first step."""
    build = open_build(script_build)
    rec = build.recordings[0]
    aigem = replace(build.config, protocol=Protocol.AIGEM, ego_is_target=True)
    checked = set()
    for split in ("train", "val", "test"):
        samples = build.samples(split)
        first, _ = rec.track_steps(samples[s.EGO_TRACK_ID].to_numpy())
        late = np.flatnonzero(first > samples[s.START_STEP].to_numpy())
        for i in late.tolist():
            ego, start = samples.row(i, named=True)[s.EGO_TRACK_ID], int(samples[s.START_STEP][i])
            ours = build.graphs(split, np.array([i]))
            skipped = int(first[i]) - start
            assert ours.node_step.min() == skipped
            ref = induce_graphs(rec, np.array([ego]), np.array([start]), aigem, skipped)
            for name in ("node_step", "node_track", "node_is_ego", "node_features"):
                np.testing.assert_array_equal(getattr(ours, name), getattr(ref, name))
            np.testing.assert_array_equal(ours.edges["spatial"].index, ref.edges["spatial"].index)
            np.testing.assert_array_equal(ours.edges["temporal"].index, ref.edges["temporal"].index)
            ego_target = ref.target_node[ref.node_is_ego[ref.target_node]]
            np.testing.assert_array_equal(ours.target_node, ego_target)
            checked.add(int(samples[s.EGO_VEHICLE_ID][i]))
    assert checked == {3, 4, 5}
    # vehicle 5's first sample starts at step -1
    assert build.samples("train").filter(pl.col(s.START_STEP) < 0)[s.EGO_VEHICLE_ID].to_list() == [
        5
    ]


def test_a_quirky_synthetic_recording_gives_the_reference_population(tmp_path: Path) -> None:
    """The portal CSV with duplicates, conflicts, empty fields and gaps: the rows that reach
    cleaning (the reader's) make the script's population; what cleaning removed is counted."""
    write_synthetic(
        tmp_path / "raw",
        SynthConfig(raw_format=RawFormat.PORTAL, recordings=1, minutes=0.2, seed=4, quirks=True),
    )
    result = run_build([tmp_path / "raw"], tmp_path / "build", CSLSTM)
    [path] = sorted((tmp_path / "raw").glob("*.csv"))
    read = read_file_recordings(path, CSLSTM)
    rows = read.recording_rows((US101_FIRST.location, US101_FIRST.period)).collect()
    columns = (s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_X, ns.LOCAL_Y, s.LANE_ID)
    population, kept = reference_population(rows.select(columns).to_numpy().astype(np.float64))
    tracked = track_frames(tmp_path / "build")
    samples = {row for row in population if row[:2] in tracked}
    assert build_samples(tmp_path / "build") == samples
    script = result.manifest.counts.cslstm_rows
    assert (script.kept, script.on_grid, script.samples) == (kept, len(population), len(samples))
    counts = result.manifest.counts
    assert counts.conflicting_duplicates > 0 and counts.gaps > 0 and script.kept > 2 * len(samples)


@pytest.mark.slow
def test_a_cs_lstm_build_cleaned_in_parts_is_the_build_cleaned_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The quirky portal file in parts of 4 vehicle ids (the default: one part): the same files
    and manifest, byte for byte; the script's rows are read back from all the parts."""
    write_synthetic(
        tmp_path / "raw",
        SynthConfig(raw_format=RawFormat.PORTAL, recordings=1, minutes=0.2, seed=4, quirks=True),
    )
    run_build([tmp_path / "raw"], tmp_path / "whole", CSLSTM)
    set_budget(monkeypatch, vehicles_per_part=4)
    run_build([tmp_path / "raw"], tmp_path / "parts", CSLSTM)
    files = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*.*"))
    assert len(files) > 10 and (tmp_path / "whole" / "manifest.json").exists()
    for name in files:
        assert (tmp_path / "parts" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    manifest = open_build(tmp_path / "whole").manifest
    assert manifest.counts.cslstm_rows.samples > 100
    assert manifest.recordings[0].report.vehicles > 10 * 4


def test_fit_and_evaluate_say_the_protocol(
    script_build: Path, tiny_run: Path, tmp_path: Path
) -> None:
    from ngsim_cli.aigem import app

    runner = CliRunner(env={"COLUMNS": "200"})
    run = tmp_path / "run"
    fit = runner.invoke(
        app,
        ["fit", str(script_build), "--out", str(run), "--epochs", "1", "--horizon-s", "2"]
        + ["--batch-size", "16", "--device", "cpu"],
    )
    assert fit.exit_code == 0, fit.output
    shown = runner.invoke(app, ["evaluate", str(run), "--device", "cpu"])
    assert shown.exit_code == 0, shown.output
    assert (
        "Protocol: cs-lstm (the literature's samples: CS-LSTM's kept rows on the 0.2 s grid, the "
        "sample's vehicle as the only target)" in shown.stdout
    )
    assert "constant velocity" in shown.stdout and "CS-LSTM (paper)" in shown.stdout
    # 58 test samples: vehicles 9 (frames 0..89) and 10 (8..97) at 29 even frames each from
    # their 31st; recorded 1 s later up to frame 78 and 86 (25 each), 2 s later up to 68 and 76
    assert "58 samples; evaluated actors per horizon: 1 s: 50, 2 s: 40" in shown.stdout
    # The ego is the target, at y = 0: no front or rear tables, only all and mid.
    assert "No front or rear actors among the targets: no table for them." in shown.stdout
    assert "front actors (metres)" not in shown.stdout and "mid actors (metres)" in shown.stdout
    document = json.loads(runner.invoke(app, ["evaluate", str(run), "--json"]).stdout)
    assert document["protocol"] == "cs-lstm" and document["samples"] == 58
    assert document["protocol_description"].startswith("the literature's samples")
    ours = json.loads(runner.invoke(app, ["evaluate", str(tiny_run), "--json"]).stdout)
    assert ours["protocol"] == "aigem"
    assert ours["protocol_description"] == (
        "AiGem's samples: ego windows every 8 s, the actors within 12 m of the ego at the present "
        "as targets"
    )


def test_the_build_prints_the_scripts_rows(tmp_path: Path) -> None:
    raw = write_txt(tmp_path / "raw" / "trajectories-0750am-0805am.txt", script_recording())
    result = invoke("build", raw, "--out", tmp_path / "out", "--protocol", "cs-lstm")
    assert result.exit_code == 0, result.output
    assert (
        "cs-lstm protocol: CS-LSTM's script keeps 510 rows, 254 on the 0.2 s grid (one per "
        "vehicle and even frame); 1 of those have no track at their step (cleaning removed the "
        "row) and give no sample; 20 rows of vehicles under 31 rows left out (the script stops "
        "on them)." in result.stdout
    )
    assert (
        "samples: 166 train, 29 val, 58 test (253 in all; shares 66% / 11% / 23%: the vehicle "
        "split cuts each recording's Vehicle_IDs at 70% and 80% of its largest, not its samples"
        in result.stdout
    )
    config = json.loads((tmp_path / "out" / "manifest.json").read_text())["config"]
    assert config["protocol"] == "cs-lstm"
    stats = invoke("stats", tmp_path / "out")  # the same counts, in the rows' table
    assert stats.exit_code == 0, stats.output
    rows = {}
    for line in stats.stdout.splitlines():
        cells = [cell.strip() for cell in line.strip("│ ").split("│")]
        if len(cells) == 3:
            rows[cells[0]] = cells[1]
    assert rows["kept by CS-LSTM's script (cs-lstm protocol)"] == "510"
    assert rows["of them on the grid (even frames)"] == "254"
    assert rows["without a track at their step: no sample"] == "1"
    assert rows["of vehicles under 31 rows: left out"] == "20"


@pytest.mark.parametrize(
    ("options", "fragment"),
    [
        (["--split", "time"], "--split time: "),
        (["--split", "random", "--stride-s", "2"], "--split random, --stride-s 2.0: "),
        (["--ego-target"], "--ego-target True: "),
        (["--locations", "us-101,lankershim"], "reads us-101 and i-80 only"),
    ],
)
def test_options_without_meaning_under_cs_lstm_are_refused(
    tmp_path: Path, options: list[str], fragment: str
) -> None:
    raw = write_txt(tmp_path / "a.txt", script_recording()[:10])
    out = tmp_path / "out"
    result = invoke("build", raw, "--out", out, "--protocol", "cs-lstm", *options)
    assert result.exit_code == 2
    line = error_line(result)
    assert fragment in line and "cs-lstm protocol" in line, line
    assert not out.exists()


def test_the_protocols_locations_are_checked_by_the_library_too(tmp_path: Path) -> None:
    """The cs-lstm protocol's locations live on the protocol (protocols.py), not in BuildConfig:
    the config is made, and run_build refuses it before it reads or writes anything."""
    config = BuildConfig(protocol=Protocol.CS_LSTM, locations=("us-101", "lankershim"))
    raw = write_txt(tmp_path / "a.txt", script_recording()[:10])
    with pytest.raises(
        ValueError, match=r"reads us-101 and i-80 only \(CS-LSTM's six .*lankershim"
    ):
        run_build(raw, tmp_path / "out", config)
    assert not (tmp_path / "out").exists()


def test_a_recording_the_script_does_not_read_is_an_error(tmp_path: Path) -> None:
    # 08:28 PDT: no official period; the folder names the location
    start_ms = 1118935680000 + 7_000
    rows = [make_row(1, f, local_y_ft=3.0 * f, start_ms=start_ms) for f in range(50)]
    raw = write_txt(tmp_path / "us-101" / "trajectories.txt", rows)
    out = tmp_path / "out"
    result = invoke("build", raw, "--out", out, "--protocol", "cs-lstm")
    assert_failed_cleanly(
        result, out, {}, raw, "recording us-101/0828-0828 is not one of the six", "0750am-0805am"
    )


def test_the_protocol_is_in_the_config_and_its_hash() -> None:
    assert BuildConfig().protocol is Protocol.AIGEM
    assert BuildConfig.from_dict(CSLSTM.to_dict()) == CSLSTM
    assert CSLSTM.to_dict()["protocol"] == "cs-lstm"
    old = {k: v for k, v in BuildConfig().to_dict().items() if k != "protocol"}
    assert BuildConfig.from_dict(old) == BuildConfig()  # a manifest made before the protocol
    assert layout.config_hash(CSLSTM.to_dict()) != layout.config_hash(BuildConfig().to_dict())
    with pytest.raises(ValueError, match="split time: has no meaning under the cs-lstm protocol"):
        BuildConfig(protocol=Protocol.CS_LSTM, split=SplitMode.TIME)


def test_the_protocol_and_export_cslstm_take_the_same_rows(tmp_path: Path) -> None:
    """Two implementations of the script's population side by side: on two synthetic text
    recordings without faults, the build's samples are exactly the exported `traj` rows on the
    even grid (one per vehicle and frame), recording by recording, split by split."""
    from scipy.io import loadmat

    from ngsim_graphs.cslstm import DATASET_IDS
    from ngsim_graphs.cslstm_export import FILE_NAMES, export_cslstm

    write_synthetic(
        tmp_path / "raw",
        SynthConfig(raw_format=RawFormat.TXT, recordings=2, minutes=0.2, seed=7),
    )
    export_cslstm([tmp_path / "raw"], tmp_path / "mat", allow_partial=True)
    run_build([tmp_path / "raw"], tmp_path / "build", CSLSTM)
    exported = set()
    for split, name in FILE_NAMES.items():
        traj = loadmat(tmp_path / "mat" / name)["traj"]
        even = traj[traj[:, 2] % 2 == 0]
        exported |= {(int(d), int(v), int(f), split) for d, v, f in even[:, :3]}
    built = set()
    for split in ("train", "val", "test"):
        table = pl.read_parquet(layout.samples_path(tmp_path / "build", split))
        for location, period, vehicle, step in table.select(
            s.LOCATION, s.PERIOD, s.EGO_VEHICLE_ID, s.PRESENT_STEP
        ).iter_rows():
            built.add((DATASET_IDS[(location, period)], vehicle, 2 * step, split))
    assert len(built) > 1000 and {d for d, *_ in built} == {1, 4}
    assert built == exported
