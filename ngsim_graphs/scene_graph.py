"""The graph view of a scene (`ngsim-graphs show` without a run): a sample's whole graph in the
road frame of ngsim_graphs.scene_frame, in equal metres on both axes so that the d_sense
circle is a circle. What is drawn:
- every history node, older steps fainter; the ego's in red, a star at (0, 0), the neighbours'
  dark grey;
- the spatial edges of the present step, ego-neighbour and neighbour-neighbour told apart, each
  undirected pair drawn once (the counts returned are of directed edges, as the graph holds
  them);
- the temporal edges, which draw each vehicle's history as a line through its nodes;
- the targets' recorded futures (the truth, in palette.TRUTH, thin; masked steps left out), a
  ring at each target's present position;
- the d_sense circle around the ego at the present step, lightly filled.
The panel spans its data and a margin, widened across the road (or along it) to the panel's
shape GRAPH_BOX_ASPECT, so that a metre is as long on both axes.
"""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.palette import TRUTH
from ngsim_graphs.scene_frame import SampleParts, node_xy, paths, plotted

EGO_COLOUR, NEIGHBOUR_COLOUR = "tab:red", "0.3"
EGO_EDGE_COLOUR, NEIGHBOUR_EDGE_COLOUR = "lightcoral", "tab:purple"
SENSE_COLOUR = "0.55"
SENSE_STYLE = {"linestyle": (0, (6, 3)), "linewidth": 0.9}
GRAPH_BOX_ASPECT = 0.3  # the axes' height / width: a road is long and narrow
MARGIN_M = 5.0  # around the drawn things, inside the axes


def _rgba(colour: str) -> np.ndarray:
    return np.array(to_rgba(colour))


def _draw_nodes(axes: Axes, batch: GraphBatch, parts: SampleParts) -> None:
    """Nodes as dots, fainter the older their step; the present ones larger. Drawn above the
    futures and edges, so that the graph is never hidden."""
    steps = batch.node_step[parts.nodes].astype(np.float64)
    oldest = steps.min()
    alpha = 0.15 + 0.85 * (steps - oldest) / max(parts.present - oldest, 1.0)
    is_ego = batch.node_is_ego[parts.nodes]
    colours = np.where(is_ego[:, None], _rgba(EGO_COLOUR), _rgba(NEIGHBOUR_COLOUR))
    colours[:, 3] = alpha
    sizes = np.where(steps == parts.present, 22.0, 7.0)
    xy = node_xy(batch, parts.nodes)
    axes.scatter(xy[:, 0], xy[:, 1], s=sizes, c=colours, linewidths=0, zorder=4)
    axes.scatter([0.0], [0.0], marker="*", s=160, c=EGO_COLOUR, edgecolors="k", zorder=6)


def _draw_edges(axes: Axes, batch: GraphBatch, parts: SampleParts) -> None:
    """The present step's spatial edges, one line per undirected pair, and the temporal
    edges."""
    source, destination = parts.spatial
    is_ego = batch.node_is_ego[source] | batch.node_is_ego[destination]
    for kind, colour, style in (
        (is_ego, EGO_EDGE_COLOUR, "-"),
        (~is_ego, NEIGHBOUR_EDGE_COLOUR, ":"),
    ):
        pairs = np.unique(np.sort(parts.spatial[:, kind], axis=0), axis=1)
        segments = np.stack([node_xy(batch, pairs[0]), node_xy(batch, pairs[1])], axis=1)
        axes.add_collection(
            LineCollection(segments, colors=colour, linestyles=style, linewidths=0.9, zorder=2)
        )
    ego_track = batch.node_is_ego[parts.temporal[0]]
    segments = np.stack(
        [node_xy(batch, parts.temporal[0]), node_xy(batch, parts.temporal[1])], axis=1
    )
    colours = np.where(ego_track[:, None], _rgba(EGO_COLOUR), _rgba(NEIGHBOUR_COLOUR))
    colours[:, 3] = np.where(ego_track, 0.9, 0.45)
    widths = np.where(ego_track, 2.0, 1.0)  # the ego's history stands out
    axes.add_collection(LineCollection(segments, colors=colours, linewidths=widths, zorder=3.5))


def _draw_futures(axes: Axes, batch: GraphBatch, parts: SampleParts) -> np.ndarray:
    """The targets' recorded futures, thin, and a ring at each one's present position; returns
    every position drawn (m, 2)."""
    start = node_xy(batch, batch.target_node[parts.targets])
    future = plotted(batch.target_xy[parts.targets])
    truth = paths(start, future, batch.target_mask[parts.targets])
    for line in truth:
        axes.plot(line[:, 0], line[:, 1], color=TRUTH, linewidth=1.0, alpha=0.55, zorder=3)
    axes.scatter(
        start[:, 0],
        start[:, 1],
        s=36,
        facecolors="none",
        edgecolors=TRUTH,
        linewidths=0.8,
        zorder=5,
    )
    return np.concatenate([start, truth.reshape(-1, 2)])


def equal_limits(axes: Axes, drawn: np.ndarray, box_aspect: float = GRAPH_BOX_ASPECT) -> None:
    """Limits around everything drawn (plotted positions, and the ego at (0, 0)) and MARGIN_M,
    the shorter side widened about its middle so that the axes of shape `box_aspect` (height /
    width) hold a metre as long on both."""
    finite = drawn[np.isfinite(drawn).all(axis=1)]
    low = np.minimum(finite.min(axis=0, initial=0.0), 0.0) - MARGIN_M
    high = np.maximum(finite.max(axis=0, initial=0.0), 0.0) + MARGIN_M
    span = high - low
    wanted = np.array([max(span[0], span[1] / box_aspect), max(span[1], span[0] * box_aspect)])
    middle = (low + high) / 2
    axes.set_xlim(middle[0] - wanted[0] / 2, middle[0] + wanted[0] / 2)
    axes.set_ylim(middle[1] - wanted[1] / 2, middle[1] + wanted[1] / 2)
    axes.set_box_aspect(box_aspect)
    axes.set_aspect("equal", adjustable="datalim")


def draw_graph(axes: Axes, batch: GraphBatch, parts: SampleParts, d_sense_m: float) -> None:
    """Draw the sample's graph into `axes` (see the module's docstring)."""
    _draw_nodes(axes, batch, parts)
    _draw_edges(axes, batch, parts)
    axes.add_patch(
        Circle(
            (0.0, 0.0),
            d_sense_m,
            facecolor=(*to_rgba(SENSE_COLOUR)[:3], 0.08),
            edgecolor=SENSE_COLOUR,
            zorder=1,
            **SENSE_STYLE,
        )
    )
    drawn = _draw_futures(axes, batch, parts)
    equal_limits(axes, np.concatenate([node_xy(batch, parts.nodes), drawn]))


def graph_handles() -> list[Line2D]:
    """Proxy artists for the legend: what each mark of a graph panel means."""

    def dot(colour: str, label: str, **style: object) -> Line2D:
        return Line2D([], [], linestyle="none", marker="o", color=colour, label=label, **style)

    return [
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
        dot(NEIGHBOUR_COLOUR, "neighbour node (fainter: older)", markersize=4),
        Line2D([], [], color=EGO_COLOUR, linewidth=2.0, alpha=0.9, label="ego's history"),
        Line2D([], [], color=NEIGHBOUR_COLOUR, alpha=0.45, label="neighbours' history"),
        Line2D([], [], color=EGO_EDGE_COLOUR, label="spatial edge ego-neighbour (present)"),
        Line2D([], [], color=NEIGHBOUR_EDGE_COLOUR, linestyle=":", label="spatial edge neighbours"),
        Line2D([], [], color=SENSE_COLOUR, label="d_sense around the ego", **SENSE_STYLE),
        dot("none", "target at present", markeredgecolor=TRUTH, markersize=6),
        Line2D([], [], color=TRUTH, alpha=0.55, label="truth: recorded future"),
    ]
