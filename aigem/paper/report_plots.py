"""The figures of `aigem paper`'s report, drawn from report.json's numbers (aigem.paper.report):

    table1.png    RMSE at 1..5 s as the paper's Table 1 reads: a panel per horizon, a row per
                  model, this call's AiGem and constant velocity above the published rows
    dmin.png      RMSE per horizon for each d_min, as bars (the paper's d_min figure)
    concat.png    RMSE per horizon with and without the output concatenation
    curves.png    train and validation RMSE per epoch, one panel per horizon's model
    regions.png   RMSE per horizon for front, mid and rear actors

The colours are ngsim_graphs.palette's, as in every figure: AiGem at the paper's settings in
AiGem's colour (another setting of an ablation in OTHER_SETTINGS, a region in a shade of it),
constant velocity in its own, drawn on the same targets over each bar; the published rows
hollow. AiGem's numbers are the mean over the seeds; where they have a 95 % interval (several
seeds; with one seed, Table 1's bootstrap over the test samples) it is drawn as an error bar or
a band. Each figure's footer says how AiGem was trained (epochs, seeds) and what its intervals
are, or that it has none.

A figure of synthetic data says SYNTHETIC at its top left (ngsim_graphs.plotting.mark_synthetic);
one of partly synthetic data PARTLY SYNTHETIC, one of an unfinished report UNFINISHED, in its
title.
Figures are made as aigem.figure_parts makes them: a Figure on an Agg canvas, no pyplot.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from aigem.figure_parts import footed_figure, legend_below, panel_handles, png_bytes
from aigem.figures.plots import REGION_TITLES
from aigem.figures.published import published_style
from aigem.paper import report_cells
from aigem.paper.report_cells import Cell
from aigem.paper.report_tables import data_mark
from aigem.paper.report_text import seeds_words
from aigem.paper_layout import PAPER_D_MIN_M
from aigem.runs.curves import TRAIN_STYLE, VALIDATION_STYLE
from ngsim_graphs.palette import AIGEM, CONSTANT_VELOCITY, OTHER_SETTINGS, REGION_SHADES
from ngsim_graphs.plotting import mark_synthetic

SECONDS = np.array(report_cells.SECONDS)
UNFINISHED_PICTURE = "UNFINISHED (training stopped by --max-hours)"
PARTLY_SYNTHETIC_PICTURE = "PARTLY SYNTHETIC data"
CONSTANT_VELOCITY_TICK = "constant velocity, same targets"
PAPERS = " (the paper's)"  # after the label of the paper's setting in an ablation


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


def _errors(values: np.ndarray, bounds: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """(2, n) distances from each value down and up to its interval's bounds (errorbar's), 0
    where it has none; None without any interval."""
    if bounds is None:
        return None
    return np.nan_to_num([values - bounds[0], bounds[1] - values]).clip(min=0)


def _training(document: dict[str, Any]) -> str:
    """How AiGem was trained: "AiGem: up to 2 epochs per model, seed 0"."""
    epochs = document["settings"]["epochs"]
    return f"AiGem: up to {epochs} epoch{'s' * (epochs != 1)} per model, {seeds_words(document['seeds'])}"


def _intervals(document: dict[str, Any], bootstrap: dict[str, Any] | None = None) -> str:
    """What the error bars are: the seeds' interval, a bootstrap's (`bootstrap`: Table 1's
    `intervals` with one seed), or that there are none."""
    seeds = len(document["seeds"])
    if seeds > 1:
        return (
            f"AiGem: the mean over the {seeds} seeds, its 95 % interval (Student's t) as an "
            "error bar or a band"
        )
    if bootstrap is not None:
        return (
            f"error bars: AiGem's 95 % interval, a bootstrap over the {bootstrap['samples']:,} "
            "test samples (the test set's noise, not training's: one seed)"
        )
    return "one seed: no interval (`aigem\u00a0paper\u00a0--seeds\u00a0N` draws 95 % intervals)"


def _footer(document: dict[str, Any], bootstrap: dict[str, Any] | None = None) -> str:
    mark = data_mark(document)
    data = f"{mark} data" if mark else "this call's data"
    return f"This call: {data}, {document['split']} split. {_training(document)}; {_intervals(document, bootstrap)}."


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


# ------------------------------------------------------------------------------------------------
# Table 1


@dataclass(frozen=True)
class _Row:
    """A row of the Table 1 figure: its label, RMSE at 1..5 s (NaN: none), its interval."""

    label: str
    values: np.ndarray  # (5,) metres
    bounds: tuple[np.ndarray, np.ndarray] | None
    colour: str
    marker: str
    filled: bool  # this call's numbers; a published row is hollow


def _table1_rows(part: dict[str, Any]) -> list[_Row]:
    """Table 1's rows, top to bottom: this call's AiGem and constant velocity, the published
    AiGem and constant velocity, then the other published rows."""
    rows = []
    for name, colour in (("AiGem (this run)", AIGEM), ("constant velocity", CONSTANT_VELOCITY)):
        cells = [part["ours"][name][f"rmse_{s}s_m"] for s in SECONDS]
        label = f"{name.split(' (')[0]}, this call"
        rows.append(_Row(label, _values(cells), _bounds(cells), colour, "D", True))
    published = part["published"]
    first = [n for n in published if n.startswith(("AiGem", "constant velocity"))]
    for name in [*first, *(n for n in published if n not in first)]:
        model, colour, marker = published_style(name)
        values = [published[name][f"rmse_{s}s_m"] for s in SECONDS]
        numbers = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
        rows.append(_Row(f"{model}, published", numbers, None, colour, marker, False))
    return rows


def _table1_panel(axes: Axes, rows: list[_Row], column: int) -> None:
    """One horizon's column of Table 1: each row's RMSE as a marker on its line, its number
    beside it, its interval as an error bar."""
    for y, row in enumerate(rows):
        value = row.values[column]
        if np.isnan(value):
            axes.text(0, y, " –", va="center", fontsize=8)
            continue
        errors = _errors(row.values, row.bounds)
        axes.errorbar(
            value,
            y,
            xerr=None if errors is None else errors[:, column : column + 1],
            marker=row.marker,
            ms=7,
            mfc=row.colour if row.filled else "none",
            mec=row.colour,
            mew=1.5,
            color=row.colour,
            capsize=3,
            ls="none",
        )
        axes.annotate(
            f"{value:.2f}", (value, y), xytext=(7, 4), textcoords="offset points", fontsize=7
        )
    ends = [r.values[column] if r.bounds is None else r.bounds[1][column] for r in rows]
    axes.set_xlim(0, np.nanmax([*ends, 1.0]) * 1.35)
    axes.axhline(1.5, color="0.6", lw=0.8)  # this call's rows above, the published below
    axes.set(title=f"{SECONDS[column]} s", xlabel="RMSE (m)")
    axes.grid(alpha=0.3, axis="x")


def table1_figure(document: dict[str, Any]) -> Figure:
    """RMSE at 1..5 s (each from its own horizon's model) of this call's AiGem and constant
    velocity on the same targets, above the published rows: a panel per horizon, a row per
    model, the number beside each point."""
    part = document["table1"]
    rows = _table1_rows(part)
    figure = footed_figure(11, 1.4 + 0.3 * len(rows), _footer(document, part["intervals"]))
    panels = figure.subplots(1, len(SECONDS), sharey=True)
    for column, axes in enumerate(panels):
        _table1_panel(axes, rows, column)
    panels[0].set_yticks(range(len(rows)), [row.label for row in rows])
    panels[0].set_ylim(len(rows) - 0.5, -0.5)  # the table's first row on top
    for tick, row in zip(panels[0].get_yticklabels(), rows, strict=True):
        tick.set_color(row.colour)
    figure.suptitle(
        "RMSE by horizon of each model: this call's beside the published NGSIM rows "
        "(AiGem: each horizon's own model)"
    )
    return figure


# ------------------------------------------------------------------------------------------------
# Bars: the ablations and the regions


def bars_figure(
    series: dict[str, Sequence[Cell | None]],
    colours: Sequence[str],
    reference: Sequence[Sequence[Cell | None]],
    title: str,
    legend_title: str,
    footer: str,
) -> Figure:
    """RMSE per horizon as grouped bars, one per series (its label its key, its colour the
    next of `colours`), its number above it, its 95 % interval as an error bar where it has
    one, and over it constant velocity's RMSE on the same targets (`reference`, one per
    series) as a tick in constant velocity's colour."""
    figure = footed_figure(8.5, 4.8, footer)
    axes = figure.add_subplot()
    width = 0.8 / max(len(series), 1)
    for index, ((label, cells), colour) in enumerate(zip(series.items(), colours, strict=True)):
        heights = _values(cells)
        x = SECONDS + (index - (len(series) - 1) / 2) * width
        drawn = axes.bar(
            x,
            np.nan_to_num(heights),
            width,
            color=colour,
            label=label,
            yerr=_errors(heights, _bounds(cells)),
            capsize=3,
            error_kw={"elinewidth": 1.2, "ecolor": "black"},
        )
        words = [("–" if np.isnan(h) else f"{h:.2f}") for h in heights]
        axes.bar_label(drawn, words, padding=2, fontsize=7)  # above the bar and its error bar
        axes.hlines(
            _values(reference[index]),
            x - width / 2,
            x + width / 2,
            colors=CONSTANT_VELOCITY,
            lw=2.5,
            zorder=3,
            label=CONSTANT_VELOCITY_TICK,
        )
    axes.set(xlabel="horizon (s)", ylabel="RMSE (m)", xticks=SECONDS)
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3, axis="y")
    handles = panel_handles([axes])
    handles[CONSTANT_VELOCITY_TICK] = handles.pop(CONSTANT_VELOCITY_TICK)  # after the bars
    legend_below(figure, handles, columns=len(series) + 1, title=legend_title)
    figure.suptitle(title)
    return figure


def _ablation_series(
    cells: dict[str, Any], paper: str, words: str
) -> tuple[dict[str, Any], list[str], list[Any]]:
    """An ablation's bars: `words` of each label ("d_min {} m"), the `paper` label's marked as
    the paper's and in AiGem's colour, the others in OTHER_SETTINGS; and each one's constant
    velocity."""
    series, colours = {}, []
    others = iter(OTHER_SETTINGS)
    for label, values in cells.items():
        mine = label == paper
        series[words.format(label) + PAPERS * mine] = values
        colours.append(AIGEM if mine else next(others))
    return series, colours


def dmin_figure(document: dict[str, Any]) -> Figure:
    paper = next((d for d in document["dmin"] if float(d) == PAPER_D_MIN_M), None)
    series, colours = _ablation_series(document["dmin"], paper, "d_min {} m")
    reference = list(document["dmin_constant_velocity"].values())
    title = "RMSE by d_min, the actor-actor edges' reach (each horizon's own model)"
    footer = _footer(document, document.get("dmin_intervals"))  # one seed: a bootstrap's
    return bars_figure(series, colours, reference, title, "AiGem, spatial edges", footer)


def concat_figure(document: dict[str, Any]) -> Figure:
    series, colours = _ablation_series(document["concat"], "with", "{} concatenation")
    reference = list(document["concat_constant_velocity"].values())
    title = "RMSE with and without the previous position at the MLP (d_min 25 m)"
    footer = _footer(document, document.get("concat_intervals"))  # one seed: a bootstrap's
    return bars_figure(series, colours, reference, title, "AiGem, output", footer)


def regions_figure(document: dict[str, Any]) -> Figure:
    part = document["regions"]
    series = {REGION_TITLES[r]: v for r, v in part["rmse_m"].items()}
    reference = list(part["constant_velocity_rmse_m"].values())
    title = "RMSE by the actor's present position, y along the road (d_min 25 m)"
    colours = REGION_SHADES[: len(series)]
    return bars_figure(series, colours, reference, title, "AiGem, region", _footer(document))


# ------------------------------------------------------------------------------------------------
# Training curves


def curves_figure(document: dict[str, Any]) -> Figure:
    """Train and validation RMSE per epoch, one panel per model of the paper's fit, the best
    epoch starred: with several seeds, their mean, its 95 % interval as a band, and each seed's
    best epoch."""
    curves = document["curves"]
    footer = f"{_training(document)}; {_intervals(document)}."
    figure = footed_figure(3.2 * max(len(curves), 1), 3.8, footer)
    panels = figure.subplots(1, max(len(curves), 1), squeeze=False)[0]
    for axes, (name, curve) in zip(panels, curves.items(), strict=False):
        _curve_panel(axes, name, curve)
    panels[0].set_ylabel("RMSE (m)")
    legend_below(figure, panel_handles(panels[:1]))
    figure.suptitle("Training of one AiGem model per horizon (d_min 25 m)")
    return figure


def _curve_panel(axes: Axes, name: str, curve: dict[str, Any]) -> None:
    epochs = np.array(curve["epoch"])
    for key, words, style in (
        ("train_rmse_m", "train", TRAIN_STYLE),
        ("val_rmse_m", "validation", VALIDATION_STYLE),
    ):
        axes.plot(epochs, _values(curve[key]), **style, label=words)
        if (bounds := _bounds(curve[key])) is not None:
            axes.fill_between(epochs, *bounds, color=style["color"], alpha=0.15, lw=0)
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


DRAWN = {  # each figure's part of report.json -> its drawing
    "table1": table1_figure,
    "dmin": dmin_figure,
    "concat": concat_figure,
    "curves": curves_figure,
    "regions": regions_figure,
}


def draw_report(document: dict[str, Any]) -> dict[str, Figure]:
    """The figure of each part the report holds, by name (table1, dmin, concat, curves,
    regions), before report_figures marks and renders it."""
    return {name: draw(document) for name, draw in DRAWN.items() if name in document}


def report_figures(document: dict[str, Any]) -> dict[str, bytes]:
    """The PNG of each part the report holds, by name, marked SYNTHETIC, PARTLY SYNTHETIC and
    UNFINISHED where the report is."""
    return {name: _finish(figure, document) for name, figure in draw_report(document).items()}
