"""Pictures of samples' graphs in the road frame: nodes, edges, targets' futures, predictions.

One panel per sample, drawn from a `GraphBatch` (metres, the sample frame, the ego at (0, 0) at the
present step). A road is long and narrow, so the panel lies along it: y longitudinal on the
horizontal axis (travel to the right), x lateral on the vertical axis, growing downwards (to the
driver's right, as seen from above). Each axis spans the panel's own data (nodes, futures,
predictions) and a margin, not the d_sense circle: the lateral axis is stretched (about 4 times
the longitudinal at a typical scene) so that lanes stand apart. What is drawn:
- every history node, older steps fainter; the ego's nodes in their own colour, a star at (0, 0);
- the spatial edges of the present step, ego-actor and actor-actor told apart, each undirected
  pair drawn once (the counts returned are of directed edges, as the graph holds them);
- the temporal edges, which draw each vehicle's history as a line through its nodes;
- the targets' recorded futures (truth: solid, masked steps left out), and optional predictions,
  each its own colour, dash pattern and marker at its last step;
- the d_sense circle around the ego at the present step (an ellipse where the axes' scales
  differ, cut where it leaves the data);
- for a build of synthetic data, a red label at the top (plotting.mark_synthetic).

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
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.plotting import SYNTHETIC_BAND_IN, mark_synthetic

EGO_COLOUR, ACTOR_COLOUR = "tab:red", "tab:blue"
EGO_EDGE_COLOUR, ACTOR_EDGE_COLOUR = "tab:orange", "tab:purple"
FUTURE_COLOUR, SENSE_COLOUR = "tab:green", "0.55"
SENSE_STYLE = {"linestyle": (0, (6, 3)), "linewidth": 0.9, "zorder": 1}
PREDICTION_STYLES = (  # (colour, dashes, marker at the last step) of the 1st, 2nd, ... labels
    ("black", (4, 2), "X"),
    ("magenta", (1.5, 1.5), "^"),
    ("tab:brown", (6, 2, 1, 2), "s"),
    ("tab:cyan", (3, 3), "D"),
)
PANEL_WIDTH_IN = 4.0
PANEL_BOX_ASPECT = 0.55  # the axes' height / width: a road is long and narrow
TITLE_IN = 1.25  # a panel's title (up to four lines: evaluate's scenes) and axis labels
LEGEND_COLUMN_IN = 2.6  # the width of a legend column, its longest label at 8 points
MARGIN_M = 5.0  # along the road, around the drawn things, inside the axes
LATERAL_MARGIN_M = 1.5  # across it
MIN_LATERAL_SPAN_M = 12.0  # about three lanes: a lone vehicle is not magnified without end
DPI = 120
MAX_PANELS = 64  # a picture of more would be too large to read


@dataclass(frozen=True)
class DrawnScene:
    """What one panel drew, counted from the sample.

    nodes: the sample's nodes (every history step); spatial_edges: its directed spatial edges at
    the present step (drawn as undirected pairs), = ego_edges (ego<->actor, both directions) +
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


@dataclass(frozen=True)
class _Sample:
    """One sample of a batch, with batch-global node indices."""

    nodes: np.ndarray  # (n,) its nodes
    present: int  # its present step (K_H-1: the ego is a node at every step)
    spatial: np.ndarray  # (2, e) its directed spatial edges at the present step
    temporal: np.ndarray  # (2, t) its temporal edges
    targets: np.ndarray  # (a,) its targets' indices into target_node


def _sample(batch: GraphBatch, sample: int) -> _Sample:
    if not 0 <= sample < batch.n_samples:
        raise ValueError(f"sample {sample} is not in a batch of {batch.n_samples}")
    first, last = int(batch.node_ptr[sample]), int(batch.node_ptr[sample + 1])
    present = int(batch.node_step[first:last].max())
    none = np.zeros((2, 0), np.int64)  # a build without the type: none drawn
    spatial, temporal = (
        batch.edges[name].index if name in batch.edges else none for name in ("spatial", "temporal")
    )
    source = spatial[0]
    mine = (source >= first) & (source < last)
    spatial = spatial[:, mine & (batch.node_step[source] == present)]
    temporal = temporal[:, (temporal[0] >= first) & (temporal[0] < last)]
    targets = np.flatnonzero(batch.node_sample[batch.target_node] == sample)
    return _Sample(np.arange(first, last), present, spatial, temporal, targets)


def _xy(batch: GraphBatch, nodes: np.ndarray) -> np.ndarray:
    """(n, 2) the nodes' positions as plotted: (y longitudinal, x lateral)."""
    return _plotted(batch.node_features[nodes, :2])


def _plotted(xy: np.ndarray) -> np.ndarray:
    """Positions (..., 2) of the sample frame, (x, y), as plotted: (y, x), along the road first."""
    return np.asarray(xy, dtype=np.float64)[..., ::-1]


def _draw_nodes(axes: Axes, batch: GraphBatch, sample: _Sample) -> None:
    """Nodes as dots, fainter the older their step; the present ones larger. Drawn above the
    futures and edges, so that the graph is never hidden."""
    steps = batch.node_step[sample.nodes].astype(np.float64)
    oldest = steps.min()
    alpha = 0.15 + 0.85 * (steps - oldest) / max(sample.present - oldest, 1.0)
    is_ego = batch.node_is_ego[sample.nodes]
    colours = np.where(is_ego[:, None], _rgba(EGO_COLOUR), _rgba(ACTOR_COLOUR))
    colours[:, 3] = alpha
    sizes = np.where(steps == sample.present, 22.0, 7.0)
    xy = _xy(batch, sample.nodes)
    axes.scatter(xy[:, 0], xy[:, 1], s=sizes, c=colours, linewidths=0, zorder=4)
    axes.scatter([0.0], [0.0], marker="*", s=160, c=EGO_COLOUR, edgecolors="k", zorder=6)


def _rgba(colour: str) -> np.ndarray:
    return np.array(to_rgba(colour))


def _draw_edges(axes: Axes, batch: GraphBatch, sample: _Sample) -> tuple[int, int]:
    """The present step's spatial edges, one line per undirected pair, and the temporal edges;
    returns the directed (ego, actor-actor) spatial edge counts."""
    source, destination = sample.spatial
    is_ego = batch.node_is_ego[source] | batch.node_is_ego[destination]
    for kind, colour, style, width in (
        (is_ego, EGO_EDGE_COLOUR, "-", 0.9),
        (~is_ego, ACTOR_EDGE_COLOUR, ":", 0.9),
    ):
        pairs = np.unique(np.sort(sample.spatial[:, kind], axis=0), axis=1)
        segments = np.stack([_xy(batch, pairs[0]), _xy(batch, pairs[1])], axis=1)
        axes.add_collection(
            LineCollection(segments, colors=colour, linestyles=style, linewidths=width, zorder=2)
        )
    ego_track = batch.node_is_ego[sample.temporal[0]]
    segments = np.stack([_xy(batch, sample.temporal[0]), _xy(batch, sample.temporal[1])], axis=1)
    colours = np.where(ego_track[:, None], _rgba(EGO_COLOUR), _rgba(ACTOR_COLOUR))
    colours[:, 3] = np.where(ego_track, 0.9, 0.45)
    widths = np.where(ego_track, 2.0, 1.0)  # the ego's history stands out
    axes.add_collection(LineCollection(segments, colors=colours, linewidths=widths, zorder=3.5))
    return int(is_ego.sum()), int((~is_ego).sum())


def _paths(start: np.ndarray, future: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(a, 1+K, 2) lines from each present position through its future positions; NaN at masked
    steps, so that a line breaks where the vehicle is not recorded."""
    future = np.where(mask[..., None], future, np.nan) if mask is not None else future
    return np.concatenate([start[:, None, :], future], axis=1)


def _draw_futures(
    axes: Axes,
    batch: GraphBatch,
    sample: _Sample,
    predictions: Mapping[str, np.ndarray],
) -> tuple[np.ndarray, dict[str, int]]:
    """The targets' recorded futures and the predictions; returns every position drawn (m, 2)."""
    start = _xy(batch, batch.target_node[sample.targets])
    future = _plotted(batch.target_xy[sample.targets])
    truth = _paths(start, future, batch.target_mask[sample.targets])
    drawn = [start, truth.reshape(-1, 2)]
    for line in truth:
        axes.plot(line[:, 0], line[:, 1], color=FUTURE_COLOUR, linewidth=1.8, zorder=3)
    axes.scatter(
        start[:, 0],
        start[:, 1],
        s=36,
        facecolors="none",
        edgecolors=FUTURE_COLOUR,
        linewidths=1.0,
        zorder=5,
    )
    predicted = {}
    for (label, values), (colour, dashes, marker) in zip(
        predictions.items(), _styles(predictions), strict=True
    ):
        lines = _paths(start, _plotted(np.asarray(values)[sample.targets]), None)
        for line in lines:
            axes.plot(
                line[:, 0],
                line[:, 1],
                color=colour,
                dashes=dashes,
                linewidth=1.2,
                marker=marker,
                markevery=[len(line) - 1],
                markersize=5,
                zorder=5,
            )
        drawn.append(lines.reshape(-1, 2))
        predicted[label] = len(lines)
    return np.concatenate(drawn), predicted


def _styles(predictions: Mapping[str, np.ndarray]) -> list[tuple[str, tuple[float, ...], str]]:
    return [PREDICTION_STYLES[i % len(PREDICTION_STYLES)] for i in range(len(predictions))]


def _check_predictions(batch: GraphBatch, predictions: Mapping[str, np.ndarray]) -> None:
    targets, future_steps = batch.target_xy.shape[:2]
    for label, values in predictions.items():
        shape = np.shape(values)
        if len(shape) != 3 or shape[0] != targets or shape[2] != 2 or shape[1] > future_steps:
            raise ValueError(
                f"predictions {label!r}: shape {shape}, expected ({targets}, K <= {future_steps}, 2)"
            )


def _limits(axes: Axes, drawn: np.ndarray) -> None:
    """Axis limits around everything drawn (plotted (along, across) positions, and the ego at
    (0, 0)) and a margin: MARGIN_M along the road, LATERAL_MARGIN_M across it, at least
    MIN_LATERAL_SPAN_M across; the lateral axis grows downwards."""
    finite = drawn[np.isfinite(drawn).all(axis=1)]
    low = np.minimum(finite.min(axis=0, initial=0.0), 0.0)
    high = np.maximum(finite.max(axis=0, initial=0.0), 0.0)
    widen = max(0.0, MIN_LATERAL_SPAN_M - 2 * LATERAL_MARGIN_M - (high[1] - low[1])) / 2
    axes.set_xlim(low[0] - MARGIN_M, high[0] + MARGIN_M)
    axes.set_ylim(high[1] + LATERAL_MARGIN_M + widen, low[1] - LATERAL_MARGIN_M - widen)
    axes.set_box_aspect(PANEL_BOX_ASPECT)


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}" if count == 1 else f"{count} {noun}s"


def _decorate(axes: Axes, title: str, scene: DrawnScene) -> None:
    """The title (`title`, then the counts), axis labels and a light grid."""
    counts = (
        f"{_plural(scene.nodes, 'node')}, {_plural(scene.temporal_edges, 'temporal edge')},\n"
        f"{_plural(scene.spatial_edges, 'spatial edge')} at present, "
        f"{_plural(scene.targets, 'target')}"
    )
    axes.set_title(f"{title}\n{counts}", fontsize=8)
    axes.set_xlabel("y longitudinal (m), travel to the right", fontsize=7)
    axes.set_ylabel("x lateral (m), stretched", fontsize=7)
    axes.tick_params(labelsize=7)
    axes.grid(alpha=0.25, linewidth=0.5)


def draw_scene(
    axes: Axes,
    batch: GraphBatch,
    sample: int,
    d_sense_m: float,
    title: str,
    predictions: Mapping[str, np.ndarray] | None = None,
) -> DrawnScene:
    """Draw sample `sample` of `batch` into `axes` (see the module's docstring) and return what
    was drawn, counted from the sample. `predictions`: label -> (T, K, 2) positions in metres,
    aligned with the batch's T targets (K <= K_F), drawn dashed, one style per label. The title
    is `title`, then the sample's counts. No legend: see `add_legend`."""
    predictions = dict(predictions or {})
    _check_predictions(batch, predictions)
    picked = _sample(batch, sample)
    _draw_nodes(axes, batch, picked)
    ego_edges, actor_edges = _draw_edges(axes, batch, picked)
    axes.add_patch(Circle((0.0, 0.0), d_sense_m, fill=False, color=SENSE_COLOUR, **SENSE_STYLE))
    drawn, predicted = _draw_futures(axes, batch, picked, predictions)
    _limits(axes, np.concatenate([_xy(batch, picked.nodes), drawn]))
    scene = DrawnScene(
        nodes=len(picked.nodes),
        spatial_edges=ego_edges + actor_edges,
        ego_edges=ego_edges,
        actor_edges=actor_edges,
        temporal_edges=picked.temporal.shape[1],
        targets=len(picked.targets),
        predicted=predicted,
    )
    _decorate(axes, title, scene)
    return scene


def _legend_handles(labels: Sequence[str]) -> list[Line2D]:
    """Proxy artists for the legend: what each mark of a panel means."""

    def dot(colour: str, label: str, **style: object) -> Line2D:
        return Line2D([], [], linestyle="none", marker="o", color=colour, label=label, **style)

    handles = [
        Line2D(
            [],
            [],
            linestyle="none",
            marker="*",
            markersize=11,
            color=EGO_COLOUR,
            markeredgecolor="k",
            label="ego at present (0, 0)",
        ),
        dot(EGO_COLOUR, "ego node (fainter: older)", markersize=4),
        dot(ACTOR_COLOUR, "neighbour node (fainter: older)", markersize=4),
        Line2D([], [], color=EGO_COLOUR, linewidth=2.0, alpha=0.9, label="ego's history"),
        Line2D([], [], color=ACTOR_COLOUR, alpha=0.45, label="neighbours' history"),
        Line2D([], [], color=EGO_EDGE_COLOUR, label="spatial edge ego-neighbour (present)"),
        Line2D([], [], color=ACTOR_EDGE_COLOUR, linestyle=":", label="spatial edge neighbours"),
        Line2D([], [], color=SENSE_COLOUR, label="d_sense around ego", **SENSE_STYLE),
        dot("none", "target at present", markeredgecolor=FUTURE_COLOUR, markersize=6),
        Line2D([], [], color=FUTURE_COLOUR, linewidth=1.8, label="truth: recorded future"),
    ]
    styles = _styles(dict.fromkeys(labels))
    for label, (colour, dashes, marker) in zip(labels, styles, strict=True):
        handles.append(
            Line2D(
                [0.0, 1.0],
                [0.0, 0.0],
                color=colour,
                dashes=dashes,
                marker=marker,
                markevery=[1],
                markersize=5,
                label=f"predicted: {label}",
            )
        )
    return handles


def add_legend(figure: Figure, labels: Sequence[str] = ()) -> int:
    """One legend for every panel of `figure`, below them (it hides no scene), in as many
    columns as the figure's width holds; `labels`: the predictions' labels, in the order given
    to `draw_scene`. Returns the legend's rows."""
    handles = _legend_handles(labels)
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
    columns: int = 4,
    synthetic: bool = False,
) -> tuple[Figure, tuple[DrawnScene, ...]]:
    """Every sample of `batch` drawn in one figure, a panel each in rows of `columns`, titled
    `titles[b]`, marked as synthetic data where `synthetic` (plotting.mark_synthetic); and what
    each panel drew (see `DrawnScene`)."""
    if len(titles) != batch.n_samples:
        raise ValueError(f"{len(titles)} titles for {batch.n_samples} samples")
    if not 1 <= batch.n_samples <= MAX_PANELS:
        raise ValueError(f"{batch.n_samples} samples: draw 1 to {MAX_PANELS} at once")
    n_columns = min(columns, batch.n_samples)
    n_rows = math.ceil(batch.n_samples / n_columns)
    figure = Figure(layout=ConstrainedLayoutEngine(h_pad=0.1, w_pad=0.08))
    grid = figure.subplots(n_rows, n_columns, squeeze=False)
    scenes = tuple(
        draw_scene(axes, batch, b, d_sense_m, titles[b], predictions)
        for b, axes in enumerate(grid.flat[: batch.n_samples])
    )
    for axes in grid.flat[batch.n_samples :]:
        axes.remove()
    panel_height_in = (PANEL_WIDTH_IN - 0.75) * PANEL_BOX_ASPECT + TITLE_IN
    figure.set_size_inches(PANEL_WIDTH_IN * n_columns, panel_height_in * n_rows)
    legend_rows = add_legend(figure, list(predictions or {}))
    band_in = SYNTHETIC_BAND_IN if synthetic else 0.0
    figure.set_size_inches(
        PANEL_WIDTH_IN * n_columns, panel_height_in * n_rows + 0.2 * legend_rows + 0.2 + band_in
    )
    if synthetic:
        mark_synthetic(figure)
    return figure, scenes


def write_scenes(
    path: Path,
    batch: GraphBatch,
    titles: Sequence[str],
    d_sense_m: float,
    predictions: Mapping[str, np.ndarray] | None = None,
    columns: int = 4,
    overwrite: bool = True,
    synthetic: bool = False,
) -> tuple[DrawnScene, ...]:
    """`scene_figure` written as one PNG to `path`; returns what each panel drew.

    The PNG is written to a hidden name in the same folder and renamed, so `path` is never a
    half-written file; without `overwrite`, an existing `path` is left as it is (an error).
    """
    if not overwrite and path.exists():
        raise NgsimOutputError(path, "exists; not replaced")
    figure, scenes = scene_figure(batch, titles, d_sense_m, predictions, columns, synthetic)
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
