"""The figures of `aigem paper`'s report, drawn from report.json's numbers (aigem.report):

    table1.png    RMSE against the horizon: AiGem (each horizon's model), constant velocity, and
                  the paper's Table 1 as markers (published, NGSIM)
    dmin.png      RMSE per horizon for each d_min, as bars (the paper's d_min figure)
    concat.png    RMSE per horizon with and without the output concatenation
    curves.png    train and validation RMSE per epoch, one panel per horizon's model
    regions.png   RMSE per horizon for front, mid and rear actors

AiGem's numbers are the mean over the seeds; where they have a 95 % interval (several seeds,
aigem.report_cells) it is drawn: a band around a line, an error bar on a bar.

A figure of synthetic data says SYNTHETIC at its top left (ngsim_graphs.plotting.mark_synthetic);
one of partly synthetic data PARTLY SYNTHETIC, one of an unfinished report UNFINISHED, in its
title.
Figures are made as aigem.plots makes them: a Figure on an Agg canvas, no pyplot.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from aigem import report_cells
from aigem.plots import REGION_TITLES, paper_points, png_bytes
from aigem.report_cells import Cell
from aigem.report_text import data_mark
from ngsim_graphs.palette import AIGEM, CONSTANT_VELOCITY
from ngsim_graphs.plotting import mark_synthetic

SECONDS = np.array(report_cells.SECONDS)
UNFINISHED_PICTURE = "UNFINISHED (training stopped by --max-hours)"
PARTLY_SYNTHETIC_PICTURE = "PARTLY SYNTHETIC data"


def _values(cells: Sequence[Cell | None]) -> np.ndarray:
    """The cells' numbers (the means over the seeds), NaN for none."""
    values = [report_cells.value_of(cell) for cell in cells]
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def _bounds(cells: Sequence[Cell | None]) -> tuple[np.ndarray, np.ndarray] | None:
    """The cells' 95 % intervals (low, high), NaN where a cell has none; None where none has."""
    low = [np.nan if c is None or c["low"] is None else c["low"] for c in cells]
    high = [np.nan if c is None or c["high"] is None else c["high"] for c in cells]
    if np.isnan(low).all():
        return None
    return np.array(low, dtype=np.float64), np.array(high, dtype=np.float64)


def _ours(document: dict[str, Any]) -> str:
    """How AiGem's numbers came: "mean of 3 seeds, 95 % interval", nothing for one seed."""
    seeds = len(document["seeds"])
    return f", mean of {seeds} seeds, 95 % interval" if seeds > 1 else ""


def _finish(figure: Figure, document: dict[str, Any]) -> bytes:
    marks = [PARTLY_SYNTHETIC_PICTURE] * document["partly_synthetic"]
    marks += [UNFINISHED_PICTURE] * (not document["finished"])
    if marks:  # in the suptitle: a constrained layout makes room for it
        title = figure.get_suptitle()
        words = ", ".join(marks) + (f": {title}" if title else "")
        figure.suptitle(words, color="tab:red", fontweight="bold")
    if document["synthetic"]:
        mark_synthetic(figure)
    return png_bytes(figure)


def _source(document: dict[str, Any]) -> str:
    mark = data_mark(document)
    return f"{mark} data" if mark else "this call's data"


def table1_figure(document: dict[str, Any]) -> Figure:
    """RMSE at 1..5 s of AiGem and constant velocity, beside the published rows."""
    part = document["table1"]
    figure = Figure(figsize=(8, 5.5), layout="constrained")
    axes = figure.add_subplot()
    for name, colour in (("AiGem (this run)", AIGEM), ("constant velocity", CONSTANT_VELOCITY)):
        cells = [part["ours"][name][f"rmse_{s}s_m"] for s in SECONDS]
        ours = _ours(document) if name.startswith("AiGem") else ""
        label = f"{name}, {_source(document)}{ours}"
        axes.plot(SECONDS, _values(cells), color=colour, lw=2, marker="D", label=label)
        if (bounds := _bounds(cells)) is not None:
            axes.fill_between(SECONDS, *bounds, color=colour, alpha=0.2, lw=0)
    paper_points(axes, "rmse_m")  # part["published"]'s rows, as aigem evaluate draws them
    axes.set(
        xlabel="horizon (s)",
        ylabel="RMSE (m)",
        title="Table 1: RMSE by horizon (each horizon's own model)",
        xticks=SECONDS,
    )
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3)
    figure.legend(
        *axes.get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=8
    )
    return figure


def bars_figure(series: dict[str, Sequence[Cell | None]], title: str, legend_title: str) -> Figure:
    """RMSE per horizon as grouped bars, one colour per series (its label its key), each bar's
    95 % interval as an error bar where it has one."""
    figure = Figure(figsize=(8, 4.8), layout="constrained")
    axes = figure.add_subplot()
    width = 0.8 / max(len(series), 1)
    for index, (label, cells) in enumerate(series.items()):
        heights = _values(cells)
        offset = (index - (len(series) - 1) / 2) * width
        bounds = _bounds(cells)
        errors = (
            None if bounds is None else np.nan_to_num([heights - bounds[0], bounds[1] - heights])
        )
        drawn = axes.bar(
            SECONDS + offset, np.nan_to_num(heights), width, label=label, yerr=errors, capsize=2
        )
        axes.bar_label(
            drawn, labels=[("–" if np.isnan(h) else f"{h:.2f}") for h in heights], fontsize=7
        )
    axes.set(xlabel="horizon (s)", ylabel="RMSE (m)", title=title, xticks=SECONDS)
    axes.margins(y=0.15)
    axes.grid(alpha=0.3, axis="y")
    axes.legend(title=legend_title, fontsize=8, loc="upper left")
    return figure


def curves_figure(curves: dict[str, dict[str, Any]], seeds: int) -> Figure:
    """Train and validation RMSE per epoch, one panel per model, the best epoch starred: with
    several seeds, their mean, its 95 % interval as a band, and each seed's best epoch."""
    figure = Figure(figsize=(3.2 * max(len(curves), 1), 3.8), layout="constrained")
    panels = figure.subplots(1, max(len(curves), 1), squeeze=False)[0]
    for axes, (name, curve) in zip(panels, curves.items(), strict=False):
        _curve_panel(axes, name, curve)
    panels[0].set_ylabel("RMSE (m)")
    figure.legend(*panels[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
    over = f"\n(mean of {seeds} seeds, 95 % interval)" if seeds > 1 else ""
    figure.suptitle(f"Training of one model per horizon (d_min 25 m){over}")
    return figure


def _curve_panel(axes: Axes, name: str, curve: dict[str, Any]) -> None:
    epochs = np.array(curve["epoch"])
    for key, words in (("train_rmse_m", "train"), ("val_rmse_m", "validation")):
        (line,) = axes.plot(epochs, _values(curve[key]), marker="o", ms=3, label=words)
        if (bounds := _bounds(curve[key])) is not None:
            axes.fill_between(epochs, *bounds, color=line.get_color(), alpha=0.2, lw=0)
    best = [  # each seed's best epoch, at its own validation RMSE
        (seed["best_epoch"], seed["val_rmse_m"][seed["epoch"].index(seed["best_epoch"])])
        for seed in curve["seeds"]
        if seed["best_epoch"] in seed["epoch"]
    ]
    if best:
        label = "best epoch" + (" (each seed)" if len(curve["seeds"]) > 1 else "")
        axes.plot(*zip(*best, strict=True), "*", ms=12, color="tab:green", zorder=1.5, label=label)
    axes.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    axes.set_xlim(0.5, max(curve["epoch"], default=1) + 0.5)
    horizon = name.removeprefix("h").removesuffix("s")  # a member's name: h1s .. h5s
    axes.set(title=f"the {horizon} s model", xlabel="epoch")
    axes.grid(alpha=0.3)


def report_figures(document: dict[str, Any]) -> dict[str, bytes]:
    """The PNG of each part the report holds, by name (table1, dmin, concat, curves, regions)."""
    drawn: dict[str, Figure] = {}
    if "table1" in document:
        drawn["table1"] = table1_figure(document)
    over = f"\n({_ours(document)[2:]})" if _ours(document) else ""  # a second line
    if "dmin" in document:
        series = {f"d_min {d} m": values for d, values in document["dmin"].items()}
        title = f"RMSE by d_min (each horizon's own model){over}"
        drawn["dmin"] = bars_figure(series, title, "spatial edges")
    if "concat" in document:
        series = {f"{k} concatenation": v for k, v in document["concat"].items()}
        title = f"RMSE with and without the previous position at the MLP (d_min 25 m){over}"
        drawn["concat"] = bars_figure(series, title, "output")
    if "curves" in document:
        drawn["curves"] = curves_figure(document["curves"], len(document["seeds"]))
    if "regions" in document:  # each region defined in its legend entry
        series = {REGION_TITLES[r]: v for r, v in document["regions"]["rmse_m"].items()}
        title = f"RMSE by the actor's present position (y along the road){over}"
        drawn["regions"] = bars_figure(series, title, "region")
    return {name: _finish(figure, document) for name, figure in drawn.items()}
