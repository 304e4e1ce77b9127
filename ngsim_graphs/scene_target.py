"""The followed-target view of a scene (`aigem evaluate`'s scenes.png, `ngsim-graphs show
--run`): one target's history, recorded future and predictions, drawn for the eye to follow,
in the road frame of ngsim_graphs.scene_frame. What is drawn:
- the other vehicles faded: their histories and present positions light grey, the ego's light
  red with its star at (0, 0); no edges, no d_sense circle, no other target's future;
- the followed target's history (a dark line through its nodes), a ring at its present
  position, its recorded future (the truth: palette.TRUTH, solid, masked steps left out);
- each prediction of it in its model's colour (palette.MODEL_COLOURS, else PREDICTION_STYLES),
  its own dash pattern and a marker at its last step;
- on the truth and every prediction a dot at each whole second, so that where each is at the
  same time can be compared by eye.
The axes span the target's lines, the ego and a margin. No circle is drawn, so the lateral axis
may be stretched (the lateral error shows); its label says by how much.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.lines import Line2D

from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.palette import MODEL_COLOURS, TRUTH
from ngsim_graphs.scene_frame import (
    ALONG_LABEL,
    LEFT_LABEL,
    SampleParts,
    node_xy,
    paths,
    plotted,
    track_nodes,
)

CONTEXT_COLOUR, EGO_CONTEXT_COLOUR = "0.72", "lightcoral"
HISTORY_COLOUR = "0.25"  # the followed target's history
DASHES = {"AiGem": (5, 2), "constant velocity": (1.5, 1.5)}
MARKERS = {"AiGem": "X", "constant velocity": "^"}
PREDICTION_STYLES = (  # (colour, dashes, marker) of other labels, in turn
    ("tab:brown", (6, 2, 1, 2), "s"),
    ("tab:cyan", (3, 3), "D"),
)
TARGET_BOX_ASPECT = 0.45  # the axes' height / width
MARGIN_M = 5.0  # along the road, around the drawn things
LATERAL_MARGIN_M = 1.5  # across it
MIN_LATERAL_SPAN_M = 12.0  # about three lanes: a lone line is not magnified without end


def prediction_styles(labels: Sequence[str]) -> list[tuple[str, tuple[float, ...], str]]:
    """(colour, dashes, marker) of each prediction label: a model's own, else the next of
    PREDICTION_STYLES."""
    others = iter(PREDICTION_STYLES * len(labels))
    return [
        (MODEL_COLOURS[label], DASHES[label], MARKERS[label])
        if label in MODEL_COLOURS
        else next(others)
        for label in labels
    ]


def _draw_context(axes: Axes, batch: GraphBatch, parts: SampleParts) -> None:
    """Every vehicle's history and present position, faded: the scene around the target."""
    ego_track = batch.node_is_ego[parts.temporal[0]]
    segments = np.stack(
        [node_xy(batch, parts.temporal[0]), node_xy(batch, parts.temporal[1])], axis=1
    )
    colours = np.where(ego_track, EGO_CONTEXT_COLOUR, CONTEXT_COLOUR)
    axes.add_collection(LineCollection(segments, colors=colours, linewidths=1.0, zorder=1))
    present = parts.nodes[batch.node_step[parts.nodes] == parts.present]
    xy = node_xy(batch, present)
    axes.scatter(xy[:, 0], xy[:, 1], s=12, c=CONTEXT_COLOUR, linewidths=0, zorder=1.5)
    axes.scatter(
        [0.0], [0.0], marker="*", s=110, c=EGO_CONTEXT_COLOUR, edgecolors="0.4", zorder=1.6
    )


def _second_marks(steps: int, time_step_s: float) -> list[int]:
    """Indices of a line from the present (index 0) at each whole second of its `steps` steps."""
    per_second = round(1.0 / time_step_s)
    return list(range(per_second, steps + 1, per_second))


def _draw_line(axes: Axes, line: np.ndarray, marks: list[int], **style: object) -> None:
    axes.plot(line[:, 0], line[:, 1], **style)
    shown = [i for i in marks if i < len(line)]
    axes.plot(
        line[shown, 0], line[shown, 1], ls="none", marker="o", ms=3, zorder=6, color=style["color"]
    )


def draw_followed(
    axes: Axes,
    batch: GraphBatch,
    parts: SampleParts,
    target: int,
    predictions: Mapping[str, np.ndarray],
) -> dict[str, int]:
    """Draw the scene around target `target` (an index into the batch's targets, of this
    sample) and its predictions (label -> (T, K, 2) metres, the batch's targets); returns the
    targets drawn per label (1 each)."""
    if target not in parts.targets:
        raise ValueError(f"target {target} is not one of the sample's {parts.targets.tolist()}")
    _draw_context(axes, batch, parts)
    node = int(batch.target_node[target])
    history = node_xy(batch, track_nodes(batch, parts, node))
    axes.plot(history[:, 0], history[:, 1], color=HISTORY_COLOUR, lw=2.2, zorder=4)
    start = node_xy(batch, np.array([node]))  # (1, 2) its present position
    truth = paths(
        start, plotted(batch.target_xy[target : target + 1]), batch.target_mask[target : target + 1]
    )[0]
    marks = _second_marks(batch.target_xy.shape[1], batch.time_step_s)
    _draw_line(axes, truth, marks, color=TRUTH, lw=2.0, zorder=5)
    drawn = [history, truth]
    for values, (colour, dashes, marker) in zip(
        predictions.values(), prediction_styles(list(predictions)), strict=True
    ):
        line = paths(start, plotted(np.asarray(values)[target : target + 1]), None)[0]
        _draw_line(
            axes,
            line,
            marks,
            color=colour,
            dashes=dashes,
            lw=1.8,
            marker=marker,
            markevery=[len(line) - 1],
            ms=7,
            zorder=5.5,
        )
        drawn.append(line)
    axes.scatter(*start.T, s=60, facecolors="white", edgecolors=TRUTH, linewidths=1.5, zorder=7)
    _limits(axes, np.concatenate([*drawn, np.zeros((1, 2))]))
    return dict.fromkeys(predictions, 1)


def _limits(axes: Axes, drawn: np.ndarray) -> None:
    """Limits around `drawn` and a margin (MARGIN_M along, LATERAL_MARGIN_M across, at least
    MIN_LATERAL_SPAN_M across); the labels, the lateral one with its stretch against the
    longitudinal scale."""
    finite = drawn[np.isfinite(drawn).all(axis=1)]
    low, high = finite.min(axis=0), finite.max(axis=0)
    widen = max(0.0, MIN_LATERAL_SPAN_M - 2 * LATERAL_MARGIN_M - (high[1] - low[1])) / 2
    along = (low[0] - MARGIN_M, high[0] + MARGIN_M)
    across = (low[1] - LATERAL_MARGIN_M - widen, high[1] + LATERAL_MARGIN_M + widen)
    axes.set_xlim(*along)
    axes.set_ylim(*across)
    axes.set_box_aspect(TARGET_BOX_ASPECT)
    stretch = TARGET_BOX_ASPECT * (along[1] - along[0]) / (across[1] - across[0])
    axes.set_xlabel(ALONG_LABEL, fontsize=7)
    axes.set_ylabel(f"{LEFT_LABEL},\nstretched ×{stretch:.1f}", fontsize=7)


def target_handles(labels: Sequence[str]) -> list[Line2D]:
    """Proxy artists for the legend: what each mark of a followed-target panel means."""
    handles = [
        Line2D([], [], color=CONTEXT_COLOUR, marker="o", ms=3, label="other vehicles (faded)"),
        Line2D(
            [],
            [],
            color=EGO_CONTEXT_COLOUR,
            marker="*",
            ms=9,
            markeredgecolor="0.4",
            label="ego, at (0, 0) at present",
        ),
        Line2D([], [], color=HISTORY_COLOUR, lw=2.2, label="followed target's history"),
        Line2D(
            [],
            [],
            ls="none",
            marker="o",
            ms=7,
            mfc="white",
            mec=TRUTH,
            mew=1.5,
            label="followed target at present",
        ),
        Line2D([], [], color=TRUTH, lw=2.0, label="truth: its recorded future"),
    ]
    for label, (colour, dashes, marker) in zip(labels, prediction_styles(labels), strict=True):
        handles.append(
            Line2D(
                [0.0, 1.0],
                [0.0, 0.0],
                color=colour,
                dashes=dashes,
                marker=marker,
                markevery=[1],
                ms=6,
                label=f"predicted: {label}",
            )
        )
    handles.append(
        Line2D([], [], ls="none", marker="o", ms=3, color="0.3", label="dots: every whole second")
    )
    return handles
