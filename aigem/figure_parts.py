"""The pieces every figure of aigem shares (aigem.runs.curves, aigem.figures.plots, aigem.paper.report_plots): a
figure with a footer, a legend below the axes that hides neither data nor footer, and a figure's
PNG bytes (the published rows' markers: aigem.figures.published).

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot` (as
ngsim_graphs.plotting): no global state, no display, nothing kept open.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence

from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

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
