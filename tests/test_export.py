"""Per-sample graph tables: counts agree with the samples table, values with the graph batch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.export import graph_tables
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.synth.formats import write_synthetic


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> OpenBuild:
    root = tmp_path_factory.mktemp("export")
    write_synthetic(root / "raw", SynthConfig(recordings=1, minutes=1.5, seed=2))
    run_build([root / "raw"], root / "build", BuildConfig(stride_s=2.0))
    return open_build(root / "build")


def test_tables_match_samples_counts_and_round_trip(build: OpenBuild, tmp_path: Path) -> None:
    samples = build.samples("train")
    ids = np.array([samples.height - 1, 0, 7])
    tables = graph_tables(build.graphs("train", ids), ids)
    expected = samples.filter(pl.col("sample_id").is_in(ids.tolist())).sort("sample_id")
    per_sample = lambda name: tables[name].group_by("sample_id").len().sort("sample_id")["len"]  # noqa: E731
    assert per_sample("nodes").to_list() == expected["n_nodes"].to_list()
    assert per_sample("spatial_edges").to_list() == expected["n_spatial_edges"].to_list()
    assert per_sample("temporal_edges").to_list() == expected["n_temporal_edges"].to_list()
    targets = (
        tables["targets"].group_by("sample_id").agg(pl.col("node").n_unique()).sort("sample_id")
    )
    assert targets["node"].to_list() == expected["n_targets"].to_list()
    for name, table in tables.items():
        table.write_parquet(tmp_path / f"{name}.parquet")
        assert pl.read_parquet(tmp_path / f"{name}.parquet").equals(table)


def test_tables_use_sample_local_indices(build: OpenBuild) -> None:
    ids = np.array([4])
    tables = graph_tables(build.graphs("val", ids), ids)
    nodes = tables["nodes"]
    assert nodes["node"].to_list() == list(range(nodes.height))
    ego = nodes.filter(pl.col("is_ego"))
    assert ego.height == 16 and ego.filter(pl.col("k") == 15).select("x_m", "y_m").row(0) == (
        0.0,
        0.0,
    )
    spatial = tables["spatial_edges"]
    assert spatial["source"].max() < nodes.height and spatial["destination"].max() < nodes.height
    assert (spatial["source"] != spatial["destination"]).all()
    unrecorded = tables["targets"].filter(~pl.col("recorded"))
    assert unrecorded["x_m"].null_count() == unrecorded.height


def test_cli_export_writes_the_tables(build: OpenBuild, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from ngsim_cli.ngsim import app

    runner = CliRunner()
    result = runner.invoke(
        app,
        [
            "export",
            str(build.root),
            "--out",
            str(tmp_path / "t"),
            "--split",
            "val",
            "--samples",
            "1,3",
        ],
    )
    assert result.exit_code == 0, result.output
    samples = pl.read_parquet(tmp_path / "t" / "samples.parquet")
    assert samples["sample_id"].to_list() == [1, 3]
    nodes = pl.read_parquet(tmp_path / "t" / "nodes.parquet")
    assert nodes.height == samples["n_nodes"].sum()
    bad = runner.invoke(
        app, ["export", str(build.root), "--out", str(tmp_path / "u"), "--samples", "5:2"]
    )
    assert bad.exit_code == 2 and bad.stderr.count("\n") == 1 and "--samples" in bad.stderr
    assert not (tmp_path / "u").exists()
