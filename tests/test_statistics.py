"""ngsim_graphs.statistics and .plotting on a tiny synthetic build, checked against values computed
another way: the manifest, the Parquet files, the graphs induced directly, the target masks."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import layout
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.plotting import PLOT_NAMES, write_histograms
from ngsim_graphs.sources.ngsim.plausibility import LIMITS
from ngsim_graphs.statistics import (
    SPLITS,
    BuildStatistics,
    BuildValues,
    build_statistics,
    describe,
    pick_samples,
)
from ngsim_graphs.synth.formats import write_synthetic

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_GRAPHS = 50  # below the train split's size, so that the degree subset is a real subset


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> OpenBuild:
    """One recording of 30 s of synthetic traffic: a few hundred samples, built once."""
    root = tmp_path_factory.mktemp("stats")
    write_synthetic(root / "raw", SynthConfig(recordings=1, minutes=0.5, seed=11))
    run_build([root / "raw"], root / "build", BuildConfig())
    return open_build(root / "build")


@pytest.fixture(scope="module")
def computed(build: OpenBuild) -> tuple[BuildStatistics, BuildValues]:
    return build_statistics(build, max_degree_graphs=MAX_GRAPHS, seed=0)


def test_fixture_has_samples_in_every_split(build: OpenBuild) -> None:
    assert all(build.samples(split).height > MAX_GRAPHS // 5 for split in SPLITS)
    assert build.samples("train").height > MAX_GRAPHS


def test_describe_by_hand() -> None:
    d = describe(np.array([4, 1, 3, 2]))
    assert (d.count, d.mean, d.min, d.p50, d.max) == (4, 2.5, 1.0, 2.5, 4.0)
    assert d.p5 == pytest.approx(1.15) and d.p95 == pytest.approx(3.85)  # linear interpolation
    assert d.std == pytest.approx(np.sqrt(1.25))
    empty = describe(np.array([]))
    assert empty.count == 0 and empty.mean is None and empty.p95 is None


def test_pick_samples_is_seeded_sorted_and_bounded() -> None:
    ids = pick_samples(1000, 30, seed=4)
    assert len(ids) == 30 == len(set(ids.tolist())) and (np.diff(ids) > 0).all()
    assert ids.min() >= 0 and ids.max() < 1000
    np.testing.assert_array_equal(ids, pick_samples(1000, 30, seed=4))
    assert not np.array_equal(ids, pick_samples(1000, 30, seed=5))
    np.testing.assert_array_equal(pick_samples(7, 30, seed=0), np.arange(7))  # all, when fewer


def test_samples_per_split_match_manifest_and_parquet(build: OpenBuild, computed) -> None:
    statistics, _ = computed
    for split in SPLITS:
        rows = (
            pl.scan_parquet(build.root / "samples" / f"{split}.parquet")
            .select(pl.len())
            .collect()
            .item()
        )
        assert statistics.samples[split] == build.manifest.splits[split] == rows
    [recording] = statistics.recordings
    assert recording["samples"] == {split: statistics.samples[split] for split in SPLITS}
    assert sum(statistics.samples.values()) == statistics.counts["samples"]


def test_graph_size_equals_polars_on_the_samples_tables(build: OpenBuild, computed) -> None:
    statistics, _ = computed
    for split in SPLITS:
        table = build.samples(split)
        for column in ("n_nodes", "n_spatial_edges", "n_temporal_edges", "n_targets"):
            d = statistics.graph_size[split][column]
            assert d.count == table.height
            assert d.mean == pytest.approx(table[column].mean())
            assert (d.min, d.max) == (table[column].min(), table[column].max())
            assert d.p50 == pytest.approx(table[column].median())
            assert d.min <= d.p5 <= d.p50 <= d.p95 <= d.max


def test_degree_mean_is_spatial_edges_over_nodes_of_the_sampled_graphs(
    build: OpenBuild, computed
) -> None:
    statistics, values = computed
    for split in SPLITS:
        ids = pick_samples(build.samples(split).height, MAX_GRAPHS, seed=0)
        batch = build.graphs(split, ids)
        summary = statistics.node_degree[split]
        assert summary.sampled_graphs == len(ids) == min(MAX_GRAPHS, build.samples(split).height)
        assert summary.spatial_in_degree.count == len(batch.node_track)
        assert summary.spatial_in_degree.mean == pytest.approx(
            batch.edges["spatial"].index.shape[1] / len(batch.node_track)
        )
        assert values.spatial_in_degree[split].sum() == batch.edges["spatial"].index.shape[1]


def test_degree_over_all_graphs_matches_the_samples_table_counts(build: OpenBuild) -> None:
    statistics, _ = build_statistics(build, max_degree_graphs=10**6)
    for split in SPLITS:
        table = build.samples(split)
        assert statistics.node_degree[split].sampled_graphs == table.height
        expected = table["n_spatial_edges"].sum() / table["n_nodes"].sum()
        assert statistics.node_degree[split].spatial_in_degree.mean == pytest.approx(expected)


def test_degree_subset_depends_on_the_seed_only(build: OpenBuild, computed) -> None:
    _, values = computed
    again = build_statistics(build, max_degree_graphs=MAX_GRAPHS, seed=0)[1]
    other = build_statistics(build, max_degree_graphs=MAX_GRAPHS, seed=1)[1]
    np.testing.assert_array_equal(
        values.spatial_in_degree["train"], again.spatial_in_degree["train"]
    )
    assert not np.array_equal(values.spatial_in_degree["train"], other.spatial_in_degree["train"])


def test_full_future_share_equals_the_target_masks(build: OpenBuild, computed) -> None:
    statistics, _ = computed
    for split in SPLITS:
        batch = build.graphs(split, np.arange(build.samples(split).height))
        full = int(batch.target_mask.all(axis=1).sum())
        share = statistics.targets[split]
        assert (share.targets, share.full_future) == (len(batch.target_node), full)
        assert share.full_future_share == pytest.approx(full / len(batch.target_node))
    assert statistics.future_horizon_s == 5.0


def test_kinematics_over_every_tracks_row(build: OpenBuild, computed) -> None:
    statistics, values = computed
    entry = build.manifest.recordings[0]
    tracks = pl.read_parquet(layout.tracks_path(build.root, entry.location, entry.period))
    speed, heading = statistics.kinematics["speed_mps"], statistics.kinematics["heading_rad"]
    assert speed.count == heading.count == tracks.height == build.manifest.counts.grid_rows
    assert speed.mean == pytest.approx(tracks["speed_mps"].mean())
    assert heading.max == pytest.approx(tracks["heading_rad"].max())
    assert len(values.speed_mps) == tracks.height
    assert 0 <= speed.min <= speed.p50 <= speed.max < 45  # m/s: highway speeds
    assert -np.pi <= heading.min <= heading.max <= np.pi


def test_scaler_and_config_come_from_the_manifest(build: OpenBuild, computed) -> None:
    statistics, _ = computed
    assert statistics.scaler == build.manifest.to_dict()["scaler"]
    # the config and the limits its source applied: what the config hash covers
    assert statistics.config == {**build.manifest.to_dict()["config"], "limits": asdict(LIMITS)}
    assert BuildConfig.from_dict(statistics.config) == build.config == BuildConfig()
    assert statistics.config_hash == build.manifest.config_hash


def test_to_dict_is_plain_json(computed) -> None:
    statistics, _ = computed
    document = json.loads(json.dumps(statistics.to_dict(), allow_nan=False))
    for key in (
        "samples",
        "graph_size",
        "node_degree",
        "targets",
        "kinematics",
        "scaler",
        "config",
    ):
        assert key in document
    assert document["node_degree"]["train"]["sampled_graphs"] == MAX_GRAPHS
    assert (
        document["graph_size"]["val"]["n_nodes"]["mean"]
        == statistics.graph_size["val"]["n_nodes"].mean
    )


def test_histograms_are_png_files(tmp_path: Path, computed) -> None:
    _, values = computed
    paths = write_histograms(values, tmp_path / "plots")
    assert [p.name for p in paths] == [f"{name}.png" for name in PLOT_NAMES]
    for path in paths:
        data = path.read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 5_000
