"""A finished build, opened: graphs against the brute force, samples tables, byte-identical
rebuilds and clear errors for what is not a finished build.

One synthetic input (two recordings of 1.5 minutes, with the quirks of real exports: frame gaps
make vehicles of two tracks) is built once per session and shared with test_scaling.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest
from conftest import set_budget
from polars.testing import assert_frame_equal
from test_cli_ngsim import invoke
from test_graphs import SampleGraph, assert_same_graph, brute_force_graph, fast_graphs
from test_grid import AS_STORED, brute_force_pairs

from ngsim_graphs import integrity, layout, storage
from ngsim_graphs import schema as s
from ngsim_graphs.build import OpenBuild, open_build, verify_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.engine import tasks
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.grid import pair_table
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.synth.formats import write_synthetic

SYNTH = SynthConfig(raw_format=RawFormat.CSV, recordings=2, minutes=1.5, seed=7, quirks=True)
SPLITS = ("train", "val", "test")
COUNTS = ("n_nodes", "n_spatial_edges", "n_temporal_edges", "n_targets", "n_targets_full_future")
_BUILT: dict[str, Path] = {}
_GRAPHS: dict[tuple[Path, str], GraphBatch] = {}


def synthetic_build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(raw folder, build folder) of SYNTH with the default BuildConfig, made once per session."""
    if not _BUILT:
        root = tmp_path_factory.mktemp("synthetic")
        write_synthetic(root / "raw", SYNTH)
        run_build([root / "raw"], root / "build", BuildConfig())
        _BUILT.update(raw=root / "raw", build=root / "build")
    return _BUILT["raw"], _BUILT["build"]


def all_graphs(build: OpenBuild, split: str) -> GraphBatch:
    """The graphs of every sample of a split, in sample order (induced once per session)."""
    key = (build.root, split)
    if key not in _GRAPHS:
        _GRAPHS[key] = build.graphs(split, np.arange(build.samples(split).height))
    return _GRAPHS[key]


def grid_tables(build: OpenBuild) -> dict[tuple[str, str], pl.DataFrame]:
    """Each recording's tracks Parquet as a grid-node table, keyed by (location, period)."""
    tables = {}
    for entry in build.manifest.recordings:
        tracks = pl.read_parquet(layout.tracks_path(build.root, entry.location, entry.period))
        tables[(entry.location, entry.period)] = tracks.select(
            (pl.col(s.TIME_S) / build.config.time_step_s).round().cast(pl.Int32).alias(s.STEP),
            s.TRACK_ID, s.VEHICLE_ID, s.X_M, s.Y_M, s.HEADING_RAD, s.SPEED_MPS,
        )  # fmt: skip
    return tables


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> OpenBuild:
    return open_build(synthetic_build(tmp_path_factory)[1])


@pytest.fixture(scope="module")
def tables(built: OpenBuild) -> dict[tuple[str, str], pl.DataFrame]:
    return grid_tables(built)


def graph_count_row(graph: SampleGraph) -> tuple[int, ...]:
    full = sum(all(mask) for _, _, mask, _ in graph.targets)
    return len(graph.nodes), len(graph.spatial), len(graph.temporal), len(graph.targets), full


@pytest.mark.parametrize("split", SPLITS)
def test_graphs_in_any_order_match_the_brute_force(
    built: OpenBuild, tables: dict, split: str
) -> None:
    samples = built.samples(split)
    rng = np.random.default_rng(len(split))
    ids = rng.permutation(samples.height)[:25]
    recordings = samples[ids]["period"].unique()
    assert len(recordings) == 2, "the shuffled samples should mix both recordings"
    fast = fast_graphs(built.graphs(split, ids))
    assert len(fast) == len(ids)
    for sample_id, graph in zip(ids.tolist(), fast, strict=True):
        row = samples.row(sample_id, named=True)
        table = tables[(row[s.LOCATION], row[s.PERIOD])]
        brute = brute_force_graph(table, row[s.EGO_TRACK_ID], row[s.START_STEP], built.config)
        assert_same_graph(graph, brute)
        assert graph_count_row(brute) == tuple(row[c] for c in COUNTS)
        assert brute.nodes[-1][0] == built.config.history_steps - 1


def test_a_vehicle_with_two_tracks_is_two_nodes(built: OpenBuild, tables: dict) -> None:
    """The quirky input has frame gaps: some graphs hold two tracks of one vehicle, never joined."""
    # Every train graph (those of a vehicle with a gap can lie anywhere in the split).
    n_samples = built.samples("train").height
    batch = all_graphs(built, "train")
    vehicle_of = pl.concat([t.select(s.TRACK_ID, s.VEHICLE_ID).unique() for t in tables.values()])
    assert vehicle_of[s.TRACK_ID].is_unique().all()  # track ids are unique across recordings
    nodes = pl.DataFrame({"sample": batch.node_sample, s.TRACK_ID: batch.node_track}).unique()
    per_sample = (
        nodes.join(vehicle_of, on=s.TRACK_ID)
        .group_by("sample")
        .agg(
            pl.col(s.TRACK_ID).n_unique().alias("tracks"),
            pl.col(s.VEHICLE_ID).n_unique().alias("vehicles"),
        )
    )
    assert per_sample.height == n_samples
    assert per_sample.filter(pl.col("tracks") > pl.col("vehicles")).height > 0
    src, dst = batch.edges["temporal"].index
    assert np.array_equal(batch.node_track[src], batch.node_track[dst])
    assert np.array_equal(batch.node_step[dst], batch.node_step[src] + 1)


@pytest.mark.parametrize("split", SPLITS)
def test_samples_table_ids_order_and_counts(built: OpenBuild, split: str) -> None:
    samples = built.samples(split)
    assert samples.height > 0
    assert samples.columns == [*s.SAMPLE_SCHEMA.names(), *COUNTS]
    assert dict(samples.select(s.SAMPLE_SCHEMA.names()).schema) == dict(s.SAMPLE_SCHEMA)
    assert samples[s.SAMPLE_ID].to_list() == list(range(samples.height))
    order = [s.LOCATION, s.PERIOD, s.EGO_TRACK_ID, s.START_STEP]
    assert samples.select(order).equals(samples.select(order).sort(order))
    assert (samples[s.PRESENT_STEP] - samples[s.START_STEP] == built.config.history_steps - 1).all()
    arrays = built.sample_arrays(split)
    assert np.array_equal(arrays["ego_track_id"], samples[s.EGO_TRACK_ID].to_numpy())
    assert np.array_equal(arrays["start_step"], samples[s.START_STEP].to_numpy())
    names = [
        (e.location, e.period) for e in sorted(built.manifest.recordings, key=lambda e: e.index)
    ]
    assert [names[i] for i in arrays["recording_index"]] == list(
        samples.select(s.LOCATION, s.PERIOD).iter_rows()
    )
    assert built.manifest.splits[split] == samples.height
    # Counts equal those of the induced graphs, sample by sample.
    batch = all_graphs(built, split)

    def per(nodes: np.ndarray) -> np.ndarray:
        return np.bincount(batch.node_sample[nodes], minlength=samples.height)

    full = batch.target_node[batch.target_mask.all(axis=1)]
    expected = np.stack(
        [np.diff(batch.node_ptr), per(batch.edges["spatial"].index[0]), per(batch.edges["temporal"].index[0]),
         per(batch.target_node), per(full)], axis=1,
    )  # fmt: skip
    assert np.array_equal(samples.select(COUNTS).to_numpy(), expected)


def test_samples_are_every_window_once_split_by_vehicle(built: OpenBuild, tables: dict) -> None:
    config = built.config
    samples = pl.concat(
        [built.samples(split).with_columns(pl.lit(split).alias("split")) for split in SPLITS]
    )
    key = [s.LOCATION, s.PERIOD, s.EGO_TRACK_ID, s.START_STEP]
    assert samples.select(key).is_duplicated().sum() == 0  # no window in two splits
    for (location, period), table in tables.items():
        mine = samples.filter((pl.col(s.LOCATION) == location) & (pl.col(s.PERIOD) == period))
        # every window of every track: starts first, first + 40, ... while 41 steps fit
        expected = []
        per_track = table.group_by(s.TRACK_ID).agg(pl.col(s.STEP).min(), pl.len()).sort(s.TRACK_ID)
        for track, first, n in per_track.iter_rows():
            expected += [
                (track, st)
                for st in range(first, first + n - config.window_steps + 1, config.stride_steps)
            ]
        assert sorted(mine.select(s.EGO_TRACK_ID, s.START_STEP).iter_rows()) == expected
        # origin: the ego's position at the present step
        origins = mine.join(
            table.rename({s.TRACK_ID: s.EGO_TRACK_ID, s.STEP: s.PRESENT_STEP}),
            on=[s.EGO_TRACK_ID, s.PRESENT_STEP],
        )
        assert origins.height == mine.height
        assert (origins[s.ORIGIN_X_M] == origins[s.X_M]).all() and (
            origins[s.ORIGIN_Y_M] == origins[s.Y_M]
        ).all()
        assert (origins[s.EGO_VEHICLE_ID] == origins[s.VEHICLE_ID]).all()
        # the vehicle rule with the recording's largest Vehicle_ID
        max_id = table[s.VEHICLE_ID].max()
        matlab_round = lambda x: math.floor(x + 0.5)  # noqa: E731 - halves up, not to even
        rule = (
            pl.when(pl.col(s.EGO_VEHICLE_ID) <= matlab_round(0.7 * max_id)).then(pl.lit("train"))
            .when(pl.col(s.EGO_VEHICLE_ID) <= matlab_round(0.8 * max_id)).then(pl.lit("val"))
            .otherwise(pl.lit("test"))
        )  # fmt: skip
        assert mine.select((rule == pl.col("split")).all()).item()
    assert set(samples["split"]) == set(SPLITS)


def build_files(root: Path) -> dict[str, bytes]:
    files = sorted(p for p in root.rglob("*") if p.suffix in (".parquet", ".npy"))
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def assert_same_build(first: Path, other: Path) -> None:
    """Every file of the two builds, the manifest included, byte for byte the same."""
    before, after = build_files(first), build_files(other)
    assert before.keys() == after.keys()
    assert [name for name in before if before[name] != after[name]] == []
    assert (other / "manifest.json").read_bytes() == (first / "manifest.json").read_bytes()


@pytest.mark.parametrize("jobs", [1, 3])
def test_the_same_build_twice_is_byte_identical(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, jobs: int
) -> None:
    """Also with three worker processes (the first build had one): files and manifest alike."""
    raw, first = synthetic_build(tmp_path_factory)
    run_build([raw], tmp_path / "again", BuildConfig(), jobs=jobs)
    before = build_files(first)
    assert sum(name.endswith(".npy") for name in before) == 2 * 10 + 3 * 3
    assert sum(name.endswith(".parquet") for name in before) == 2 + 3  # tracks, samples
    assert_same_build(first, tmp_path / "again")


def test_a_recording_built_in_pieces_of_steps_is_the_recording_built_at_once(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The grid rows made 3,000 at a time, and the pairs found, written and used 2,000 grid
    rows at a time (about 20 pieces a recording here; the default is one), three at once on
    threads: every file of the build is the same, the manifest included."""
    raw, first = synthetic_build(tmp_path_factory)
    set_budget(monkeypatch, piece_rows=2_000)
    set_budget(monkeypatch, grid_rows=3_000)
    monkeypatch.setattr(pl, "thread_pool_size", lambda: 3)  # threads.in_order's
    run_build([raw], tmp_path / "pieces", BuildConfig(), jobs=1)
    assert open_build(first).manifest.counts.proximity_edges > 20_000
    assert_same_build(first, tmp_path / "pieces")


@pytest.mark.slow
def test_a_recording_cleaned_a_few_vehicles_at_a_time_is_the_recording_cleaned_at_once(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each part cleaned 300 raw rows at a time (a vehicle or two; the default holds a part
    here), its evidence of the speed check staged and streamed: the tracks numbered alike, the
    medians alike, and every file of the build the same, byte for byte (the manifest too)."""
    raw, first = synthetic_build(tmp_path_factory)
    groups, vehicle_groups = [], tasks.vehicle_groups

    def counted(raw: pl.LazyFrame, most_rows: int) -> list[pl.Expr]:
        groups.append(vehicle_groups(raw, most_rows))
        return groups[-1]

    set_budget(monkeypatch, clean_rows=300)
    monkeypatch.setattr(tasks, "vehicle_groups", counted)
    run_build([raw], tmp_path / "groups", BuildConfig(), jobs=1)
    assert sum(len(g) for g in groups) > 10 * len(groups) > 10  # 10 groups a part and more
    assert_same_build(first, tmp_path / "groups")


def test_tables_streamed_in_small_row_groups_hold_the_same_rows(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The samples tables streamed from the recordings' staged samples, and the tracks tables
    from their staged parts, 100 rows a row group (the default holds each here in one): the
    same rows, the samples numbered over both recordings. The grid rows, made 3,000 at a time
    from such tracks tables (each range reads the row groups of its times), and every other
    file of the build are the same, byte for byte."""
    raw, first = synthetic_build(tmp_path_factory)
    monkeypatch.setattr(storage, "SINK_ROW_GROUP_ROWS", 100)
    set_budget(monkeypatch, grid_rows=3_000)  # grid rows of many row groups' times
    run_build([raw], tmp_path / "streamed", BuildConfig(), jobs=1)
    before, after = build_files(first), build_files(tmp_path / "streamed")
    samples = [name for name in before if name.startswith(layout.SAMPLES_DIR)]
    tracks = [name for name in before if name.startswith(layout.TRACKS_DIR)]
    assert (len(samples), len(tracks)) == (3, 2)
    assert [name for name in before if before[name] != after[name]] == sorted(tracks + samples)
    for name in samples + tracks:
        whole, streamed = (
            pl.read_parquet(first / name),
            pl.read_parquet(tmp_path / "streamed" / name),
        )
        if name in samples:
            assert streamed[s.LOCATION].n_unique() == 2 or streamed[s.PERIOD].n_unique() == 2
        assert_frame_equal(whole, streamed)
        groups = pq.ParquetFile(tmp_path / "streamed" / name).metadata.num_row_groups
        assert groups == -(-whole.height // 100) > 1


def test_recordings_cleaned_a_few_vehicles_at_a_time_are_the_recordings_cleaned_at_once(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Parts of 8 vehicle ids (a dozen and more a recording here; the default is one): the
    same build, byte for byte, manifest included; its duplicates, outliers, jumps and gaps are
    counted over parts, the speed column's medians taken over all of them."""
    raw, first = synthetic_build(tmp_path_factory)
    set_budget(monkeypatch, vehicles_per_part=8)
    run_build([raw], tmp_path / "parts", BuildConfig(), jobs=1)
    before, after = build_files(first), build_files(tmp_path / "parts")
    assert before.keys() == after.keys()
    assert [name for name in before if before[name] != after[name]] == []
    manifest = (tmp_path / "parts" / "manifest.json").read_bytes()
    assert manifest == (first / "manifest.json").read_bytes()
    counts = open_build(first).manifest.counts
    assert min(counts.gaps, counts.tracks) > 0
    for entry in open_build(first).manifest.recordings:
        assert entry.report.vehicles > 12 * 8
        assert entry.report.speed_rows_compared > 1_000


def test_open_build_without_manifest(tmp_path: Path) -> None:
    (tmp_path / "tracks").mkdir()
    with pytest.raises(
        NgsimInputError, match=r"an unfinished build \(interrupted\?\): no manifest"
    ):
        open_build(tmp_path)
    with pytest.raises(NgsimInputError, match="no such build directory"):
        open_build(tmp_path / "missing")
    (tmp_path / "file").write_text("x")
    with pytest.raises(NgsimInputError, match="not a directory"):
        open_build(tmp_path / "file")


def test_open_build_of_another_format_version(built: OpenBuild, tmp_path: Path) -> None:
    manifest = dict(built.manifest.to_dict(), format_version=99)
    (tmp_path / layout.MANIFEST_NAME).write_text(json.dumps(manifest))
    with pytest.raises(NgsimInputError, match=r"format version 99; expected 4 or 3") as err:
        open_build(tmp_path)
    assert str(tmp_path / layout.MANIFEST_NAME) in str(err.value)


def test_the_proximity_table_is_every_pair_of_the_grid_nodes(
    built: OpenBuild, tables: dict[tuple[str, str], pl.DataFrame]
) -> None:
    """A recording's pairs as a table, from the arrays the build wrote a range of steps at a
    time: every pair of its grid nodes within d_min, found without the sweep."""
    for entry in built.entries:
        nodes = tables[(entry.location, entry.period)]
        expected = brute_force_pairs(nodes, built.config.d_min_m).with_columns(AS_STORED)
        assert expected.height > 1_000
        assert_frame_equal(built.proximity(entry.index), expected, check_exact=True)
    with pytest.raises(ValueError, match="recording 2: the build has recordings 0..1"):
        built.proximity(2)


def reseal(build: Path, **changes: object) -> dict:
    """The build's manifest with `changes` (top-level keys), sealed anew over its files."""
    body = json.loads(layout.manifest_path(build).read_text())
    for key in (integrity.FILES_KEY, integrity.CHECKSUM_KEY):
        del body[key]
    return layout.write_manifest_json(build, body | changes)


def as_format_3(build: Path) -> None:
    """Make a build into what format 3 wrote: its pairs also as proximity tables (the sweep's
    float64 distances: the arrays hold them in float32), the manifest of that version sealed
    over every file."""
    opened = open_build(build)
    for entry in opened.entries:
        rec = opened.recordings[entry.index]
        low, high = rec.pair_rows[:, 0], rec.pair_rows[:, 1]
        dx = rec.node_state[high, 0] - rec.node_state[low, 0]
        dy = rec.node_state[high, 1] - rec.node_state[low, 1]
        table = pair_table(replace(rec, pair_dist=np.sqrt(dx * dx + dy * dy)))
        storage.write_parquet(table, layout.proximity_path(build, entry.location, entry.period))
    reseal(build, format_version=3)


def test_a_build_of_format_3_opens_and_verifies(
    built: OpenBuild, tables: dict[tuple[str, str], pl.DataFrame], tmp_path: Path
) -> None:
    """Its proximity tables are listed and checked like its other files, and read by nothing:
    its graphs are today's, and its tables the pairs that `proximity` gives (float32)."""
    copy = tmp_path / "format-3"
    shutil.copytree(built.root, copy)
    as_format_3(copy)
    old = open_build(copy)
    assert old.manifest.format_version == 3
    assert verify_build(copy).problems == ()
    ids = np.arange(min(50, built.samples("train").height))
    then, now = fast_graphs(old.graphs("train", ids)), fast_graphs(built.graphs("train", ids))
    assert len(then) == len(ids)
    for before, after in zip(then, now, strict=True):
        assert_same_graph(before, after)
    entry = old.entries[0]
    path = layout.proximity_path(copy, entry.location, entry.period)
    table = pl.read_parquet(path)
    nodes = tables[(entry.location, entry.period)]
    assert_frame_equal(table, brute_force_pairs(nodes, old.config.d_min_m), check_exact=True)
    assert_frame_equal(old.proximity(0), table.with_columns(AS_STORED), check_exact=True)
    path.unlink()  # listed: every open misses it
    with pytest.raises(NgsimInputError, match="missing"):
        open_build(copy)


def test_a_build_of_format_3_through_the_cli(built: OpenBuild, tmp_path: Path) -> None:
    """`stats` reads it; `build --overwrite` replaces it, its proximity tables with it."""
    copy = tmp_path / "format-3"
    shutil.copytree(built.root, copy)
    as_format_3(copy)
    assert invoke("stats", copy).exit_code == 0
    raw = _BUILT["raw"]
    result = invoke("build", raw, "--out", copy, "--overwrite")
    assert result.exit_code == 0, result.stderr
    assert open_build(copy).manifest.format_version == layout.FORMAT_VERSION == 4
    assert not (copy / layout.PROXIMITY_DIR).exists()
    assert sorted(p.name for p in copy.iterdir()) == [
        "arrays", "build.log", "manifest.json", "samples", "tracks"
    ]  # fmt: skip


def test_open_build_with_missing_arrays(built: OpenBuild, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(built.root, copy)
    entry = built.manifest.recordings[0]
    (layout.recording_arrays_dir(copy, entry.location, entry.period) / "pair_key.npy").unlink()
    with pytest.raises(NgsimInputError, match="pair_key.npy: missing: the build is incomplete"):
        open_build(copy).graphs("train", np.arange(3))


def test_graphs_of_no_samples(built: OpenBuild) -> None:
    with pytest.raises(ValueError, match="no samples asked for"):
        built.graphs("val", np.array([], dtype=np.int64))
