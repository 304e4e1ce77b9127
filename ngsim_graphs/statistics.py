"""What a researcher checks about a finished build before training: pure functions, no printing.

Two stages: `collect_values` gathers the per-item values (one row per sample, one spatial
in-degree per node of a seeded subset of graphs, one speed and heading per tracks row);
`summarize_build` turns them and the manifest into plain dataclasses and dicts, JSON-ready through
`BuildStatistics.to_dict`. The histograms of `plotting` take the same values.

Graph sizes come from the count columns of the samples tables: exact and cheap. Node degrees
need the graphs themselves, so they are induced for at most `max_degree_graphs` samples per split.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import polars as pl

from ngsim_graphs import edges
from ngsim_graphs import schema as s
from ngsim_graphs.build import OpenBuild
from ngsim_graphs.config import check_seed
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.manifest import json_form
from ngsim_graphs.splits import SPLIT_ORDER

SPLITS = tuple(split.value for split in SPLIT_ORDER)  # train, val, test
KINEMATIC_COLUMNS = (s.SPEED_MPS, s.HEADING_RAD)
MAX_DEGREE_GRAPHS = 300  # graphs induced per split for the node degrees


@dataclass(frozen=True)
class Distribution:
    """Summary of a set of values; every field but `count` is None when there are none."""

    count: int
    mean: float | None
    std: float | None
    min: float | None
    p5: float | None
    p50: float | None
    p95: float | None
    max: float | None


def describe(values: np.ndarray) -> Distribution:
    """Mean, population std, min, 5th/50th/95th percentiles (linear interpolation) and max."""
    values = np.asarray(values, dtype=np.float64)
    if len(values) == 0:
        return Distribution(0, None, None, None, None, None, None, None)
    p5, p50, p95 = (float(p) for p in np.percentile(values, [5, 50, 95]))
    return Distribution(
        count=len(values),
        mean=float(values.mean()),
        std=float(values.std()),
        min=float(values.min()),
        p5=p5,
        p50=p50,
        p95=p95,
        max=float(values.max()),
    )


@dataclass(frozen=True)
class BuildValues:
    """Per-item values of a build: the input of every distribution and histogram."""

    samples: dict[str, pl.DataFrame]  # split -> its samples table (SAMPLE_SCHEMA and counts)
    degree_graphs: dict[str, int]  # split -> graphs induced for the degrees
    spatial_in_degree: dict[str, np.ndarray]  # split -> (N,) int64 per node of those graphs
    speed_mps: np.ndarray  # (R,) float64 every tracks row (0.2 s grid), all recordings
    heading_rad: np.ndarray  # (R,) float64 likewise, from +y towards +x


@dataclass(frozen=True)
class TargetShare:
    """Targets (actor nodes at the present step) of a split, and those with a full future."""

    targets: int
    full_future: int
    full_future_share: float | None  # None when the split has no targets


@dataclass(frozen=True)
class DegreeSummary:
    """Spatial in-degree per node (ego included, all history steps) over a subset of graphs."""

    sampled_graphs: int
    spatial_in_degree: Distribution


@dataclass(frozen=True)
class BuildStatistics:
    """Everything `ngsim-graphs stats` reports. Keys of the dicts are split or recording names."""

    build_dir: str
    config: dict[str, Any]  # its config and, under "limits", its source's: what config_hash covers
    config_hash: str
    counts: dict[str, int]  # the manifest's input and cleaning counts
    recordings: list[dict[str, Any]]  # name, location, period, vehicles, tracks, grid_rows, samples
    samples: dict[str, int]  # split -> samples
    graph_size: dict[str, dict[str, Distribution]]  # split -> count column -> per graph
    node_degree: dict[str, DegreeSummary]  # split -> degrees over its sampled graphs
    targets: dict[str, TargetShare]  # split -> targets and full-future share
    future_horizon_s: float  # what a "full future" covers (5 s by default)
    kinematics: dict[str, Distribution]  # speed_mps, heading_rad over all tracks rows
    scaler: dict[str, Any]  # the manifest's fitted ranges
    warnings: list[str]  # the build's warnings (splits that are empty or tiny)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values (None where a split is empty)."""
        return asdict(self)


def graph_size_columns(edge_types: tuple[str, ...]) -> tuple[str, ...]:
    """The count columns a graph's size is told by: nodes, each edge type's edges, targets."""
    return edges.count_columns(edge_types)[:-1]  # but the targets with a full future


def graph_size(samples: pl.DataFrame, edge_types: tuple[str, ...]) -> dict[str, Distribution]:
    """Nodes, each edge type's edges (the build's `edge_types`) and targets per graph, from the
    count columns."""
    return {name: describe(samples[name].to_numpy()) for name in graph_size_columns(edge_types)}


def target_share(samples: pl.DataFrame) -> TargetShare:
    """How many of a split's targets are recorded at every future step."""
    targets, full = int(samples[s.N_TARGETS].sum()), int(samples[s.N_FULL_TARGETS].sum())
    return TargetShare(targets, full, full / targets if targets else None)


def pick_samples(n_samples: int, max_samples: int, seed: int) -> np.ndarray:
    """A seeded random subset of at most `max_samples` sample ids of 0..n_samples-1, ascending."""
    rng = np.random.default_rng(seed)
    chosen = rng.choice(n_samples, size=min(n_samples, max_samples), replace=False)
    return np.sort(chosen).astype(np.int64)


def spatial_in_degree(build: OpenBuild, split: str, sample_ids: np.ndarray) -> np.ndarray:
    """(N,) spatial in-degree of every node of the given samples' graphs (all history steps);
    none where the build has no spatial edges."""
    if len(sample_ids) == 0 or edges.SPATIAL.name not in build.config.edge_types:
        return np.zeros(0, dtype=np.int64)
    batch = build.graphs(split, sample_ids)
    return np.bincount(batch.edges["spatial"].index[1], minlength=len(batch.node_track)).astype(
        np.int64
    )


def read_kinematics(build: OpenBuild) -> dict[str, np.ndarray]:
    """Speed and heading of every tracks row, reading only those columns of the tracks files."""
    if not build.manifest.recordings:
        return {name: np.zeros(0) for name in KINEMATIC_COLUMNS}
    try:
        frame = build.tracks().select(KINEMATIC_COLUMNS).collect()
    except pl.exceptions.PolarsError as err:
        raise NgsimInputError(
            build.root / "tracks", f"unreadable tracks table (damaged?): {err}"
        ) from None
    return {
        name: frame[name].drop_nulls().to_numpy().astype(np.float64) for name in KINEMATIC_COLUMNS
    }


def collect_values(
    build: OpenBuild, max_degree_graphs: int = MAX_DEGREE_GRAPHS, seed: int = 0
) -> BuildValues:
    """Read the samples tables and tracks columns, and induce the degree subset of each split."""
    samples = {split: build.samples(split) for split in SPLITS}
    picked = {
        split: pick_samples(samples[split].height, max_degree_graphs, seed) for split in SPLITS
    }
    kinematics = read_kinematics(build)
    return BuildValues(
        samples=samples,
        degree_graphs={split: len(ids) for split, ids in picked.items()},
        spatial_in_degree={
            split: spatial_in_degree(build, split, ids) for split, ids in picked.items()
        },
        speed_mps=kinematics[s.SPEED_MPS],
        heading_rad=kinematics[s.HEADING_RAD],
    )


def _recordings_table(build: OpenBuild) -> list[dict[str, Any]]:
    return [
        {
            "name": r.name,
            "location": r.location,
            "period": r.period,
            "vehicles": r.report.vehicles,
            "tracks": r.report.tracks,
            "grid_rows": r.report.grid_rows,
            "samples": dict(r.samples),
        }
        for r in build.entries
    ]


def summarize_build(build: OpenBuild, values: BuildValues) -> BuildStatistics:
    """The statistics of a build from its manifest and its collected values."""
    manifest, config = build.manifest, build.config
    return BuildStatistics(
        build_dir=str(build.root),
        config=manifest.settings(),  # keys sorted, as the manifest holds them
        config_hash=manifest.config_hash,
        counts=json_form(manifest.counts.to_dict()),
        recordings=_recordings_table(build),
        samples={split: values.samples[split].height for split in SPLITS},
        graph_size={
            split: graph_size(values.samples[split], config.edge_types) for split in SPLITS
        },
        node_degree={
            split: DegreeSummary(
                values.degree_graphs[split], describe(values.spatial_in_degree[split])
            )
            for split in SPLITS
        },
        targets={split: target_share(values.samples[split]) for split in SPLITS},
        future_horizon_s=round(config.future_steps * config.time_step_s, 6),
        kinematics={
            s.SPEED_MPS: describe(values.speed_mps),
            s.HEADING_RAD: describe(values.heading_rad),
        },
        scaler=json_form(manifest.scaler.to_dict()),
        warnings=list(manifest.warnings),
    )


def build_statistics(
    build: OpenBuild, max_degree_graphs: int = MAX_DEGREE_GRAPHS, seed: int = 0
) -> tuple[BuildStatistics, BuildValues]:
    """The statistics of a build, and the values behind them (for histograms); `seed` chooses
    the graphs of the degree statistics (ValueError for no seed: check_seed)."""
    check_seed("seed", seed)
    values = collect_values(build, max_degree_graphs, seed)
    return summarize_build(build, values), values
