"""curves.png of a run: its training and validation loss per epoch, the best epoch, constant
velocity's validation loss (aigem.runs.folder.folder.plot_curves writes it into the run). Made with
`matplotlib.figure.Figure` and an Agg canvas, not `pyplot` (aigem.figure_parts)."""

from __future__ import annotations

import math

from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter, MaxNLocator

from aigem.figure_parts import png_bytes
from aigem.runs.run_log import EpochRow
from ngsim_graphs.palette import AIGEM, CONSTANT_VELOCITY
from ngsim_graphs.plotting import mark_synthetic

# The curves' labels say why the train loss may lie above the validation loss: dropout
# (ModelConfig.dropout) is on in training and off in validation, and the train loss is the mean
# over an epoch whose first batches met a worse model.
TRAIN_LABEL = "train (epoch mean, dropout on)"
VALIDATION_LABEL = "validation (end of epoch, no dropout)"
# Both curves are AiGem's, in its colour: validation solid, train dashed with hollow points.
TRAIN_STYLE = {"color": AIGEM, "ls": "--", "marker": "o", "ms": 4, "mfc": "white"}
VALIDATION_STYLE = {"color": AIGEM, "marker": "o", "ms": 4}


class _PlainLog(LogFormatter):
    """Log-axis labels as plain numbers (600, 0.1), not 6 x 10^2 or 1e-01."""

    def _num_to_string(self, x: float, vmin: float, vmax: float) -> str:
        return f"{x:g}"


def curves_png(
    rows: list[EpochRow],
    baseline_m2: float | None,
    horizon_s: float | None,
    synthetic: bool = False,
    trained: str = "",
) -> bytes:
    """curves.png of a run (curves_figure)."""
    return png_bytes(curves_figure(rows, baseline_m2, horizon_s, synthetic, trained))


def curves_figure(
    rows: list[EpochRow],
    baseline_m2: float | None,
    horizon_s: float | None,
    synthetic: bool = False,
    trained: str = "",
) -> Figure:
    """A run's training from its metrics.jsonl rows: train and validation MSE (m²) per epoch,
    the best epoch (by validation MSE) marked, constant velocity's validation MSE as a line; the
    legend below the axes, where it hides no point (after one epoch, the only points are in the
    middle); `trained` (how many of its epochs, aigem.runs.course) under the title; SYNTHETIC at
    the top left for a run on a build of synthetic data."""
    figure = Figure(figsize=(7, 5), layout="constrained")
    axes = figure.add_subplot()
    epochs = [row.epoch for row in rows]
    axes.plot(epochs, [r.train_loss_m2 for r in rows], **TRAIN_STYLE, label=TRAIN_LABEL)
    axes.plot(epochs, [r.val_loss_m2 for r in rows], **VALIDATION_STYLE, label=VALIDATION_LABEL)
    best = rows[-1].best_epoch
    best_m2 = next((r.val_loss_m2 for r in rows if r.epoch == best), None)
    if best_m2 is not None:
        axes.axvline(best, color="tab:green", lw=1, ls=":")
        axes.plot(
            [best],
            [best_m2],
            "*",
            ms=13,
            color="tab:green",
            zorder=1.5,  # under the validation point it marks, which stays visible
            label=f"best: epoch {best}, validation {best_m2:.3g} m²",
        )
    if baseline_m2 is not None and math.isfinite(baseline_m2):
        axes.axhline(
            baseline_m2,
            color=CONSTANT_VELOCITY,
            lw=1.5,
            label=f"constant velocity, validation ({baseline_m2:.3g} m²)",
        )
    # Whole epochs, also where the axis holds one (the default asks for two ticks, and falls
    # back to 0.5, 0.6, ... when no two whole numbers fit).
    axes.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    axes.set_xlim(0.5, max(epochs) + 0.5)
    horizon = "" if horizon_s is None else f", {horizon_s:g} s horizon"
    axes.set(
        xlabel="epoch",
        ylabel="MSE over valid future steps (m², log)",
        yscale="log",
        title=f"AiGem training{horizon}" + (f"\n{trained}" if trained else ""),
    )
    axes.yaxis.set_major_formatter(_PlainLog(labelOnlyBase=False))
    axes.yaxis.set_minor_formatter(_PlainLog(labelOnlyBase=False, minor_thresholds=(2, 0.5)))
    rates = [r.learning_rate for r in rows]
    if None not in rates and len(set(rates)) > 1:  # a schedule: its rate on a second axis
        rate_axes = axes.twinx()
        rate_axes.plot(epochs, rates, color="tab:gray", lw=1, alpha=0.6)
        rate_axes.set_ylabel("learning rate at the epoch's end (grey)", color="tab:gray")
        rate_axes.set_ylim(bottom=0)
        rate_axes.tick_params(axis="y", colors="tab:gray")
    figure.legend(*axes.get_legend_handles_labels(), loc="outside lower center", ncols=2)
    if synthetic:
        mark_synthetic(figure)
    return figure
