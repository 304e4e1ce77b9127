"""`synth --format highd`: the simulated traffic in highD's files, read back by the highD source.

The round trip builds one simulation twice, from NGSIM text and from highD files, and compares the
graphs: the same samples, nodes, edges and targets, values equal up to the highD files' rounding.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import make_row, set_budget
from typer.testing import CliRunner

from ngsim_cli.ngsim import app
from ngsim_graphs import schema as s
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.schema import HighdFile
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.synth.formats import write_synthetic
from ngsim_graphs.synth.highd import LOWER, UPPER, image_layout, tracks_table

FT = 0.3048


def test_tracks_table_by_hand() -> None:
    """NGSIM frames 0, 1, 2 at 10 Hz become highD frames 5..10 at 25 Hz, in both directions.

    us-101's image: 6 lanes a side of 12 ft = 3.6576 m; the upper carriageway's median marking
    at 8 + 6 * 3.6576 = 29.946 m (rounded), the lower one's 3 m below, at 32.946 m; the section
    is 2100 ft = 640.08 m long, 25 m inside the image's edges.
    """
    rows = pl.DataFrame(
        [make_row(1, n, local_x_ft=6.0, local_y_ft=100.0 + 3.0 * n, lane_id=1, v_length=15.0, v_width=6.0)
         for n in range(3)]
    ).cast(dict(ns.RAW_SCHEMA))  # fmt: skip
    layout = image_layout("us-101")
    assert (layout.upper_markings_m[-1], layout.lower_markings_m[0]) == (29.946, 32.946)
    lower = tracks_table(rows, layout, LOWER)
    assert lower[hs.HIGHD_FRAME].to_list() == [5, 6, 7, 8, 9, 10]
    # Local_Y at frame f is 100 + 3 * (f - 5) / 2.5 ft; the box's rear is 15 ft behind it, 25 m in.
    expected_x = [25 + (100 + 1.2 * (f - 5) - 15) * FT for f in range(5, 11)]
    assert lower[hs.HIGHD_X].to_list() == pytest.approx(expected_x, abs=1e-9)
    # centre 6 ft = 1.8288 m below the median marking; the box 6 ft wide, its top 0.9144 m higher
    assert lower[hs.HIGHD_Y].to_list() == pytest.approx([32.946 + 0.9144] * 6)
    assert lower.select(
        hs.HIGHD_WIDTH, hs.HIGHD_HEIGHT, hs.HIGHD_LANE_ID, hs.HIGHD_X_VELOCITY
    ).unique().rows() == [
        (pytest.approx(15 * FT), pytest.approx(6 * FT), 9, pytest.approx(30 * FT))  # lane 1 + 6 + 2
    ]
    upper = tracks_table(rows, layout, UPPER)
    # driving towards -x: the box's left edge is the front, 25 m + 640.08 m - Local_Y from x = 0
    expected_x = [25 + 640.08 - (100 + 1.2 * (f - 5)) * FT for f in range(5, 11)]
    assert upper[hs.HIGHD_X].to_list() == pytest.approx(expected_x, abs=1e-9)
    assert upper[hs.HIGHD_Y].to_list() == pytest.approx([29.946 - 1.8288 - 0.9144] * 6)
    assert upper.select(hs.HIGHD_LANE_ID, hs.HIGHD_X_VELOCITY).unique().rows() == [
        (7, pytest.approx(-30 * FT))
    ]


@pytest.mark.slow
def test_synth_highd_is_deterministic_and_lists_its_files(tmp_path: Path) -> None:
    config = SynthConfig(raw_format=RawFormat.HIGHD, recordings=2, minutes=0.2, seed=3)
    first = write_synthetic(tmp_path / "a", config)
    second = write_synthetic(tmp_path / "b", config)
    assert [p.name for p in first] == [f"0{n}_{k.value}.csv" for n in (1, 2) for k in HighdFile]
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(first, second, strict=True))
    marker = (tmp_path / "a" / "SYNTHETIC.md").read_text()
    assert "NOT real highD" in marker and "- 02_recordingMeta.csv" in marker
    meta = [pl.read_csv(tmp_path / "a" / f"0{n}_tracksMeta.csv") for n in (1, 2)]
    assert [m[hs.HIGHD_DRIVING_DIRECTION].unique().to_list() for m in meta] == [[LOWER], [UPPER]]


# Tolerances of the round trip, from the highD files' 3 decimals (rounding by at most 0.0005):
# a world y (box x + width) is off by at most 0.001 m, a world x (box y + height / 2) by 0.00075;
# in a sample's frame, relative to the ego, twice that; a distance by sqrt(0.0015² + 0.002²) =
# 0.0025 m (0.003 with float32 storage); a heading by at most 0.0025 m over the 0.4 m a vehicle
# moves in a step at 2 m/s (slower, the heading is held): 0.00625 rad; a speed by 0.0005 m/s.
POSITION_TOL_M = 0.002
DISTANCE_TOL_M = 0.003
HEADING_TOL_RAD = 0.0065
SPEED_TOL_MPS = 0.0005 + 1e-9
NAMES = {("us-101", "0750am-0805am"): "highd-1/01", ("i-80", "0400-0415"): "highd-2/02"}


def _matched_samples(ngsim: OpenBuild, highd: OpenBuild, split: str) -> pl.DataFrame:
    """Both builds' sample ids, matched by (recording, ego vehicle, start step); highD's steps
    are one later (its time is 0.2 s later: see synth.highd)."""
    ours = ngsim.samples(split).with_columns(
        pl.concat_str(s.LOCATION, s.PERIOD, separator="/").replace_strict(
            {f"{a}/{b}": v for (a, b), v in NAMES.items()}).alias("rec"))  # fmt: skip
    theirs = highd.samples(split).with_columns(
        pl.concat_str(s.LOCATION, s.PERIOD, separator="/").alias("rec"), pl.col(s.START_STEP) - 1
    )
    keys = ["rec", s.EGO_VEHICLE_ID, s.START_STEP]
    matched = ours.join(theirs, on=keys, how="full", suffix="_h")
    assert matched.height == ours.height == theirs.height  # the same sample populations
    return matched


def _nodes(batch: GraphBatch, build: OpenBuild) -> pl.DataFrame:
    """One row per node: its sample (`pair`), step, vehicle and segment, features, and its
    distance to the ego at its step."""
    tracks = build.tracks().select(s.TRACK_ID, s.VEHICLE_ID, s.SEGMENT).unique().collect()
    f = batch.node_features
    nodes = pl.DataFrame({
        "node": np.arange(len(f)), "pair": batch.node_sample, "step": batch.node_step, s.TRACK_ID: batch.node_track,
        "ego": batch.node_is_ego, "x": f[:, 0], "y": f[:, 1], "heading": f[:, 2], "speed": f[:, 3],
    }).join(tracks, on=s.TRACK_ID, how="left")  # fmt: skip
    egos = nodes.filter("ego").select(
        "pair", "step", pl.col("x").alias("ex"), pl.col("y").alias("ey")
    )
    distance = ((pl.col("x") - pl.col("ex")) ** 2 + (pl.col("y") - pl.col("ey")) ** 2).sqrt()
    return nodes.join(egos, on=["pair", "step"]).with_columns(distance.alias("d_ego"))


def _edges(
    batch: GraphBatch, nodes: pl.DataFrame, edges: np.ndarray, dist: np.ndarray | None
) -> pl.DataFrame:
    """Edges keyed by their end nodes' (pair, step, vehicle, segment)."""
    key = nodes.select("node", "pair", "step", s.VEHICLE_ID, s.SEGMENT, "ego")
    frame = pl.DataFrame(
        {"src": edges[0], "dst": edges[1], "dist": dist if dist is not None else 0.0}
    )
    frame = frame.join(key.rename(lambda c: f"{c}_s"), left_on="src", right_on="node_s")
    return frame.join(key.rename(lambda c: f"{c}_d"), left_on="dst", right_on="node_d").drop(
        "src", "dst"
    )


def _compare_graphs(
    a: GraphBatch, b: GraphBatch, na: pl.DataFrame, nb: pl.DataFrame, config: BuildConfig
) -> None:
    """Nodes and edges of matched samples (`na`, `nb`: their _nodes)."""
    keys = ["pair", "step", s.VEHICLE_ID, s.SEGMENT]
    nodes = na.join(nb, on=keys, how="full", coalesce=True, suffix="_h")
    only = nodes.filter(pl.col("node").is_null() | pl.col("node_h").is_null())
    near = (pl.coalesce("d_ego", "d_ego_h") - config.d_sense_m).abs() <= DISTANCE_TOL_M
    assert only.filter(~near).height == 0  # a node in one graph only is at d_sense, up to rounding
    assert only.height <= 1e-4 * nodes.height
    both = nodes.filter(pl.col("node").is_not_null() & pl.col("node_h").is_not_null())
    assert (both["ego"] == both["ego_h"]).all()
    for column, tol in (("x", POSITION_TOL_M), ("y", POSITION_TOL_M), ("heading", HEADING_TOL_RAD),
                        ("speed", SPEED_TOL_MPS)):  # fmt: skip
        assert (both[column] - both[f"{column}_h"]).abs().max() <= tol, column
    flipped = only.select(*keys).with_columns(pl.lit(True).alias("flip"))
    edge_keys = [f"{k}_{end}" for end in "sd" for k in keys]
    for edges_a, edges_b, dist_a, dist_b, limit in (
        (
            a.edges["spatial"].index,
            b.edges["spatial"].index,
            a.edges["spatial"].attribute,
            b.edges["spatial"].attribute,
            config.d_min_m,
        ),
        (a.edges["temporal"].index, b.edges["temporal"].index, None, None, None),
    ):
        ea, eb = _edges(a, na, edges_a, dist_a), _edges(b, nb, edges_b, dist_b)
        edges = ea.join(eb, on=edge_keys, how="full", coalesce=True, suffix="_h")
        for end in "sd":  # an edge of a node in one graph only
            renamed = flipped.rename({c: f"{c}_{end}" for c in flipped.columns})
            edges = edges.join(renamed, on=[f"{k}_{end}" for k in keys], how="left")
        unmatched = edges.filter(pl.col("dist").is_null() | pl.col("dist_h").is_null())
        explained = pl.col("flip_s").fill_null(False) | pl.col("flip_d").fill_null(False)
        if limit is not None:  # actor-actor edges at d_min
            at_limit = (pl.coalesce("dist", "dist_h") - limit).abs() <= DISTANCE_TOL_M
            actors = ~pl.coalesce("ego_s", "ego_s_h") & ~pl.coalesce("ego_d", "ego_d_h")
            explained = explained | (at_limit & actors)
        assert unmatched.filter(~explained).height == 0
        assert (edges["dist"] - edges["dist_h"]).abs().max() <= DISTANCE_TOL_M


def _compare_targets(a: GraphBatch, b: GraphBatch, na: pl.DataFrame, nb: pl.DataFrame) -> None:
    """Targets of matched samples, keyed by vehicle: the same mask, positions within tolerance."""
    keys = ["pair", s.VEHICLE_ID, s.SEGMENT]

    def targets(batch: GraphBatch, nodes: pl.DataFrame) -> pl.DataFrame:
        index = pl.DataFrame({"node": batch.target_node, "t": np.arange(len(batch.target_node))})
        return nodes.select("node", *keys).join(index, on="node")

    both = targets(a, na).join(targets(b, nb), on=keys, suffix="_h")
    i, j = both["t"].to_numpy(), both["t_h"].to_numpy()
    assert np.array_equal(a.target_mask[i], b.target_mask[j])
    assert np.abs(a.target_xy[i] - b.target_xy[j]).max() <= POSITION_TOL_M


@pytest.mark.slow
def test_round_trip_ngsim_text_and_highd_give_the_same_graphs(tmp_path: Path) -> None:
    """One simulation (2 recordings of 1 minute: us-101 on the lower lanes, i-80 on the upper ones)
    built from NGSIM text and from highD files.

    What is compared: the sample populations exactly (recording, ego vehicle, start step; the keys
    differ by name, and highD's steps are one later, see synth.highd); the nodes, spatial and
    temporal edges and targets of every val and test sample and of every fourth train sample, keyed
    by (step, vehicle, segment) since track ids are numbered over recordings in another order
    ((highd-1, 01) is us-101, sorted first). Values agree within the tolerances above. A node or
    edge may be in one graph only where its distance is within that tolerance of d_sense (50 m) or
    d_min (25 m): rounding can put it either side (this simulation has a few such, at 49.9998 m);
    every other difference fails the test.
    """
    config = BuildConfig()
    builds = {}
    for raw_format in (RawFormat.TXT, RawFormat.HIGHD):
        raw = tmp_path / raw_format.value
        write_synthetic(raw, SynthConfig(raw_format=raw_format, recordings=2, minutes=1.0, seed=5))
        run_build([raw], tmp_path / f"build-{raw_format.value}", config)
        builds[raw_format] = open_build(tmp_path / f"build-{raw_format.value}")
    ngsim, highd = builds[RawFormat.TXT], builds[RawFormat.HIGHD]
    assert ngsim.manifest.dataset == "ngsim" and highd.manifest.dataset == "highd"
    for split in ("train", "val", "test"):
        matched = _matched_samples(ngsim, highd, split)  # the whole populations match
        if split == "train":  # the graphs of every fourth sample (of val and test: all), for time
            matched = matched.sort(s.SAMPLE_ID).gather_every(4)
        a = ngsim.graphs(split, matched[s.SAMPLE_ID].to_numpy())
        b = highd.graphs(split, matched[f"{s.SAMPLE_ID}_h"].to_numpy())
        na, nb = _nodes(a, ngsim), _nodes(b, highd)
        _compare_graphs(a, b, na, nb, config)
        _compare_targets(a, b, na, nb)


def test_cli_synth_highd_then_build_tells_the_dataset(tmp_path: Path) -> None:
    runner = CliRunner(env={"COLUMNS": "200"})
    made = runner.invoke(app, ["synth", str(tmp_path / "raw"), "--format", "highd", "--recordings", "1",
                               "--minutes", "0.5", "--seed", "2"])  # fmt: skip
    assert made.exit_code == 0, made.output
    built = runner.invoke(app, ["build", str(tmp_path / "raw"), "--out", str(tmp_path / "out")])
    assert built.exit_code == 0, built.output
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["dataset"] == "highd"
    assert sorted(Path(f["path"]).name for f in manifest["inputs"]) == [
        "01_recordingMeta.csv", "01_tracks.csv", "01_tracksMeta.csv",
    ]  # fmt: skip
    assert "highd-1" in built.stdout and "skipped" not in built.stdout


@pytest.mark.slow
def test_a_highd_build_cleaned_in_parts_is_the_build_cleaned_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """highD's cleaning in parts of 4 vehicle ids (the default: one part): the same files and
    manifest, byte for byte."""
    raw = tmp_path / "raw"
    write_synthetic(raw, SynthConfig(raw_format=RawFormat.HIGHD, recordings=1, minutes=0.5, seed=5))
    run_build([raw], tmp_path / "whole", BuildConfig())
    set_budget(monkeypatch, vehicles_per_part=4)
    run_build([raw], tmp_path / "parts", BuildConfig())
    files = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*.*"))
    assert len(files) > 10 and (tmp_path / "whole" / "manifest.json").exists()
    for name in files:
        assert (tmp_path / "parts" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    [recording] = open_build(tmp_path / "whole").manifest.recordings
    assert recording.report.vehicles > 10 * 4 and recording.report.grid_rows > 1_000
