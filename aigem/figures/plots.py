"""aigem's figures of an evaluation's errors (aigem.figures.pictures writes them as `aigem evaluate
--plots DIR`; a run's training curves are aigem.runs.curves'). Each function takes the numbers and
returns a Figure.

    error_by_horizon          RMSE and mean displacement error at every future step, AiGem and
                              constant velocity, beside the paper's table (NGSIM) as markers
    error_by_region           the same per region of the actor's present position
    final_error_distribution  the final displacement error of each target, as an ECDF

A run (a group of one model per horizon) draws its RMSE at h s from the first model that reaches
h s (the paper's protocol) as diamonds. Our curves are labelled with the build they come from
(`label`), never as NGSIM: a figure of a build of `ngsim-graphs synth` data says SYNTHETIC at its
top left (ngsim_graphs.plotting.mark_synthetic).

Figures are made with `matplotlib.figure.Figure` and an Agg canvas, not `pyplot`, from the pieces
of aigem.figure_parts (a footer, the legend below the axes) and aigem.figures.published (the published
rows).
"""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from aigem.evaluation.results import Evaluation, ModelEvaluation
from aigem.figure_parts import footed_figure, legend_below, panel_handles
from aigem.figures.published import paper_points
from aigem.metrics import FRONT_Y_M, REGIONS
from aigem.runs.course import training_line, training_words
from ngsim_graphs.palette import AIGEM, CONSTANT_VELOCITY
from ngsim_graphs.plotting import mark_synthetic

REGION_TITLES = {
    "front": f"front (y > {FRONT_Y_M:g} m)",
    "mid": f"mid (|y| ≤ {FRONT_Y_M:g} m)",
    "rear": f"rear (y < -{FRONT_Y_M:g} m)",
}


def _times_s(evaluation: ModelEvaluation) -> np.ndarray:
    return np.arange(1, evaluation.horizon_steps + 1) * evaluation.time_step_s


def _curve(evaluation: ModelEvaluation, kind: str, region: str, key: str) -> np.ndarray:
    """(K,) one per-step curve of an evaluation, NaN where no target counts."""
    values = evaluation.steps[kind][region][key]
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def _ours_label(result: Evaluation) -> str:
    return f"AiGem, this run's {result.horizons_s[-1]:g} s model"


def _evaluation_figure(
    width_in: float, result: Evaluation, label: str, legend_rows: int = 0
) -> Figure:
    """A figure whose footer says where our curves come from, with room for a legend of
    `legend_rows` rows below the axes (legend_below)."""
    footer = (
        f"Lines: {result.split} split ({result.samples:,} samples) of {label}. "
        f"{training_line(result.training)}."
    )
    return footed_figure(width_in, 4.5 + 0.2 * legend_rows, footer)


def _marked(figure: Figure, result: Evaluation) -> Figure:
    """The finished figure: its title says how many of its epochs the model trained (in red
    where the run is unfinished; the footer says how to continue it), SYNTHETIC at its top left
    where the build is of synthetic data."""
    title, trained = figure.get_suptitle(), training_words(result.training)
    unfinished = result.training is not None and not result.training["finished"]
    figure.suptitle(
        f"{title}\n{trained}" if title else trained,
        color="tab:red" if unfinished else "black",
        fontweight="bold" if unfinished else "normal",
    )
    if result.synthetic:
        mark_synthetic(figure)
    return figure


def _protocol_points(axes: Axes, result: Evaluation) -> None:
    """RMSE at s s from the first model that reaches s s (the paper's protocol), as diamonds
    labelled with their model; nothing for a run of one model (its curve is those numbers)."""
    if len(result.members) < 2:
        return
    seconds = [s for s in range(1, 6) if f"rmse_{s}s_m" in result.model["all"]]
    values = [result.model["all"][f"rmse_{s}s_m"] for s in seconds]
    axes.plot(
        seconds,
        [np.nan if v is None else v for v in values],
        ls="none",
        marker="D",
        ms=6,
        color=AIGEM,
        clip_on=False,
        label="AiGem at h s from its h s model (the paper's protocol)",
    )
    horizon_of = dict(zip(result.members, result.horizons_s, strict=True))
    for s, value in zip(seconds, values, strict=True):
        if value is not None:  # up and left: clear of a rising curve and of the paper's points
            axes.annotate(
                f"{horizon_of[result.sources[f'rmse_{s}s_m']]:g} s model",
                (s, value),
                xytext=(-5, 5),
                textcoords="offset points",
                ha="right",
                fontsize=7,
                color=AIGEM,
            )


def _model_lines(axes: Axes, times: np.ndarray, result: Evaluation, region: str, key: str) -> None:
    """AiGem's and constant velocity's curve of `key` over `times`, in their colours."""
    for kind, colour, who in (
        ("model", AIGEM, _ours_label(result)),
        ("constant_velocity", CONSTANT_VELOCITY, "constant velocity, same targets"),
    ):
        axes.plot(times, _curve(result.longest, kind, region, key), color=colour, lw=2, label=who)


def error_by_horizon(result: Evaluation, label: str) -> Figure:
    """RMSE and mean displacement error against the horizon at every future step, the x axis
    ending at the last one; the published points up to it."""
    evaluation = result.longest
    times = _times_s(evaluation)
    last_s = float(times[-1])
    figure = _evaluation_figure(11, result, label, legend_rows=3)
    rmse, mean = figure.subplots(1, 2)
    for axes, key, title in (
        (rmse, "rmse_m", "RMSE, pooled over the targets at each step"),
        (mean, "mean_error_m", "mean displacement error (markers: published FDE)"),
    ):
        _model_lines(axes, times, result, "all", key)
        paper_points(axes, "rmse_m" if key == "rmse_m" else "fde_m", last_s)
        axes.set(xlabel="horizon (s)", ylabel=f"{title.split(',')[0].split(' (')[0]} (m)")
        axes.set_title(title, fontsize=10)
        axes.set_xlim(0, last_s)
        axes.set_ylim(bottom=0)
        axes.grid(alpha=0.3)
    _protocol_points(rmse, result)
    legend_below(figure, panel_handles((rmse, mean)))
    step = f"every {evaluation.time_step_s:g} s step to {last_s:g} s"
    figure.suptitle(f"Error of AiGem and constant velocity by horizon, {step}")
    return _marked(figure, result)


def error_by_region(result: Evaluation, label: str) -> Figure:
    """The per-step RMSE and mean displacement error of each region of the present position."""
    evaluation = result.longest
    times = _times_s(evaluation)
    figure = _evaluation_figure(12, result, label, legend_rows=2)
    panels = figure.subplots(1, 3, sharey=True)
    for axes, region in zip(panels, REGIONS[1:], strict=True):
        _model_lines(axes, times, result, region, "rmse_m")
        for line in axes.get_lines():
            line.set_label(f"{line.get_label()}: RMSE")
        for kind, colour, who in (
            ("model", AIGEM, _ours_label(result)),
            ("constant_velocity", CONSTANT_VELOCITY, "constant velocity, same targets"),
        ):
            axes.plot(
                times,
                _curve(evaluation, kind, region, "mean_error_m"),
                color=colour,
                lw=1.5,
                ls="--",
                label=f"{who}: mean error",
            )
        count = evaluation.steps["model"][region]["n"]
        axes.set(title=f"{REGION_TITLES[region]}: {count[0]:,} targets", xlabel="horizon (s)")
        axes.set_xlim(0, times[-1])
        axes.set_ylim(bottom=0)
        axes.grid(alpha=0.3)
    panels[0].set_ylabel("error (m)")
    legend_below(figure, panel_handles(panels[:1]), columns=2)
    figure.suptitle(
        "Error by horizon and by region of the actor's present position (y along the road)"
    )
    return _marked(figure, result)


def final_error_distribution(result: Evaluation, label: str) -> Figure:
    """ECDF of the final displacement error of each target valid at the last predicted step."""
    evaluation = result.longest
    final = evaluation.final
    figure = _evaluation_figure(7.5, result, label)
    axes = figure.add_subplot()
    high = 1.0
    for values, colour, who in (
        (final.model_m, AIGEM, _ours_label(result)),
        (final.constant_velocity_m, CONSTANT_VELOCITY, "constant velocity"),
    ):
        if not len(values):
            continue
        ordered = np.sort(values)
        share = np.arange(1, len(ordered) + 1) / len(ordered)
        median, p90 = np.percentile(ordered, [50, 90])
        high = max(high, float(np.percentile(ordered, 99)))
        axes.step(
            ordered,
            share,
            where="post",
            color=colour,
            lw=2,
            label=f"{who}: median {median:.2f} m, 90th pct {p90:.2f} m",
        )
    for level, name in ((0.5, "median"), (0.9, "90th percentile")):
        axes.axhline(level, color="gray", lw=0.8, ls=":")
        axes.text(0, level, f" {name}", color="gray", fontsize=8, va="bottom")
    horizon_s = evaluation.horizon_steps * evaluation.time_step_s
    axes.set(
        xlim=(0, high * 1.05),
        ylim=(0, 1.01),
        xlabel=f"final displacement error at {horizon_s:g} s (m); axis to the 99th percentile",
        ylabel="share of targets with a final error ≤ x",
    )
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8, loc="lower right")
    figure.suptitle(
        f"Final displacement error at {horizon_s:g} s: {len(final.model_m):,} targets recorded "
        "to the end, as a cumulative share"
    )
    return _marked(figure, result)
