"""`aigem paper`: the paper's experimental section in one call, into one folder.

    DIR/paper.json            written first: the folder is ours, and the settings of its work
    DIR/builds/dmin-{0,25,50}m   the three builds (BuildConfig's defaults but d_min_m)
    DIR/runs/dmin-25m         the paper's model: one per horizon, 1..5 s (fit_horizons)
    DIR/runs/dmin-25m-no-concat  the concatenation ablation (ModelConfig.concat_position False)
    DIR/runs/dmin-0m, DIR/runs/dmin-50m   the d_min ablation
    DIR/figures/*.png, DIR/report.md, DIR/report.json   written last (aigem.report); report.json
                              last of all: its presence says the call finished

`--only` selects the parts of the report (PARTS) and so the builds and fits they need (NEEDS).
A second call with the same settings continues: a finished build is reused once its config and
inputs (the trajectory files, by name and sha256) are checked, a finished fit is reused, an
interrupted one resumes from its last checkpoint (a fit killed before its first starts over:
aigem.unfinished), and the evaluations are redone. Other settings against a folder of ours are
refused unless `overwrite`: it rebuilds the builds whose config or inputs differ and discards
the runs trained on them, and all runs where the training settings make other models (more
epochs continue them: paper_folder.retrains); a folder that is not ours and not empty is
refused (aigem.paper_folder). Every check is made before the folder is touched: a refused call
leaves it, an earlier report included, as it was.

`max_hours` bounds the training (the builds and the evaluations come on top): each fit still to
train gets an equal share of the time left, and stops at the first batch past it, keeping its
models' last whole epochs, so that the next call redoes the epoch cut and ends with the models
of a call without a limit. A report with a fit left unfinished says so (its "finished" is
false); a fit without a whole epoch cannot be evaluated: no report (TimeLimitError). The report
is aigem.report's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig
from aigem.paper_folder import (
    BUILDS,
    HORIZONS_S,
    PAPER_D_MIN_M,
    RUNS,
    PaperConfig,
    build_config,
    build_name,
    build_state,
    check_folder,
    claim_folder,
    discard_run,
    epochs_left,
    fit_record,
    paper_document,
    partly_synthetic,
)
from aigem.records import LAST, member_dir, planned_group, read_horizons
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError

PARTS = ("table", "dmin", "concat", "curves", "regions")
EVALUATION_BATCH = 64  # the batch size of _evaluate on the loader, its units in _work_units
PAPER_FIT = build_name(PAPER_D_MIN_M)  # the paper's model: d_min 25 m, the output concatenation


@dataclass(frozen=True)
class FitPlan:
    """One five-horizon fit of the paper's section: its run's name, its build's d_min, and
    whether the output MLP sees the previous position."""

    name: str
    d_min_m: float
    concat_position: bool = True

    @property
    def build_name(self) -> str:
        return build_name(self.d_min_m)

    def describe(self) -> str:
        without = " without concatenation" if not self.concat_position else ""
        return f"d_min {self.d_min_m:g} m{without}"


FITS = (
    FitPlan(PAPER_FIT, PAPER_D_MIN_M),
    FitPlan(f"{PAPER_FIT}-no-concat", PAPER_D_MIN_M, concat_position=False),
    FitPlan("dmin-0m", 0.0),
    FitPlan("dmin-50m", 50.0),
)
NEEDS = {  # the fits each part of the report reads
    "table": (PAPER_FIT,),
    "dmin": ("dmin-0m", PAPER_FIT, "dmin-50m"),
    "concat": (PAPER_FIT, f"{PAPER_FIT}-no-concat"),
    "curves": (PAPER_FIT,),
    "regions": (PAPER_FIT,),
}


def parse_parts(text: str) -> tuple[str, ...]:
    """'table,dmin' -> ('table', 'dmin'), in PARTS' order; ValueError in one line."""
    given = [part.strip().lower() for part in text.split(",") if part.strip()]
    unknown = [part for part in given if part not in PARTS]
    if unknown or not given:
        what = f"{', '.join(unknown)}: not " if unknown else "none given; "
        raise ValueError(f"{what}a part of the report ({', '.join(PARTS)})")
    return tuple(part for part in PARTS if part in given)


def plan_fits(parts: Sequence[str]) -> tuple[FitPlan, ...]:
    """The fits that `parts` need, in FITS' order (the paper's model first)."""
    names = {name for part in parts for name in NEEDS[part]}
    return tuple(plan for plan in FITS if plan.name in names)


def plan_builds(parts: Sequence[str]) -> tuple[float, ...]:
    """The d_min (m) of each build that `parts` need, ascending."""
    return tuple(sorted({plan.d_min_m for plan in plan_fits(parts)}))


@dataclass(frozen=True)
class PaperCall:
    """How this call runs the work; none of it is compared with an earlier call's."""

    parts: tuple[str, ...] = PARTS
    device: str = "auto"
    threads: int | None = None  # the model step's CPU threads (a number: bit-reproducible)
    max_hours: float | None = None  # for the training; each fit gets its share of what is left
    jobs: int = 1  # the builds' worker processes
    overwrite: bool = False


# (stage's words, done, total): one display for the whole call.
Progress = Callable[[str, int, int], None]


@dataclass
class PaperResult:
    out: Path
    report: dict[str, Any]
    timings_s: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _BuildPlan:
    """The builds the parts need (by d_min), and of them those missing and those to replace."""

    dirs: dict[float, Path]
    missing: tuple[float, ...]
    stale: tuple[float, ...]  # of another config or other inputs: rebuilt with --overwrite


def _plan_builds(out: Path, inputs: list[dict[str, Any]], call: PaperCall) -> _BuildPlan:
    """Which builds to reuse, build and rebuild (build_state); refuses a build of another config
    or other inputs without --overwrite, naming it. Writes nothing."""
    dirs = {d: out / BUILDS / build_name(d) for d in plan_builds(call.parts)}
    missing, stale = [], []
    for d_min_m, build_dir in dirs.items():
        state = build_state(build_dir, build_config(d_min_m), inputs)
        if state and not call.overwrite:
            raise NgsimOutputError(build_dir, f"{state}; add --overwrite to rebuild it")
        if state is None:
            missing.append(d_min_m)
        elif state:
            stale.append(d_min_m)
    return _BuildPlan(dirs, tuple(missing), tuple(stale))


def _builds(
    raw_paths: list[Path], out: Path, plan: _BuildPlan, call: PaperCall, show: Progress
) -> None:
    """Build the missing builds and rebuild the stale ones, discarding first the runs trained on
    a stale one (they start over). The raw files are read and cleaned once for all of them."""
    from ngsim_graphs.pipeline import run_builds

    for fit in FITS:
        if fit.d_min_m in plan.stale:
            discard_run(out / RUNS / fit.name)
    todo = sorted(plan.missing + plan.stale)
    if todo:
        (out / BUILDS).mkdir(exist_ok=True)
        show(f"building {len(todo)} of {len(plan.dirs)} builds", 0, 0)
        building = lambda what, done, total: show(f"building {what}", done, total)
        targets = [(plan.dirs[d], build_config(d)) for d in todo]
        run_builds(raw_paths, targets, bool(plan.stale), building, jobs=call.jobs)


class _Meter:
    """One bar over the fits and the evaluations still to run: a training batch counts
    TRAIN_UNITS (it steps five models), an evaluation batch one (it runs a fit's five models in
    one pass: aigem.scoring.score_members)."""

    TRAIN_UNITS = 4

    def __init__(self, show: Progress, total: int) -> None:
        self.show, self.total, self.offset = show, max(total, 1), 0

    def at(self, what: str, done: int) -> None:
        self.show(what, min(self.offset + done, self.total), self.total)

    def advance(self, units: int) -> None:
        self.offset += units


def _train_config(config: PaperConfig, call: PaperCall):  # noqa: ANN202
    """The fits' TrainConfig: no max_minutes (a time limit of its own would checkpoint the epoch
    it cuts as a whole one); _fit ends a fit at its share of --max-hours."""
    from aigem.config import TrainConfig

    return TrainConfig(
        epochs=config.epochs,
        batch_size=config.batch_size,
        patience_epochs=config.patience_epochs,
        seed=config.seed,
        threads=call.threads,
    )


def _batches(build_dir: Path, split: str, batch_size: int) -> int:
    from ngsim_graphs.build import open_build

    return math.ceil(open_build(build_dir).manifest.splits.get(split, 0) / batch_size)


class _TimeUp(Exception):
    """A fit's share of --max-hours has passed: raised by its progress callback, it ends the fit
    as Ctrl-C does, its models keeping their last whole epoch."""


def _fit(
    plan: FitPlan,
    out: Path,
    config: PaperConfig,
    train: Any,
    device: str,
    meter: _Meter,
    deadline: float,
) -> None:
    """One five-horizon fit: resumed where a model kept a checkpoint, else started (over). Past
    `deadline` (time.monotonic()) it stops at the next batch: each model keeps the checkpoint of
    its last whole epoch (the next call redoes the epoch cut: the same models as without a limit),
    and a fit that kept none takes its files away (runs.discard_unfinished), as `aigem fit` does."""
    from aigem.runs import discard_unfinished
    from aigem.training import fit_horizons

    run_dir, build_dir = out / RUNS / plan.name, out / BUILDS / plan.build_name
    left = epochs_left(run_dir, config)
    first, batches = config.epochs - left, _batches(build_dir, "train", config.batch_size)
    resume = any((member_dir(run_dir, h) / LAST).is_file() for h in HORIZONS_S)
    if resume and read_horizons(run_dir) != HORIZONS_S:
        raise NgsimInputError(run_dir, "is not a run of the horizons 1..5 s; --overwrite")
    words = f"fit {plan.describe()}"

    def progress(epoch: int, done: int, total: int, _losses: tuple[float, ...]) -> None:
        meter.at(
            f"{words}, epoch {epoch}/{config.epochs}",
            _Meter.TRAIN_UNITS * ((epoch - 1 - first) * total + done),
        )
        if time.monotonic() > deadline:
            raise _TimeUp

    (out / RUNS).mkdir(exist_ok=True)
    created = not run_dir.exists()
    model = ModelConfig(concat_position=plan.concat_position)
    try:
        fit_horizons(build_dir, run_dir, HORIZONS_S, model, train, device, resume, progress)
    except _TimeUp:
        if not any(_epochs_done(run_dir, config)):
            discard_unfinished(planned_group(run_dir, HORIZONS_S), created)
        return
    meter.advance(_Meter.TRAIN_UNITS * left * batches)


def _epochs_done(run_dir: Path, config: PaperConfig) -> list[int]:
    """Each model's epochs kept (its last checkpoint's), 0 for a model with none."""
    return [model["epochs_done"] for model in fit_record(run_dir, config).values()]


def _evaluate(plan: FitPlan, out: Path, device: str, meter: _Meter) -> Any:
    """The fit's models on the test split, as the paper reports them (evaluate)."""
    from aigem.evaluation import evaluate

    run_dir, build_dir = out / RUNS / plan.name, out / BUILDS / plan.build_name
    units = _batches(build_dir, "test", EVALUATION_BATCH)  # the pass's share of the bar
    progress = lambda done, total: meter.at(f"evaluating {plan.describe()}", done * units // total)
    result = evaluate(run_dir, None, "test", device, EVALUATION_BATCH, progress)
    meter.advance(units)
    return result


class TimeLimitError(RuntimeError):
    """--max-hours ended the training before a fit the report needs kept an epoch: no report."""


def run_paper(
    raw_paths: Sequence[Path],
    out: Path,
    config: PaperConfig,
    call: PaperCall,
    progress: Progress | None = None,
) -> PaperResult:
    """The paper's experiments into `out` (see the module's docstring); returns the report,
    whose "finished" is false where --max-hours left a fit unfinished. Raises TimeLimitError
    where it left a fit without a whole epoch (nothing to report). A second call into the same
    `out` at once is refused (ngsim_graphs.lock, `.OUT.lock` beside it)."""
    from ngsim_graphs.landing import check_outside_inputs
    from ngsim_graphs.lock import output_lock

    start = time.monotonic()
    check_outside_inputs(out, list(raw_paths))
    document = paper_document(raw_paths, config)
    check_folder(out, document, call.overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)  # where the lock is
    with output_lock(out.resolve()):  # resolved: `--out .` has a name
        show = progress or (lambda _what, _done, _total: None)
        return _run(raw_paths, out, document, config, call, show, start)


def _run(
    raw_paths: Sequence[Path],
    out: Path,
    document: dict[str, Any],
    config: PaperConfig,
    call: PaperCall,
    show: Progress,
    start: float,
) -> PaperResult:
    """run_paper's work, `out` locked: every check (claim_folder's again, another call may have
    come before) before the folder is touched."""
    from aigem.report import paper_report, write_report
    from aigem.report_plots import report_figures

    timings: dict[str, float] = {}
    builds = _plan_builds(out, document["inputs"], call)
    claim_folder(out, document, call.overwrite, [plan.name for plan in FITS])
    _builds(list(raw_paths), out, builds, call, show)
    timings["builds"] = time.monotonic() - start
    fits = plan_fits(call.parts)
    to_train = [plan for plan in fits if epochs_left(out / RUNS / plan.name, config)]
    meter = _Meter(show, _work_units(out, fits, to_train, config))
    timings |= _train(out, to_train, config, call, meter)
    unfinished = [plan for plan in fits if epochs_left(out / RUNS / plan.name, config)]
    _check_reportable(out, unfinished, config)
    evaluations = {}
    with _threads(call.threads):
        for plan in fits:
            began = time.monotonic()
            evaluations[plan.name] = _evaluate(plan, out, call.device, meter)
            timings[f"evaluate {plan.name}"] = time.monotonic() - began
    began = time.monotonic()
    show("writing the report", meter.total, meter.total)
    report = paper_report(
        document,
        call.parts,
        {
            plan.name: {
                "d_min_m": plan.d_min_m,
                "concat_position": plan.concat_position,
                "models": fit_record(out / RUNS / plan.name, config),
            }
            for plan in fits
        },
        evaluations,
        _curves(out / RUNS / PAPER_FIT) if PAPER_FIT in evaluations else {},
        [plan.name for plan in unfinished],
        partly_synthetic([out / BUILDS / plan.build_name for plan in fits]),
    )
    timings["report"] = time.monotonic() - began
    timings["total"] = time.monotonic() - start
    timings = {k: round(v, 1) for k, v in timings.items()}
    report = write_report(out, report, report_figures(report), timings)
    return PaperResult(out, report, timings)


def _train(
    out: Path, to_train: Sequence[FitPlan], config: PaperConfig, call: PaperCall, meter: _Meter
) -> dict[str, float]:
    """The fits still to train, one after the other, each until its share of --max-hours
    (counted from here: the builds and the evaluations come on top); a fit that finds no time
    left does not start. Returns the time each took."""
    timings = {}
    deadline = time.monotonic() + (
        3600 * call.max_hours if call.max_hours is not None else math.inf
    )
    train = _train_config(config, call)
    for index, plan in enumerate(to_train):
        began = time.monotonic()
        share_s = fit_share_s(deadline - began, len(to_train) - index)
        if share_s > 0:
            _fit(plan, out, config, train, call.device, meter, began + share_s)
            timings[f"fit {plan.name}"] = time.monotonic() - began
    return timings


def fit_share_s(left_s: float, fits_left: int) -> float:
    """A fit's time (s): its equal share of the time left to the fits still to train (a fit
    that ends sooner leaves its time to those after it); infinite without --max-hours."""
    return left_s / fits_left


def _check_reportable(out: Path, unfinished: Sequence[FitPlan], config: PaperConfig) -> None:
    """Refuse a report where --max-hours left a fit the parts need without a whole epoch."""
    empty = [plan for plan in unfinished if 0 in _epochs_done(out / RUNS / plan.name, config)]
    if empty:
        which = ", ".join(f"{plan.name} ({plan.describe()})" for plan in empty)
        raise TimeLimitError(
            f"--max-hours ended the training before a whole epoch of {which}: no report; run "
            "the same command again to continue (with more time: a fit's epoch that its share "
            "of --max-hours cuts is redone)"
        )


def _work_units(
    out: Path, fits: Sequence[FitPlan], to_train: Sequence[FitPlan], config: PaperConfig
) -> int:
    """The bar's total: the training batches of the fits still to run, the evaluations'."""
    units = 0
    for plan in fits:
        build_dir = out / BUILDS / plan.build_name
        if plan in to_train:
            left = epochs_left(out / RUNS / plan.name, config)
            units += _Meter.TRAIN_UNITS * left * _batches(build_dir, "train", config.batch_size)
        units += _batches(build_dir, "test", EVALUATION_BATCH)  # one pass for the five models
    return units


def _curves(run_dir: Path) -> dict[str, list[dict[str, Any]]]:
    """Each member's metrics rows (its kept epochs), by member name."""
    from aigem.runs import read_metrics

    return {member_dir(run_dir, h).name: read_metrics(member_dir(run_dir, h)) for h in HORIZONS_S}


@contextmanager
def _threads(threads: int | None) -> Iterator[None]:
    """torch's intra-op threads set to `threads` in the block (None: left as they are), so that
    the evaluations of a call that trained and of one that reused its fits compute alike."""
    import torch

    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
