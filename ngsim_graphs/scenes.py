"""Pictures of samples in the road frame: a panel per sample, drawn from a `GraphBatch` (metres,
the sample frame, the ego at (0, 0) at the present step), seen from above with the traffic
travelling left to right (ngsim_graphs.scene_frame: along the road to the right, the lateral
offset to the left of travel upwards). A panel is one of two views:
- the graph (ngsim_graphs.scene_graph): every node, edge and target's recorded future of the
  sample, and the d_sense circle, in equal metres on both axes;
- a followed target (ngsim_graphs.scene_target), given `follow`: that target's history,
  recorded future and predictions drawn for the eye to follow, the rest of the scene faded.
Predictions are drawn of a followed target only. For a build of synthetic data, a red label at
the top (plotting.mark_synthetic).

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot`, as in
`plotting`: no global state, no display needed.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.plotting import SYNTHETIC_BAND_IN, mark_synthetic
from ngsim_graphs.scene_frame import ALONG_LABEL, LEFT_LABEL, sample_parts, spatial_counts
from ngsim_graphs.scene_graph import GRAPH_BOX_ASPECT, draw_graph, graph_handles
from ngsim_graphs.scene_target import TARGET_BOX_ASPECT, draw_followed, target_handles

GRAPH_PANEL_IN = 6.5  # a graph panel's width: lanes in equal metres need it
TARGET_PANEL_IN = 5.0  # a followed-target panel's
TITLE_IN = 1.0  # a panel's title (up to three lines) and axis labels
LEGEND_COLUMN_IN = 2.6  # the width of a legend column, its longest label at 8 points
DPI = 120
MAX_PANELS = 64  # a picture of more would be too large to read


@dataclass(frozen=True)
class DrawnScene:
    """What one panel drew, counted from the sample.

    nodes: the sample's nodes (every history step); spatial_edges: its directed spatial edges at
    the present step (a graph draws them as undirected pairs), = ego_edges (ego<->actor, both directions) +
    actor_edges (actor<->actor, both directions); temporal_edges: all of the sample's; targets:
    the sample's targets; predicted: label -> targets whose prediction was drawn.
    """

    nodes: int
    spatial_edges: int
    ego_edges: int
    actor_edges: int
    temporal_edges: int
    targets: int
    predicted: dict[str, int]


def _check_predictions(batch: GraphBatch, predictions: Mapping[str, np.ndarray]) -> None:
    targets, future_steps = batch.target_xy.shape[:2]
    for label, values in predictions.items():
        shape = np.shape(values)
        if len(shape) != 3 or shape[0] != targets or shape[2] != 2 or shape[1] > future_steps:
            raise ValueError(
                f"predictions {label!r}: shape {shape}, expected ({targets}, K <= {future_steps}, 2)"
            )


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}" if count == 1 else f"{count} {noun}s"


def _decorate(axes: Axes, title: str, scene: DrawnScene | None) -> None:
    """The title (`title`, then the graph's counts where `scene` is given), axis labels (a
    followed-target panel has its own) and a light grid."""
    if scene is not None:
        counts = (
            f"{_plural(scene.nodes, 'node')}, {_plural(scene.temporal_edges, 'temporal edge')}, "
            f"{_plural(scene.spatial_edges, 'spatial edge')} at present, "
            f"{_plural(scene.targets, 'target')}"
        )
        title = f"{title}\n{counts}"
        axes.set_xlabel(ALONG_LABEL, fontsize=7)
        axes.set_ylabel(f"{LEFT_LABEL}, equal metres", fontsize=7)
    axes.set_title(title, fontsize=8)
    axes.tick_params(labelsize=7)
    axes.grid(alpha=0.25, linewidth=0.5)


def draw_scene(
    axes: Axes,
    batch: GraphBatch,
    sample: int,
    d_sense_m: float,
    title: str,
    predictions: Mapping[str, np.ndarray] | None = None,
    follow: int | None = None,
) -> DrawnScene:
    """Draw sample `sample` of `batch` into `axes` and return what it holds, counted from the
    sample: its graph, or with `follow` (an index into the batch's targets, one of this
    sample's) that target and its `predictions` (label -> (T, K, 2) positions in metres,
    aligned with the batch's T targets, K <= K_F; one style per label). The title is `title`,
    and under a graph its counts. No legend: see `add_legend`."""
    predictions = dict(predictions or {})
    _check_predictions(batch, predictions)
    if predictions and follow is None:
        raise ValueError("predictions are drawn of a followed target: give `follow`")
    parts = sample_parts(batch, sample)
    if follow is None:
        draw_graph(axes, batch, parts, d_sense_m)
        predicted = {}
    else:
        predicted = draw_followed(axes, batch, parts, follow, predictions)
    ego_edges, actor_edges = spatial_counts(batch, parts)
    scene = DrawnScene(
        nodes=len(parts.nodes),
        spatial_edges=ego_edges + actor_edges,
        ego_edges=ego_edges,
        actor_edges=actor_edges,
        temporal_edges=parts.temporal.shape[1],
        targets=len(parts.targets),
        predicted=predicted,
    )
    _decorate(axes, title, scene if follow is None else None)
    return scene


def add_legend(figure: Figure, labels: Sequence[str] = (), followed: bool = False) -> int:
    """One legend for every panel of `figure`, below them (it hides no scene), in as many
    columns as the figure's width holds: of a graph, or of a followed target and its
    predictions' `labels` (in the order given to `draw_scene`). Returns the legend's rows."""
    handles = target_handles(labels) if followed else graph_handles()
    columns = int(np.clip(figure.get_figwidth() // LEGEND_COLUMN_IN, 1, 4))
    figure.legend(
        handles=handles, loc="outside lower center", ncols=columns, fontsize=8, frameon=False
    )
    return math.ceil(len(handles) / columns)


def scene_figure(
    batch: GraphBatch,
    titles: Sequence[str],
    d_sense_m: float,
    predictions: Mapping[str, np.ndarray] | None = None,
    columns: int = 2,
    synthetic: bool = False,
    follow: Sequence[int] | None = None,
    title: str = "",
) -> tuple[Figure, tuple[DrawnScene, ...]]:
    """Every sample of `batch` drawn in one figure, a panel each in rows of `columns`, titled
    `titles[b]`, the figure `title`: its graph, or with `follow` (a target of each sample, an
    index into the batch's targets) that target and its predictions; marked as synthetic data
    where `synthetic` (plotting.mark_synthetic); and what each panel drew (see
    `DrawnScene`)."""
    if len(titles) != batch.n_samples:
        raise ValueError(f"{len(titles)} titles for {batch.n_samples} samples")
    if not 1 <= batch.n_samples <= MAX_PANELS:
        raise ValueError(f"{batch.n_samples} samples: draw 1 to {MAX_PANELS} at once")
    if follow is not None and len(follow) != batch.n_samples:
        raise ValueError(f"{len(follow)} followed targets for {batch.n_samples} samples")
    n_columns = min(columns, batch.n_samples)
    n_rows = math.ceil(batch.n_samples / n_columns)
    figure = Figure(layout=ConstrainedLayoutEngine(h_pad=0.1, w_pad=0.08))
    grid = figure.subplots(n_rows, n_columns, squeeze=False)
    scenes = tuple(
        draw_scene(
            axes,
            batch,
            b,
            d_sense_m,
            titles[b],
            predictions,
            None if follow is None else int(follow[b]),
        )
        for b, axes in enumerate(grid.flat[: batch.n_samples])
    )
    for axes in grid.flat[batch.n_samples :]:
        axes.remove()
    width_in, aspect = (
        (GRAPH_PANEL_IN, GRAPH_BOX_ASPECT)
        if follow is None
        else (TARGET_PANEL_IN, TARGET_BOX_ASPECT)
    )
    panel_height_in = (width_in - 0.75) * aspect + TITLE_IN
    figure.set_size_inches(width_in * n_columns, panel_height_in * n_rows)
    legend_rows = add_legend(figure, list(predictions or {}), followed=follow is not None)
    band_in = SYNTHETIC_BAND_IN if synthetic else 0.0
    title_in = 0.3 if title else 0.0
    figure.set_size_inches(
        width_in * n_columns,
        panel_height_in * n_rows + 0.2 * legend_rows + 0.2 + band_in + title_in,
    )
    if title:
        figure.suptitle(title)
    if synthetic:
        mark_synthetic(figure)
    return figure, scenes


def write_scenes(
    path: Path,
    batch: GraphBatch,
    titles: Sequence[str],
    d_sense_m: float,
    predictions: Mapping[str, np.ndarray] | None = None,
    columns: int = 2,
    overwrite: bool = True,
    synthetic: bool = False,
    follow: Sequence[int] | None = None,
) -> tuple[DrawnScene, ...]:
    """`scene_figure` written as one PNG to `path`; returns what each panel drew.

    The PNG is written to a hidden name in the same folder and renamed, so `path` is never a
    half-written file; without `overwrite`, an existing `path` is left as it is (an error).
    """
    if not overwrite and path.exists():
        raise NgsimOutputError(path, "exists; not replaced")
    figure, scenes = scene_figure(batch, titles, d_sense_m, predictions, columns, synthetic, follow)
    _save(figure, path, overwrite)
    return scenes


def _save(figure: Figure, path: Path, overwrite: bool) -> None:
    """Write the PNG beside `path` under a hidden name, then move it there."""
    FigureCanvasAgg(figure)
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        figure.savefig(partial, dpi=DPI, format="png")
        if overwrite:
            os.replace(partial, path)
        else:
            os.link(partial, path)  # fails if `path` appeared meanwhile: never replaced
    except FileExistsError:
        raise NgsimOutputError(path, "exists; not replaced") from None
    except OSError as err:
        raise NgsimOutputError(path, f"cannot write: {err.strerror or err}") from None
    finally:
        partial.unlink(missing_ok=True)


def scene_titles(samples: pl.DataFrame, split: str, sample_ids: Sequence[int]) -> list[str]:
    """A title per sample id, from its split's samples table: recording, ego vehicle, split and
    sample id (draw_scene adds the counts)."""
    rows = samples.filter(pl.col(s.SAMPLE_ID).is_in(list(map(int, sample_ids))))
    by_id = {row[s.SAMPLE_ID]: row for row in rows.iter_rows(named=True)}
    return [
        f"{row[s.LOCATION]} {row[s.PERIOD]}, ego vehicle {row[s.EGO_VEHICLE_ID]}, {split} #{sample}"
        for sample in map(int, sample_ids)
        for row in [by_id[sample]]
    ]


def one_per_ego(samples: pl.DataFrame, start: int, count: int) -> list[int]:
    """Up to `count` sample ids from `start` on, in order, each the first of its ego (recording
    and ego track) among them: consecutive samples are often windows of one ego, drawn alike."""
    rows = samples.filter(pl.col(s.SAMPLE_ID) >= start).sort(s.SAMPLE_ID)
    firsts = rows.unique([s.LOCATION, s.PERIOD, s.EGO_TRACK_ID], keep="first", maintain_order=True)
    return firsts[s.SAMPLE_ID].head(count).to_list()


def vehicle_ids(tracks: pl.LazyFrame, track_ids: Sequence[int]) -> dict[int, int]:
    """track id -> its vehicle's id in the source (NGSIM's Vehicle_ID, highD's id), from a
    build's tracks tables (OpenBuild.tracks)."""
    wanted = [int(track) for track in track_ids]
    rows = (
        tracks.filter(pl.col(s.TRACK_ID).is_in(wanted))
        .select(s.TRACK_ID, s.VEHICLE_ID)
        .unique()
        .collect()
    )
    return dict(rows.iter_rows())
