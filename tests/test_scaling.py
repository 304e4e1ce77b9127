"""MinMax scaling: the functions by hand, and the build's fitted ranges against a brute-force
min/max over every train sample's graph (train only: not the ranges of all splits)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import straight_track, write_txt
from test_build import all_graphs, grid_tables, synthetic_build

from ngsim_graphs import edges
from ngsim_graphs import schema as s
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.scaling import SCALED, TARGET_RANGES, MinMaxScaler
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M

NAMES = ("x_m", "y_m", "heading_rad", "speed_mps", "distance_m")
SPLITS = ("train", "val", "test")


def one(low: float, high: float, target: tuple[float, float]) -> MinMaxScaler:
    """A scaler of x_m alone: enough to scale and unscale x_m."""
    return MinMaxScaler({"x_m": low}, {"x_m": high}, {"x_m": target})


def test_scale_maps_the_fitted_range_onto_the_target() -> None:
    values = np.array([-10.0, 0.0, 30.0, 50.0])
    assert one(-10.0, 30.0, (-1.0, 1.0)).scale("x_m", values).tolist() == [-1.0, -0.5, 1.0, 2.0]
    assert one(-10.0, 30.0, (0.0, 1.0)).scale("x_m", values).tolist() == [0.0, 0.25, 1.0, 1.5]
    assert one(4.0, 4.0, (-1.0, 1.0)).scale("x_m", values).tolist() == [-1.0] * 4  # constant


def test_update_ranges_and_to_dict() -> None:
    ranges = MinMaxScaler.empty()
    assert ranges.to_dict()["x_m"] == {"min": None, "max": None, "to": [-1.0, 1.0]}
    features = np.array([[1.0, -2.0, 0.1, 5.0], [-3.0, 4.0, -0.2, 0.0]])
    ranges = ranges.widened(features, {"distance_m": np.array([7.5, 2.5])})
    ranges = ranges.widened(np.array([[0.0, 9.0, 0.0, 1.0]]), {"distance_m": np.empty(0)})
    assert ranges.to_dict() == {
        "x_m": {"min": -3.0, "max": 1.0, "to": [-1.0, 1.0]},
        "y_m": {"min": -2.0, "max": 9.0, "to": [-1.0, 1.0]},
        "heading_rad": {"min": -0.2, "max": 0.1, "to": [-1.0, 1.0]},
        "speed_mps": {"min": 0.0, "max": 5.0, "to": [0.0, 1.0]},
        "distance_m": {"min": 2.5, "max": 7.5, "to": [0.0, 1.0]},
    }
    assert set(TARGET_RANGES) == set(NAMES)


def fitted() -> MinMaxScaler:
    """x -10..30 m, y 0..100 m, heading -0.5..0.5 rad, speed 0..20 m/s, distance 2..42 m."""
    features = np.array([[-10.0, 0.0, -0.5, 0.0], [30.0, 100.0, 0.5, 20.0]])
    return MinMaxScaler.empty().widened(features, {"distance_m": np.array([2.0, 42.0])})


def test_a_value_scaled_by_hand() -> None:
    """x 20 m: (20 + 10) / 40 = 0.75 of its range -> -1 + 0.75 * 2 = 0.5; y 25 m: 0.25 -> -0.5;
    heading 0.25 rad: 0.75 -> 0.5; speed 5 m/s: 5 / 20 = 0.25 (target 0..1); distance 12 m: 0.25."""
    scaler = fitted()
    assert scaler.scale_features(np.array([[20.0, 25.0, 0.25, 5.0]])).tolist() == [
        [0.5, -0.5, 0.5, 0.25]
    ]
    assert scaler.scale_edges(edges.SPATIAL, np.array([12.0])).tolist() == [[0.25]]
    assert scaler.scale_edges(edges.TEMPORAL, np.array([0.2, 0.2])).tolist() == [  # not scaled
        [np.float32(0.2)],
        [np.float32(0.2)],
    ]
    assert scaler.scale_features(np.zeros((1, 4))).dtype == np.float32


def test_numpy_and_torch_agree_and_unscale_inverts_scale() -> None:
    torch = pytest.importorskip("torch")
    scaler = fitted()
    values = np.random.default_rng(0).uniform(-50.0, 150.0, size=(6, 3))
    for name in SCALED:
        scaled = scaler.scale(name, values)
        as_tensor = scaler.scale(name, torch.from_numpy(values))
        assert isinstance(as_tensor, torch.Tensor) and np.array_equal(as_tensor.numpy(), scaled)
        assert np.allclose(scaler.unscale(name, scaled), values, rtol=0, atol=1e-12)
        back = scaler.unscale(name, torch.from_numpy(scaled))
        assert np.array_equal(back.numpy(), scaler.unscale(name, scaled))
    x = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    scaler.unscale("x_m", x).sum().backward()  # differentiable: metres per scaled unit
    assert x.grad.tolist() == [20.0] * 3
    constant = one(4.0, 4.0, (-1.0, 1.0))
    assert constant.unscale("x_m", constant.scale("x_m", np.array([4.0]))).tolist() == [4.0]


def test_to_dict_and_from_dict_round_trip() -> None:
    for scaler in (fitted(), MinMaxScaler.empty()):
        again = MinMaxScaler.from_dict(json.loads(json.dumps(scaler.to_dict())))
        assert again == scaler and again.to_dict() == scaler.to_dict()
    assert fitted().is_fitted and not MinMaxScaler.empty().is_fitted


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.pop("speed_mps"), "has no speed_mps"),
        (lambda d: d["x_m"].update(max=True), "x_m min or max is not a number"),
        (lambda d: d["y_m"].update(min="1"), "y_m min or max is not a number"),
        (lambda d: d["distance_m"].update(to=[0.0]), "distance_m target range is not two numbers"),
    ],
)
def test_from_dict_refuses_other_forms(edit: Callable[[dict], object], message: str) -> None:
    values = fitted().to_dict()
    edit(values)
    with pytest.raises(ValueError, match=message):
        MinMaxScaler.from_dict(values)
    with pytest.raises(ValueError, match="not a mapping"):
        MinMaxScaler.from_dict([1, 2])


def pairs_within(table: pl.DataFrame, d_max_m: float) -> pl.DataFrame:
    """(step, track_a < track_b, distance) of each pair <= d_max_m: a distance matrix per step."""
    table = table.sort(s.STEP, s.TRACK_ID)
    step, track = table[s.STEP].to_numpy(), table[s.TRACK_ID].to_numpy()
    x, y = table[s.X_M].to_numpy(), table[s.Y_M].to_numpy()
    bounds = np.flatnonzero(np.diff(step)) + 1
    parts = []
    for rows in np.split(np.arange(len(step)), bounds):
        dx, dy = x[rows][:, None] - x[rows][None, :], y[rows][:, None] - y[rows][None, :]
        d = np.sqrt(dx * dx + dy * dy)
        i, j = np.triu_indices(len(rows), k=1)
        keep = d[i, j] <= d_max_m
        parts.append(
            (step[rows[i[keep]]], track[rows[i[keep]]], track[rows[j[keep]]], d[i, j][keep])
        )
    columns = [np.concatenate(c) for c in zip(*parts, strict=True)]
    return pl.DataFrame(dict(zip(["step", "track_a", "track_b", "distance"], columns, strict=True)))


def brute_force_ranges(build: OpenBuild, tables: dict) -> dict[str, dict[str, tuple[float, float]]]:
    """Min and max of node features and spatial-edge distances over every graph of each split,
    from the rules: every vehicle at every history step of every sample, by joins."""
    config = build.config
    history = pl.DataFrame({"k": list(range(config.history_steps))}, schema={"k": pl.Int32})
    features, distances = [], []
    samples = pl.concat(
        [build.samples(split).with_columns(pl.lit(split).alias("split")) for split in SPLITS]
    )
    for (location, period), table in tables.items():
        mine = samples.filter((pl.col(s.LOCATION) == location) & (pl.col(s.PERIOD) == period))
        steps = (
            mine.select(
                "split", s.SAMPLE_ID, s.EGO_TRACK_ID, s.START_STEP, s.ORIGIN_X_M, s.ORIGIN_Y_M
            )
            .join(history, how="cross")
            .with_columns((pl.col(s.START_STEP) + pl.col("k")).alias(s.STEP))
        )
        ego = table.select(
            s.STEP,
            pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
            pl.col(s.X_M).alias("ex"),
            pl.col(s.Y_M).alias("ey"),
        )
        candidates = steps.join(ego, on=[s.STEP, s.EGO_TRACK_ID]).join(table, on=s.STEP)
        dx, dy = pl.col(s.X_M) - pl.col("ex"), pl.col(s.Y_M) - pl.col("ey")
        nodes = candidates.with_columns((dx * dx + dy * dy).sqrt().alias("d")).filter(
            pl.col("d") <= config.d_sense_m
        )
        features.append(nodes.select(
            "split", (pl.col(s.X_M) - pl.col(s.ORIGIN_X_M)).alias("x_m"),
            (pl.col(s.Y_M) - pl.col(s.ORIGIN_Y_M)).alias("y_m"), s.HEADING_RAD, s.SPEED_MPS,
        ))  # fmt: skip
        actors = nodes.filter(pl.col(s.TRACK_ID) != pl.col(s.EGO_TRACK_ID))
        distances.append(actors.select("split", pl.col("d").alias("distance_m")))
        members = actors.select("split", s.SAMPLE_ID, s.STEP, s.TRACK_ID)
        pairs = (
            pairs_within(table, config.d_min_m)
            .join(members.rename({s.TRACK_ID: "track_a"}), on=[s.STEP, "track_a"])
            .join(
                members.rename({s.TRACK_ID: "track_b"}),
                on=["split", s.SAMPLE_ID, s.STEP, "track_b"],
            )
        )
        distances.append(pairs.select("split", pl.col("distance").alias("distance_m")))
    ranges: dict[str, dict[str, tuple[float, float]]] = {}
    values = {"features": pl.concat(features), "distances": pl.concat(distances)}
    for split in SPLITS:
        for frame in values.values():
            part = frame.filter(pl.col("split") == split).drop("split")
            for name in part.columns:
                ranges.setdefault(split, {})[name] = (part[name].min(), part[name].max())
    return ranges


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> OpenBuild:
    return open_build(synthetic_build(tmp_path_factory)[1])


def test_scaler_is_fitted_on_every_train_graph_and_only_those(built: OpenBuild) -> None:
    per_split = brute_force_ranges(built, grid_tables(built))
    train = per_split["train"]
    every = {
        n: (min(r[n][0] for r in per_split.values()), max(r[n][1] for r in per_split.values()))
        for n in NAMES
    }
    scaler = built.manifest.scaler.to_dict()
    for name in NAMES:
        assert scaler[name]["to"] == list(TARGET_RANGES[name])
        fitted = (scaler[name]["min"], scaler[name]["max"])
        if name == "distance_m":  # actor-actor distances are stored as float32
            assert fitted == pytest.approx(train[name], abs=1e-5)
        else:
            assert fitted == train[name]
        assert every[name][0] <= train[name][0] and train[name][1] <= every[name][1]
    assert train["distance_m"][0] > 0 and train["distance_m"][1] <= built.config.d_sense_m
    assert train["speed_mps"][0] >= 0 and all(math.isfinite(v) for r in train.values() for v in r)


def test_scaler_equals_min_max_of_the_induced_train_graphs(built: OpenBuild) -> None:
    batch = all_graphs(built, "train")
    columns = [*batch.node_features.T, batch.edges["spatial"].attribute]
    scaler = built.manifest.scaler.to_dict()
    for name, column in zip(NAMES, columns, strict=True):
        assert (scaler[name]["min"], scaler[name]["max"]) == (
            float(column.min()),
            float(column.max()),
        )


def test_the_scaler_ignores_the_val_and_test_graphs(tmp_path: Path) -> None:
    """Seven train vehicles at 21..27 ft/s, then a val and a test vehicle (Vehicle_IDs 8 and 10
    of 10) at 60 ft/s, each alone on the road: the speed range ends at the train split's."""
    rows = []
    for vehicle in (*range(1, 9), 10):
        speed_fps, first = (20.0 + vehicle if vehicle < 8 else 60.0), 100 * vehicle
        for row in straight_track(vehicle, range(first, first + 82), speed_fps=speed_fps):
            rows.append({**row, ns.LOCAL_Y: row[ns.LOCAL_Y] - speed_fps * 0.1 * first})
    run_build([write_txt(tmp_path / "a.txt", rows)], tmp_path / "build", BuildConfig())
    build = open_build(tmp_path / "build")
    assert dict(build.manifest.splits) == {"train": 7, "val": 1, "test": 1}
    speed = build.manifest.scaler.to_dict()["speed_mps"]
    assert (speed["min"], speed["max"]) == pytest.approx((21 * FEET_TO_M, 27 * FEET_TO_M))
