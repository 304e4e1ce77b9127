"""The training of `aigem paper` (aigem.paper.experiments): each run still to train (a fit at one seed:
aigem.paper.plan.SeedRun), resumed where its models kept a checkpoint, within its share of
--max-hours; and the one progress bar over the training and the evaluations (Meter).

`max_hours` bounds the training (the builds and the evaluations come on top): each run still to
train gets an equal share of the time left, and stops at the first batch past it, keeping its
models' last whole epochs, so that the next call redoes the epoch cut and ends with the models
of a call without a limit. A run without a whole epoch cannot be evaluated: no report
(TimeLimitError).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig
from aigem.paper.folder import HORIZONS_S, PaperConfig, epochs_left, fit_record
from aigem.paper.plan import PaperCall, SeedRun
from aigem.paper_layout import BUILDS, RUNS
from aigem.runs.records import LAST, member_dir, planned_group, read_horizons
from ngsim_graphs.errors import NgsimInputError

EVALUATION_BATCH = 64  # the batch size of an evaluation on the loader, its units in work_units

# (stage's words, done, total): one display for the whole call.
Progress = Callable[[str, int, int], None]
# (the fit's words, "fit d_min 25 m", the model's horizon in s, the row of its metrics.jsonl
# written at the end of an epoch): the CLI prints it.
FitEpochCallback = Callable[[str, float, dict[str, float]], None]


class Meter:
    """One bar over the runs and the evaluations still to go: a training batch counts
    TRAIN_UNITS (it steps five models), an evaluation batch one (it runs a fit's five models in
    one pass: aigem.evaluation.scoring.score_members)."""

    TRAIN_UNITS = 4

    def __init__(self, show: Progress, total: int) -> None:
        self.show, self.total, self.offset = show, max(total, 1), 0

    def at(self, what: str, done: int) -> None:
        self.show(what, min(self.offset + done, self.total), self.total)

    def advance(self, units: int) -> None:
        self.offset += units


class TimeLimitError(RuntimeError):
    """--max-hours ended the training before a run the report needs kept an epoch: no report."""


class _TimeUp(Exception):
    """A run's share of --max-hours has passed: raised by its progress callback, it ends the
    fit as Ctrl-C does, its models keeping their last whole epoch."""


def batches(build_dir: Path, split: str, batch_size: int) -> int:
    from ngsim_graphs.build import open_build

    return math.ceil(open_build(build_dir).manifest.splits.get(split, 0) / batch_size)


def _train_config(config: PaperConfig, call: PaperCall):  # noqa: ANN202
    """The fits' TrainConfig (the seed set per run): no max_minutes (a time limit of its own
    would checkpoint the epoch it cuts as a whole one); _fit ends a fit at its share of
    --max-hours."""
    from aigem.config import TrainConfig

    return TrainConfig(
        epochs=config.epochs,
        batch_size=config.batch_size,
        patience_epochs=config.patience_epochs,
        seed=config.seed,
        threads=call.threads,
    )


def _fit(
    run: SeedRun,
    out: Path,
    config: PaperConfig,
    train: Any,
    device: str,
    meter: Meter,
    deadline: float,
    on_epoch: FitEpochCallback | None = None,
) -> None:
    """One five-horizon fit at `run.seed`: resumed where a model kept a checkpoint, else started
    (over); `on_epoch` gets each model's row at the end of each epoch. Past `deadline`
    (time.monotonic()) it stops at the next batch: each model keeps the checkpoint of its last
    whole epoch (the next call redoes the epoch cut: the same models as without a limit), and a
    run that kept none takes its files away (runs.folder.discard_unfinished), as `aigem fit` does."""
    from aigem.runs.folder import discard_unfinished
    from aigem.training.fit import fit_horizons

    run_dir, build_dir = out / RUNS / run.name, out / BUILDS / run.plan.build_name
    left = epochs_left(run_dir, config)
    first, count = config.epochs - left, batches(build_dir, "train", config.batch_size)
    resume = any((member_dir(run_dir, h) / LAST).is_file() for h in HORIZONS_S)
    if resume and read_horizons(run_dir) != HORIZONS_S:
        raise NgsimInputError(run_dir, "is not a run of the horizons 1..5 s; --overwrite")
    words = f"fit {run.describe()}"

    def progress(epoch: int, done: int, total: int, _losses: tuple[float, ...]) -> None:
        meter.at(
            f"{words}, epoch {epoch}/{config.epochs}",
            Meter.TRAIN_UNITS * ((epoch - 1 - first) * total + done),
        )
        if time.monotonic() > deadline:
            raise _TimeUp

    (out / RUNS).mkdir(exist_ok=True)
    created = not run_dir.exists()
    model = ModelConfig(concat_position=run.plan.concat_position)
    train = replace(train, seed=run.seed)
    ended = None if on_epoch is None else partial(on_epoch, words)
    try:
        fit_horizons(build_dir, run_dir, HORIZONS_S, model, train, device, resume, progress, ended)
    except _TimeUp:
        if not any(epochs_done(run_dir, config)):
            discard_unfinished(planned_group(run_dir, HORIZONS_S), created)
        return
    meter.advance(Meter.TRAIN_UNITS * left * count)


def epochs_done(run_dir: Path, config: PaperConfig) -> list[int]:
    """Each model's epochs kept (its last checkpoint's), 0 for a model with none."""
    return [model["epochs_done"] for model in fit_record(run_dir, config).values()]


def train_runs(
    out: Path,
    to_train: Sequence[SeedRun],
    config: PaperConfig,
    call: PaperCall,
    meter: Meter,
    on_epoch: FitEpochCallback | None = None,
) -> dict[str, float]:
    """The runs still to train, one after the other, each until its share of --max-hours
    (counted from here: the builds and the evaluations come on top); a run that finds no time
    left does not start; `on_epoch` gets each model's epochs. Returns the time each took, by
    "fit RUN"."""
    timings = {}
    deadline = time.monotonic() + (
        3600 * call.max_hours if call.max_hours is not None else math.inf
    )
    train = _train_config(config, call)
    for index, run in enumerate(to_train):
        began = time.monotonic()
        share_s = fit_share_s(deadline - began, len(to_train) - index)
        if share_s > 0:
            _fit(run, out, config, train, call.device, meter, began + share_s, on_epoch)
            timings[f"fit {run.name}"] = time.monotonic() - began
    return timings


def fit_share_s(left_s: float, fits_left: int) -> float:
    """A run's time (s): its equal share of the time left to the runs still to train (a run
    that ends sooner leaves its time to those after it); infinite without --max-hours."""
    return left_s / fits_left


def check_reportable(out: Path, unfinished: Sequence[SeedRun], config: PaperConfig) -> None:
    """Refuse a report where --max-hours left a run the parts need without a whole epoch."""
    empty = [run for run in unfinished if 0 in epochs_done(out / RUNS / run.name, config)]
    if empty:
        which = ", ".join(f"{run.name} ({run.describe()})" for run in empty)
        raise TimeLimitError(
            f"--max-hours ended the training before a whole epoch of {which}: no report; run "
            "the same command again to continue (with more time: a fit's epoch that its share "
            "of --max-hours cuts is redone)"
        )


def work_units(
    out: Path, runs: Sequence[SeedRun], to_train: Sequence[SeedRun], config: PaperConfig
) -> int:
    """The bar's total: the training batches of the runs still to train, the evaluations'."""
    units = 0
    for run in runs:
        build_dir = out / BUILDS / run.plan.build_name
        if run in to_train:
            left = epochs_left(out / RUNS / run.name, config)
            units += Meter.TRAIN_UNITS * left * batches(build_dir, "train", config.batch_size)
        units += batches(build_dir, "test", EVALUATION_BATCH)  # one pass for the five models
    return units
