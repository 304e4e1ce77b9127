"""The figures of `aigem paper`'s report, drawn from report.json's numbers (aigem.report):

    table1.png    RMSE against the horizon: AiGem (each horizon's model), constant velocity, and
                  the paper's Table 1 as markers (published, NGSIM)
    dmin.png      RMSE per horizon for each d_min, as bars (the paper's d_min figure)
    concat.png    RMSE per horizon with and without the output concatenation
    curves.png    train and validation RMSE per epoch, one panel per horizon's model
    regions.png   RMSE per horizon for front, mid and rear actors

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

from aigem import report
from aigem.plots import BASELINE, OURS, REGION_TITLES, paper_points, png_bytes
from ngsim_graphs.plotting import mark_synthetic

SECONDS = np.array(report.SECONDS)
UNFINISHED_PICTURE = "UNFINISHED (training stopped by --max-hours)"
PARTLY_SYNTHETIC_PICTURE = "PARTLY SYNTHETIC data"


def _values(values: Sequence[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


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
    mark = report.data_mark(document)
    return f"{mark} data" if mark else "this call's data"


def table1_figure(document: dict[str, Any]) -> Figure:
    """RMSE at 1..5 s of AiGem and constant velocity, beside the published rows."""
    part = document["table1"]
    figure = Figure(figsize=(8, 5.5), layout="constrained")
    axes = figure.add_subplot()
    for name, colour in (("AiGem (this run)", OURS), ("constant velocity", BASELINE)):
        row = part["ours"][name]
        values = _values([row[f"rmse_{s}s_m"] for s in SECONDS])
        axes.plot(
            SECONDS, values, color=colour, lw=2, marker="D", label=f"{name}, {_source(document)}"
        )
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


def bars_figure(series: dict[str, Sequence[float | None]], title: str, legend_title: str) -> Figure:
    """RMSE per horizon as grouped bars, one colour per series (its label its key)."""
    figure = Figure(figsize=(8, 4.8), layout="constrained")
    axes = figure.add_subplot()
    width = 0.8 / max(len(series), 1)
    for index, (label, values) in enumerate(series.items()):
        heights = _values(values)
        offset = (index - (len(series) - 1) / 2) * width
        drawn = axes.bar(SECONDS + offset, np.nan_to_num(heights), width, label=label)
        axes.bar_label(
            drawn, labels=[("–" if np.isnan(h) else f"{h:.2f}") for h in heights], fontsize=7
        )
    axes.set(xlabel="horizon (s)", ylabel="RMSE (m)", title=title, xticks=SECONDS)
    axes.margins(y=0.15)
    axes.grid(alpha=0.3, axis="y")
    axes.legend(title=legend_title, fontsize=8, loc="upper left")
    return figure


def curves_figure(curves: dict[str, dict[str, list]]) -> Figure:
    """Train and validation RMSE per epoch, one panel per model, the best epoch starred."""
    figure = Figure(figsize=(3.2 * max(len(curves), 1), 3.8), layout="constrained")
    panels = figure.subplots(1, max(len(curves), 1), squeeze=False)[0]
    for axes, (name, curve) in zip(panels, curves.items(), strict=False):
        _curve_panel(axes, name, curve)
    panels[0].set_ylabel("RMSE (m)")
    figure.legend(*panels[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
    figure.suptitle("Training of one model per horizon (d_min 25 m)")
    return figure


def _curve_panel(axes: Axes, name: str, curve: dict[str, list]) -> None:
    epochs = curve["epoch"]
    axes.plot(epochs, curve["train_rmse_m"], marker="o", ms=3, label="train")
    axes.plot(epochs, curve["val_rmse_m"], marker="o", ms=3, label="validation")
    best = curve["best_epoch"]
    if best in epochs:
        value = curve["val_rmse_m"][epochs.index(best)]
        axes.plot([best], [value], "*", ms=12, color="tab:green", zorder=1.5, label="best epoch")
    axes.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    axes.set_xlim(0.5, max(epochs, default=1) + 0.5)
    horizon = name.removeprefix("h").removesuffix("s")  # a member's name: h1s .. h5s
    axes.set(title=f"the {horizon} s model", xlabel="epoch")
    axes.grid(alpha=0.3)


def report_figures(document: dict[str, Any]) -> dict[str, bytes]:
    """The PNG of each part the report holds, by name (table1, dmin, concat, curves, regions)."""
    drawn: dict[str, Figure] = {}
    if "table1" in document:
        drawn["table1"] = table1_figure(document)
    if "dmin" in document:
        series = {f"d_min {d} m": values for d, values in document["dmin"].items()}
        drawn["dmin"] = bars_figure(
            series, "RMSE by d_min (each horizon's own model)", "spatial edges"
        )
    if "concat" in document:
        series = {f"{k} concatenation": v for k, v in document["concat"].items()}
        drawn["concat"] = bars_figure(
            series, "RMSE with and without the previous position at the MLP (d_min 25 m)", "output"
        )
    if "curves" in document:
        drawn["curves"] = curves_figure(document["curves"])
    if "regions" in document:  # each region defined in its legend entry
        series = {REGION_TITLES[r]: v for r, v in document["regions"]["rmse_m"].items()}
        drawn["regions"] = bars_figure(
            series, "RMSE by the actor's present position (y along the road)", "region"
        )
    return {name: _finish(figure, document) for name, figure in drawn.items()}
