"""What a run's records say of its training: how many of its epochs it trained, why it stopped,
and, where it stopped before its end, the command that continues it. Every table, JSON document
and figure of a run says it (aigem.evaluation.evaluate, cli/evaluation_view.py, aigem.figures.plots), so that an
unfinished run is never scored as if it were final.

It is read from run.json (the epochs and the patience asked for, the settings that a resume must
repeat) and metrics.jsonl (the epochs logged): no checkpoint is loaded, and a run of aigem 0.1.0
reads too. A run stopped before its last epoch, without early stopping, is unfinished: Ctrl-C,
a kill or --max-minutes (the records do not tell these apart; `--resume` continues each).
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig, TrainConfig, fit_option
from aigem.runs.records import Group, read_record
from aigem.runs.refusals import RESUME_FIXED
from aigem.runs.run_log import EpochRow, read_metrics

EPOCHS, EARLY_STOPPING, UNFINISHED = "epochs", "early stopping", "unfinished"


def stop_reason(
    epochs_done: int, epochs: int, rows: Sequence[EpochRow], patience: int | None
) -> str:
    """Why a model trains no more after `epochs_done` of `epochs`, from its metrics rows (those
    of its kept epochs): EPOCHS (all trained), EARLY_STOPPING (`patience` epochs without a better
    validation loss), else UNFINISHED (stopped before its end: it continues with --resume)."""
    if epochs_done >= epochs:
        return EPOCHS
    waited = rows[-1].epoch - rows[-1].best_epoch if rows else 0
    if patience is not None and rows and waited >= patience:
        return EARLY_STOPPING
    return UNFINISHED


@dataclass(frozen=True)
class Course:
    """A model's training as its run records it (epochs counted from 1)."""

    epochs_done: int
    epochs: int  # asked for (run.json's, the latest call's)
    best_epoch: int | None
    stopped: str  # EPOCHS, EARLY_STOPPING or UNFINISHED

    @property
    def finished(self) -> bool:
        return self.stopped != UNFINISHED

    def words(self) -> str:
        """'trained 1 of 3 epochs', with ', stopped early' where the patience ended it."""
        early = (
            ", stopped early (no better validation loss)" if self.stopped == EARLY_STOPPING else ""
        )
        noun = "epoch" if self.epochs == 1 else "epochs"
        return f"trained {self.epochs_done} of {self.epochs} {noun}{early}"


def course_of(run_dir: Path) -> Course:
    """The course of the model in `run_dir` (a run of one model, or a member of a group)."""
    train = read_record(run_dir).info.train
    rows = read_metrics(run_dir)
    done = rows[-1].epoch if rows else 0
    best = rows[-1].best_epoch if rows else None
    stopped = stop_reason(done, train.epochs, rows, train.patience_epochs)
    return Course(done, train.epochs, best, stopped)


def resume_command(group: Group) -> str:
    """The `aigem fit` command that continues the run `group` (its first member's run.json is
    read): its build, its horizons where they are not fit's default, each setting that a resume
    must repeat (the model's, and the train settings of refusals.RESUME_FIXED) where it is not
    its default, by the option that sets it (config.fit_option: a setting no option sets, made
    from Python, cannot be said), and its epochs."""
    info = read_record(group.members[0]).info
    words = ["aigem", "fit", str(info.build.build_dir), "--out", str(group.run_dir.resolve())]
    if group.horizons_s != (TrainConfig().horizon_s,):
        words += ["--horizon-s", ",".join(f"{h:g}" for h in group.horizons_s)]
    repeated = [(info.train, name) for name in RESUME_FIXED if name != "horizon_s"]
    for config, name in [*repeated, *((info.model, f.name) for f in fields(ModelConfig))]:
        value = getattr(config, name)
        if value != getattr(type(config)(), name):
            words += fit_option(name, value)
    words += [*fit_option("epochs", info.train.epochs), "--resume"]
    return shlex.join(words)


def training_record(courses: dict[str, Course], group: Group) -> dict[str, Any]:
    """What an evaluation says of its models' training (`courses` by model: by member folder):
    every course, whether all finished, one line that says it, and the command that continues
    the run `group` where one did not finish."""
    finished = all(course.finished for course in courses.values())
    alike = len({(c.epochs_done, c.epochs, c.stopped) for c in courses.values()}) == 1
    if alike:
        summary = next(iter(courses.values())).words()
    else:
        summary = "; ".join(f"{name} {course.words()}" for name, course in courses.items())
    command = None if finished else resume_command(group)
    return {
        "finished": finished,
        "summary": summary,
        "resume_command": command,
        "models": {name: asdict(course) for name, course in courses.items()},
    }


def training_words(training: dict[str, Any] | None) -> str:
    """What a table's or a figure's title says: 'AiGem trained 1 of 3 epochs', with
    ' (UNFINISHED)' where the run stopped before its end."""
    if training is None:
        return "AiGem's training not recorded"
    return f"AiGem {training['summary']}" + ("" if training["finished"] else " (UNFINISHED)")


def training_line(training: dict[str, Any] | None) -> str:
    """training_words, and where the run is unfinished how to continue it: '...; continue with
    `aigem fit ... --resume`'."""
    words = training_words(training)
    if training is None or training["finished"]:
        return words
    return f"{words}; continue with `{training['resume_command']}`"
