"""The pieces every figure of aigem shares (aigem.plots, aigem.report_plots): a figure with a
footer, a legend below the axes that hides neither data nor footer, the published rows as hollow
markers in their models' colours (ngsim_graphs.palette), and a figure's PNG bytes.

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot` (as
ngsim_graphs.plotting): no global state, no display, nothing kept open.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

from aigem.results import PAPER_TABLE, PUBLISHED_CONSTANT_VELOCITY
from ngsim_graphs.palette import MODEL_COLOURS, PUBLISHED

PUBLISHED_MARKERS = {  # each published row's model (results.PAPER_TABLE, then constant velocity)
    "CS-LSTM": "s",
    "GRIP++": "v",
    "STA-LSTM": "P",
    "DeepTrack": "X",
    "GSTCN": "^",
    "AiGem": "o",
    "constant velocity": "o",
}
PUBLISHED_WORDS = "published, NGSIM"  # after a published row's model, in every legend
FOOTER_CHARS_PER_IN = 14  # characters of 8-point text per inch of figure width, with room


def png_bytes(figure: Figure, dpi: int = 110) -> bytes:
    """The figure as a PNG, drawn on an Agg canvas."""
    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def footed_figure(width_in: float, height_in: float, footer: str) -> Figure:
    """A figure of `height_in` over a footer: `footer` in 8-point grey lines wrapped to the
    width, kept clear of the axes (a constrained layout's rect ends above it)."""
    text = textwrap.fill(
        footer,
        width=int(width_in * FOOTER_CHARS_PER_IN),
        break_on_hyphens=False,  # a command's options stay whole
    )
    footer_in = 0.1 + 0.16 * (text.count("\n") + 1)
    total_in = height_in + footer_in
    engine = ConstrainedLayoutEngine(rect=(0, footer_in / total_in, 1, 1 - footer_in / total_in))
    figure = Figure(figsize=(width_in, total_in), layout=engine)
    figure.text(0.01, 0.02 / total_in, text, fontsize=8, color="dimgray", va="bottom")
    return figure


def published_style(name: str) -> tuple[str, str, str]:
    """A published row's model ("AiGem" of "AiGem (paper)"), its colour (ngsim_graphs.palette)
    and its marker, drawn hollow."""
    model = name.split(" (")[0]
    return model, MODEL_COLOURS.get(model, PUBLISHED), PUBLISHED_MARKERS[model]


def paper_points(axes: Axes, key: str, last_s: float = 5.0) -> None:
    """The published rows as hollow markers, up to `last_s` seconds: RMSE at 1..5 s (key
    "rmse_m"), or FDE at 5 s ("fde_m"); a row without the number is left out. Labelled by model
    alone, so that the two panels of error_by_horizon share their legend entries. Also
    aigem.report_plots' RMSE figure."""
    for name, row in {**PAPER_TABLE, **PUBLISHED_CONSTANT_VELOCITY}.items():
        model, colour, marker = published_style(name)
        values = row[key] if key == "rmse_m" else (row[key],)
        times = np.arange(1, 6) if key == "rmse_m" else np.array([5.0])
        shown = [
            (t, v) for t, v in zip(times, values, strict=True) if v is not None and t <= last_s
        ]
        if not shown:
            continue
        axes.plot(
            *zip(*shown, strict=True),
            ls="none",
            marker=marker,
            ms=7,
            mfc="none",
            mec=colour,
            mew=1.5,
            clip_on=False,  # a point on the axis' last second is drawn whole
            label=f"{model} ({PUBLISHED_WORDS})",
        )


def panel_handles(panels: Sequence[Axes]) -> dict[str, Artist]:
    """The panels' legend entries by label, each label once, in the order drawn."""
    handles: dict[str, Artist] = {}
    for axes in panels:
        for handle, label in zip(*axes.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    return handles


def legend_below(
    figure: Figure, handles: dict[str, Artist], columns: int = 3, title: str | None = None
) -> None:
    """A legend of `handles` (label -> artist, panel_handles) below the axes and above a footer
    (the bottom of the figure's constrained-layout rect, which is raised over it): it hides no
    data and no footer line."""
    engine = figure.get_layout_engine()
    left, bottom, width, height = engine.get()["rect"]
    legend = figure.legend(
        handles.values(),
        handles.keys(),
        loc="lower center",
        bbox_to_anchor=(0.5, bottom),
        ncols=columns,
        fontsize=8,
        title=title,
        title_fontsize=8,
        frameon=False,
    )
    box = legend.get_window_extent(FigureCanvasAgg(figure).get_renderer())
    share = (box.height + 0.05 * figure.dpi) / figure.bbox.height  # and a little air above
    engine.set(rect=(left, bottom + share, width, height - share))
