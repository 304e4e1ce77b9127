"""ngsim_graphs.plotting: per-split shares (each split's own, never stacked) on values counted by
hand, and the PNG files of `write_histograms`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import StepPatch

from ngsim_graphs.plotting import (
    PLOT_NAMES,
    SYNTHETIC_PICTURE_LABEL,
    degree_title,
    mark_synthetic,
    share_figure,
    write_histograms,
)
from ngsim_graphs.statistics import BuildValues

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _stairs(figure) -> dict[str, np.ndarray]:  # noqa: ANN001
    """label -> the bin values of each step line drawn."""
    axes = figure.axes[0]
    return {p.get_label(): p.get_data().values for p in axes.patches if isinstance(p, StepPatch)}


def test_each_split_sums_to_one_on_shared_bins() -> None:
    # train: 1, 1, 2, 3 -> shares 1/2, 1/4, 1/4 on the values 1, 2, 3; val: 3 -> 0, 0, 1
    figure = share_figure(
        {"train": np.array([1, 1, 2, 3]), "val": np.array([3]), "test": np.array([], int)},
        "Nodes",
        "nodes per graph",
        "graphs",
    )
    assert {label: list(values) for label, values in _stairs(figure).items()} == {
        "train (n=4 graphs)": [0.5, 0.25, 0.25],
        "val (n=1 graphs)": [0.0, 0.0, 1.0],
    }
    axes = figure.axes[0]
    legend = [text.get_text() for text in axes.get_legend().get_texts()]
    assert legend == ["train (n=4 graphs)", "val (n=1 graphs)", "test (n=0 graphs): none drawn"]
    assert axes.get_ylabel() == "share of graphs"  # one bin per value


def test_wide_bins_are_named() -> None:
    figure = share_figure({"train": np.arange(400)}, "Edges", "edges", "graphs")
    [values] = _stairs(figure).values()
    assert np.isclose(values.sum(), 1.0) and figure.axes[0].get_ylabel().startswith(
        "share of graphs per bin ("
    )


def test_degree_title_names_the_graphs_of_each_split() -> None:
    assert degree_title({"train": 300, "val": 12, "test": 0}) == (
        "Spatial in-degree per node, share per split\n"
        "(graphs sampled per split: train 300, val 12, test 0)"
    )


def test_write_histograms(tmp_path: Path) -> None:
    def samples(nodes: list[int]) -> pl.DataFrame:
        return pl.DataFrame({"n_nodes": nodes, "n_spatial_edges": [2 * n for n in nodes]})

    values = BuildValues(
        samples={"train": samples([5, 6, 7]), "val": samples([6]), "test": samples([])},
        degree_graphs={"train": 3, "val": 1, "test": 0},
        spatial_in_degree={
            "train": np.array([1, 2, 2]),
            "val": np.array([1]),
            "test": np.zeros(0, np.int64),
        },
        speed_mps=np.array([10.0, 12.0]),
        heading_rad=np.array([0.0, 0.1]),
    )
    paths = write_histograms(values, tmp_path / "plots")
    assert paths == [tmp_path / "plots" / f"{name}.png" for name in PLOT_NAMES]
    for path in paths:
        data = path.read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 5_000


def _extent(figure: Figure, text: str):  # noqa: ANN202
    (found,) = [t for t in figure.texts if t.get_text() == text]
    return found.get_window_extent()


def test_the_synthetic_label_has_a_line_of_its_own() -> None:
    """Above a suptitle as wide as the figure (the title keeps its colour), or above the axes'
    title where there is none: never on either."""
    titled = Figure(figsize=(7.5, 5), layout="constrained")
    axes = titled.add_subplot(title="the axes' title")
    titled.suptitle("A centred title as wide as the figure, wider than its left half", color="red")
    mark_synthetic(titled)
    FigureCanvasAgg(titled).draw()
    label = _extent(titled, SYNTHETIC_PICTURE_LABEL)
    title = _extent(titled, titled.get_suptitle())
    assert label.y0 > (title.y0 + title.y1) / 2  # on the title's empty first line
    assert not title.overlaps(axes.title.get_window_extent())
    assert [t.get_color() for t in titled.texts if t.get_text() == titled.get_suptitle()] == ["red"]
    for plain in (
        Figure(figsize=(7, 4.5), layout="constrained"),
        share_figure({"train": np.array([1, 2])}, "t", "x", "g"),
    ):
        axes = plain.axes[0] if plain.axes else plain.add_subplot(title="a long axes title " * 3)
        mark_synthetic(plain)
        FigureCanvasAgg(plain).draw()
        label = _extent(plain, SYNTHETIC_PICTURE_LABEL)
        assert not label.overlaps(axes.title.get_window_extent())
        assert label.y0 > axes.get_window_extent().y1
