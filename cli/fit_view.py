"""What `aigem fit` prints: a line per epoch, the results, what an interrupted fit kept."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from ngsim_cli.console import counted, print_line, stdout
from ngsim_cli.exits import exit_on_error
from ngsim_cli.progress import progress_line

if TYPE_CHECKING:
    from aigem.runs.records import Group
    from aigem.runs.run_log import EpochRow
    from aigem.training.fit import FitResult


def discard_if_nothing_kept(group: Group, created: bool) -> list[int]:
    """Each model's epochs kept in the run `group` (its last checkpoint's); with none, a fit that
    stopped (interrupted, or an error) takes away the files it wrote (runs.discard_unfinished)."""
    from aigem.runs.checkpoints import epochs_kept
    from aigem.runs.folder import discard_unfinished

    kept = [epochs_kept(member) if member.is_dir() else 0 for member in group.members]
    if not any(kept):
        with exit_on_error():
            discard_unfinished(group, created)
    return kept


def interrupted(group: Group, created: bool) -> typer.Exit:
    """One line on what an interrupted fit kept, and exit status 130 (as for Ctrl-C): the epochs
    of each model's last checkpoint, or, with none, nothing (the run's files go)."""
    out = group.run_dir
    kept = discard_if_nothing_kept(group, created)
    if not any(kept):
        say("interrupted before the first epoch ended; nothing kept")
    elif len(set(kept)) == 1:
        say(
            f"interrupted after epoch {kept[0]} (run {out} holds its checkpoint); continue "
            "with --resume"
        )
    else:
        each = ", ".join(
            f"{h:g} s model after epoch {n}" for h, n in zip(group.horizons_s, kept, strict=True)
        )
        say(f"interrupted ({each}; run {out} holds their checkpoints); continue with --resume")
    return typer.Exit(130)


def say(message: str) -> None:
    print_line(message)


# Why a model stopped (FitResult.stopped_because), as the summary says it.
STOPPED_WORDS = {
    "epochs": "the epochs asked",
    "early stopping": "stopped early: --patience epochs without a better validation loss",
    "time limit": "--max-minutes ran out",
}


def print_results(results: tuple[FitResult, ...], out: Path) -> None:
    """The model's size, a line per model; with several, one more for the run."""
    stdout.print(f"AiGem: {results[0].parameters:,} parameters (the paper: 74.5 K)")
    several = len(results) > 1
    for result in results:
        who = f"{result.horizon_s:g} s model: " if several else ""
        speed = "" if several else f"{result.train_graphs_per_s:,.1f} graphs/s in training. "
        stdout.print(
            f"{who}{counted(result.epochs_done, 'epoch')} on {result.device} "
            f"({STOPPED_WORDS[result.stopped_because]}); best "
            f"epoch {result.best_epoch}, validation MSE {result.best_val_loss_m2:.3f} m²; "
            f"{speed}Run: {result.run_dir}"
        )
    if several:
        stdout.print(
            f"{len(results)} models trained together at {results[0].train_graphs_per_s:,.1f} "
            f"graphs/s (each graph through every model still training). Run: {out}; "
            f"`aigem evaluate {out}` scores them as the paper reports."
        )


def running_losses(losses: tuple[float, ...]) -> str:
    """The progress's detail: each model's running training loss of the epoch ("-" for a model
    not training in it), or nothing before the epoch's first is read."""
    if all(math.isnan(loss) for loss in losses):
        return ""
    shown = " | ".join("-" if math.isnan(loss) else f"{loss:.3f}" for loss in losses)
    return f"loss {shown} m²"


def print_epoch(row: EpochRow, who: str = "") -> None:
    """One line per epoch on stderr (after its time in a log: progress_line), so that a log of
    a long run shows its course; `who`: the model's words before it ("1 s model, ")."""
    best = " (best)" if row.best_epoch == row.epoch else ""
    progress_line(
        f"{who}epoch {row.epoch}: train MSE {row.train_loss_m2:.3f} m², validation MSE "
        f"{row.val_loss_m2:.3f} m²{best}; {row.train_seconds:.0f} s training at "
        f"{row.train_graphs_per_s:,.0f} graphs/s, {row.val_seconds:.0f} s validation"
    )
