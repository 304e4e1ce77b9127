"""PNG histograms of a build's statistics: one figure per quantity, written with matplotlib's Agg.

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot`: no global
state, no display needed, nothing kept open after a file is written. A figure of a build of
synthetic data says so at its top left (`mark_synthetic`, used by every picture of a build).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

from ngsim_graphs.edges import SPATIAL
from ngsim_graphs.plot_folder import claim_plot_folder, land_plots
from ngsim_graphs.schema import N_NODES
from ngsim_graphs.statistics import SPLITS, BuildValues

SPLIT_COLOURS = {"train": "tab:blue", "val": "tab:orange", "test": "tab:green"}
PLOT_NAMES = ("nodes_per_graph", "spatial_edges_per_graph", "node_degree", "speed", "heading")
WRITER = "ngsim-graphs stats --plots"  # whose pictures they are (plot_folder)
SYNTHETIC_COLOUR = "crimson"
# What a picture of a build of synthetic data says at its top left, on a line of its own.
SYNTHETIC_PICTURE_LABEL = "SYNTHETIC data (ngsim-graphs synth)"
SYNTHETIC_BAND_IN = 0.25  # the strip taken from the top of a figure for the label


def mark_synthetic(figure: Figure) -> None:
    """Write SYNTHETIC_PICTURE_LABEL at the top left of `figure`, bold and red, on a line of its
    own, so that it covers nothing whatever the title's width: above the suptitle, which gets an
    empty first line for it, or, without one, in a strip of SYNTHETIC_BAND_IN taken from the top
    of its layout (a constrained layout's rect, or fixed margins). Call it once the figure has
    its final size and suptitle."""
    height_in = figure.get_figheight()
    if figure.get_suptitle():
        _lower_suptitle(figure)
    else:
        share = SYNTHETIC_BAND_IN / height_in
        engine = figure.get_layout_engine()
        if isinstance(engine, ConstrainedLayoutEngine):
            left, bottom, width, height = engine.get()["rect"]
            engine.set(rect=(left, bottom, width, min(height, 1 - share - bottom)))
        else:
            figure.subplots_adjust(top=figure.subplotpars.top - share)
    figure.text(
        0.01,
        1 - 0.06 / height_in,
        SYNTHETIC_PICTURE_LABEL,
        ha="left",
        va="top",
        fontsize=10,
        fontweight="bold",
        color=SYNTHETIC_COLOUR,
    )


def _lower_suptitle(figure: Figure) -> None:
    """An empty first line for the suptitle (a constrained layout keeps placing it at the top and
    makes room for the whole of it); its colour, weight and size as they were."""
    title = figure.get_suptitle()
    text = [t for t in figure.texts if t.get_text() == title][-1]
    figure.suptitle(
        f"\n{title}",
        color=text.get_color(),
        fontweight=text.get_fontweight(),
        fontsize=text.get_fontsize(),
    )


def _integer_bins(values: list[np.ndarray], max_bins: int = 60) -> np.ndarray:
    """Bin edges for integer counts: one bin per value when few, else about `max_bins` wide bins."""
    present = [v for v in values if len(v)]
    if not present:
        return np.arange(0, 2) - 0.5
    low, high = min(int(v.min()) for v in present), max(int(v.max()) for v in present)
    width = max(1, int(np.ceil((high - low + 1) / max_bins)))
    return np.arange(low, high + width + 1, width) - 0.5


def share_figure(per_split: dict[str, np.ndarray], title: str, xlabel: str, unit: str) -> Figure:
    """One quantity per split as the share of its items (`unit`: "graphs", "nodes") in each bin:
    step lines on the same bins, each split's summing to 1, not stacked, so that the small splits
    show beside train; n per split in the legend. A split without values is named in the legend,
    nothing drawn."""
    data = {split: np.asarray(per_split[split]) for split in SPLITS if split in per_split}
    bins = _integer_bins(list(data.values()), max_bins=40)
    figure, axes = _figure(top=0.86 if "\n" in title else 0.92)
    for split, values in data.items():
        label = f"{split} (n={len(values):,} {unit})"
        if len(values):
            shares = np.histogram(values, bins=bins)[0] / len(values)
            axes.stairs(shares, bins, color=SPLIT_COLOURS[split], linewidth=1.6, label=label)
        else:
            axes.plot([], [], color=SPLIT_COLOURS[split], label=f"{label}: none drawn")
    width = int(round(bins[1] - bins[0]))
    per = "" if width == 1 else f" per bin ({width} wide)"
    axes.set(title=title, xlabel=xlabel, ylabel=f"share of {unit}{per}")
    axes.legend(title="split")
    return figure


def degree_title(degree_graphs: dict[str, int]) -> str:
    """The node-degree plot's title: how many graphs of each split its degrees come from."""
    sampled = ", ".join(f"{split} {degree_graphs[split]:,}" for split in SPLITS)
    return f"Spatial in-degree per node, share per split\n(graphs sampled per split: {sampled})"


def _histogram(
    values: np.ndarray,
    title: str,
    xlabel: str,
    ylabel: str,
    log_y: bool = False,
) -> Figure:
    figure, axes = _figure()
    axes.hist(values, bins=80, histtype="stepfilled", color="tab:blue")
    if log_y:
        axes.set_yscale("log")
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    return figure


def _figure(top: float = 0.92) -> tuple[Figure, Axes]:
    # Fixed margins: a layout engine would cost more than drawing the figure.
    figure = Figure(figsize=(7, 4.5))
    figure.subplots_adjust(left=0.12, right=0.97, bottom=0.12, top=top)
    return figure, figure.add_subplot()


def png_bytes(figure: Figure, dpi: int = 110) -> bytes:
    """`figure` as a PNG file's bytes (drawn on an Agg canvas)."""
    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def write_histograms(values: BuildValues, folder: Path, synthetic: bool = False) -> list[Path]:
    """Write PLOT_NAMES as `<name>.png` into `folder` (created), each marked as synthetic data
    where `synthetic` (mark_synthetic); returns the paths written. A file of those names that
    is not ours is refused before anything is written (plot_folder: plots.json lists ours)."""
    owned = claim_plot_folder(folder, [f"{name}.png" for name in PLOT_NAMES], WRITER)
    figures = _figures(values)
    if synthetic:
        for figure in figures.values():
            mark_synthetic(figure)
    pictures = {f"{name}.png": png_bytes(figure) for name, figure in figures.items()}
    return land_plots(folder, pictures, owned, WRITER)


def _figures(values: BuildValues) -> dict[str, Figure]:
    """The figure of each of PLOT_NAMES."""
    nodes = {split: values.samples[split][N_NODES].to_numpy() for split in SPLITS}
    edges = {  # none where the build has no spatial edges
        split: values.samples[split]
        .get_column(SPATIAL.count_column, default=pl.Series([], dtype=pl.Int32))
        .to_numpy()
        for split in SPLITS
    }
    rows = f"{len(values.speed_mps):,} tracks rows"
    return {
        "nodes_per_graph": share_figure(
            nodes,
            "Nodes per graph (all history steps), share per split",
            "nodes per graph",
            "graphs",
        ),
        "spatial_edges_per_graph": share_figure(
            edges,
            "Spatial edges per graph (directed, all history steps), share per split",
            "spatial edges per graph",
            "graphs",
        ),
        "node_degree": share_figure(
            values.spatial_in_degree,
            degree_title(values.degree_graphs),
            "spatial in-degree (edges into a node at its step)",
            "nodes",
        ),
        "speed": _histogram(values.speed_mps, f"Speed ({rows})", "speed (m/s)", "tracks rows"),
        "heading": _histogram(
            values.heading_rad,
            f"Heading ({rows}, log scale)",
            "heading (rad, from +y towards +x)",
            "tracks rows",
            log_y=True,
        ),
    }
