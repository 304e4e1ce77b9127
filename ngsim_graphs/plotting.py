"""PNG histograms of a build's statistics: one figure per quantity, written with matplotlib's Agg.

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot`: no global
state, no display needed, nothing kept open after a file is written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ngsim_graphs.schema import N_NODES, N_SPATIAL
from ngsim_graphs.statistics import SPLITS, BuildValues

SPLIT_COLOURS = {"train": "tab:blue", "val": "tab:orange", "test": "tab:green"}
PLOT_NAMES = ("nodes_per_graph", "spatial_edges_per_graph", "node_degree", "speed", "heading")


def _integer_bins(values: list[np.ndarray], max_bins: int = 60) -> np.ndarray:
    """Bin edges for integer counts: one bin per value when few, else about `max_bins` wide bins."""
    present = [v for v in values if len(v)]
    if not present:
        return np.arange(0, 2) - 0.5
    low, high = min(int(v.min()) for v in present), max(int(v.max()) for v in present)
    width = max(1, int(np.ceil((high - low + 1) / max_bins)))
    return np.arange(low, high + width + 1, width) - 0.5


def _split_histogram(
    folder: Path, name: str, per_split: dict[str, np.ndarray], title: str, xlabel: str, ylabel: str
) -> Path:
    """Stacked histogram of one quantity, the splits in their colours."""
    splits = [split for split in SPLITS if split in per_split]
    data = [np.asarray(per_split[split]) for split in splits]
    figure, axes = _figure()
    labels = [f"{split} (n={len(values):,})" for split, values in zip(splits, data, strict=True)]
    axes.hist(
        data,
        bins=_integer_bins(data),
        stacked=True,
        histtype="stepfilled",
        label=labels,
        color=[SPLIT_COLOURS[split] for split in splits],
    )
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    axes.legend(title="split")
    return _save(figure, folder / f"{name}.png")


def _histogram(
    folder: Path,
    name: str,
    values: np.ndarray,
    title: str,
    xlabel: str,
    ylabel: str,
    log_y: bool = False,
) -> Path:
    figure, axes = _figure()
    axes.hist(values, bins=80, histtype="stepfilled", color="tab:blue")
    if log_y:
        axes.set_yscale("log")
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    return _save(figure, folder / f"{name}.png")


def _figure() -> tuple[Figure, Axes]:
    # Fixed margins: a layout engine would cost more than drawing the figure.
    figure = Figure(figsize=(7, 4.5))
    figure.subplots_adjust(left=0.12, right=0.97, bottom=0.12, top=0.92)
    return figure, figure.add_subplot()


def _save(figure: Figure, path: Path) -> Path:
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=110)
    return path


def write_histograms(values: BuildValues, folder: Path) -> list[Path]:
    """Write PLOT_NAMES as `<name>.png` into `folder` (created); returns the paths written."""
    folder.mkdir(parents=True, exist_ok=True)
    nodes = {split: values.samples[split][N_NODES].to_numpy() for split in SPLITS}
    edges = {split: values.samples[split][N_SPATIAL].to_numpy() for split in SPLITS}
    n_graphs = sum(values.degree_graphs.values())
    rows = f"{len(values.speed_mps):,} tracks rows"
    return [
        _split_histogram(
            folder,
            "nodes_per_graph",
            nodes,
            "Nodes per graph (all history steps)",
            "nodes per graph",
            "samples",
        ),
        _split_histogram(
            folder,
            "spatial_edges_per_graph",
            edges,
            "Spatial edges per graph (directed, all history steps)",
            "spatial edges per graph",
            "samples",
        ),
        _split_histogram(
            folder,
            "node_degree",
            values.spatial_in_degree,
            f"Spatial in-degree per node (from {n_graphs:,} sampled graphs)",
            "spatial in-degree (edges into a node at its step)",
            "nodes",
        ),
        _histogram(
            folder, "speed", values.speed_mps, f"Speed ({rows})", "speed (m/s)", "tracks rows"
        ),
        _histogram(
            folder,
            "heading",
            values.heading_rad,
            f"Heading ({rows}, log scale)",
            "heading (rad, from +y towards +x)",
            "tracks rows",
            log_y=True,
        ),
    ]
