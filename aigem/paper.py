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
inputs are checked, a finished fit is reused, an interrupted one resumes from its last
checkpoint (a fit killed before its first starts over: aigem.unfinished), and the evaluations
are redone. Other settings against a folder of ours are refused unless `overwrite`, which
discards the runs (and the builds whose config or inputs differ); a folder that is not ours and
not empty is refused (aigem.paper_folder). The report is aigem.report's.
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
    RUNS,
    PaperConfig,
    build_config,
    build_name,
    build_state,
    claim_folder,
    discard_run,
    epochs_left,
    fit_record,
    paper_document,
)
from aigem.records import LAST, member_dir, read_horizons
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError

PARTS = ("table", "dmin", "concat", "curves", "regions")
PAPER_FIT = "dmin-25m"  # the paper's model: d_min 25 m, the output concatenation


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
    FitPlan(PAPER_FIT, 25.0),
    FitPlan("dmin-25m-no-concat", 25.0, concat_position=False),
    FitPlan("dmin-0m", 0.0),
    FitPlan("dmin-50m", 50.0),
)
NEEDS = {  # the fits each part of the report reads
    "table": (PAPER_FIT,),
    "dmin": ("dmin-0m", PAPER_FIT, "dmin-50m"),
    "concat": (PAPER_FIT, "dmin-25m-no-concat"),
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
    max_hours: float | None = None  # for the whole call; each fit gets its share of what is left
    jobs: int = 1  # the builds' worker processes
    overwrite: bool = False


# (stage's words, done, total): one display for the whole call.
Progress = Callable[[str, int, int], None]


@dataclass
class PaperResult:
    out: Path
    report: dict[str, Any]
    timings_s: dict[str, float] = field(default_factory=dict)


def _builds(
    raw_paths: list[Path], out: Path, inputs: list[dict[str, Any]], call: PaperCall, show: Progress
) -> dict[float, Path]:
    """The builds the parts need: each reused where finished and of the right config and
    inputs, else built (one with another config or inputs only with --overwrite, which
    discards the runs trained on it). The raw files are read and cleaned once for all of them."""
    from ngsim_graphs.pipeline import run_builds

    targets, replace_them = [], False
    builds = {d: out / BUILDS / build_name(d) for d in plan_builds(call.parts)}
    for d_min_m, build_dir in builds.items():
        state = build_state(build_dir, build_config(d_min_m), inputs)
        if state == "":
            continue
        if state is not None and not call.overwrite:
            raise NgsimOutputError(build_dir, f"{state}; add --overwrite to rebuild it")
        if state is not None:  # rebuilt: the runs trained on it start over
            replace_them = True
            for plan in FITS:
                if plan.d_min_m == d_min_m:
                    discard_run(out / RUNS / plan.name)
        targets.append((build_dir, build_config(d_min_m)))
    if targets:
        (out / BUILDS).mkdir(exist_ok=True)
        show(f"building {len(targets)} of {len(builds)} builds", 0, 0)
        building = lambda what, done, total: show(f"building {what}", done, total)
        run_builds(list(raw_paths), targets, replace_them, building, jobs=call.jobs)
    return builds


class _Meter:
    """One bar over the fits and the evaluations still to run: a training batch counts
    TRAIN_UNITS (it steps five models), an evaluation batch of one model one."""

    TRAIN_UNITS = 4

    def __init__(self, show: Progress, total: int) -> None:
        self.show, self.total, self.offset = show, max(total, 1), 0

    def at(self, what: str, done: int) -> None:
        self.show(what, min(self.offset + done, self.total), self.total)

    def advance(self, units: int) -> None:
        self.offset += units


def _train_config(config: PaperConfig, call: PaperCall, max_minutes: float | None):  # noqa: ANN202
    from aigem.config import TrainConfig

    return TrainConfig(
        epochs=config.epochs,
        batch_size=config.batch_size,
        patience_epochs=config.patience_epochs,
        seed=config.seed,
        threads=call.threads,
        max_minutes=max_minutes,
    )


def _batches(build_dir: Path, split: str, batch_size: int) -> int:
    from ngsim_graphs.build import open_build

    return math.ceil(open_build(build_dir).manifest.splits.get(split, 0) / batch_size)


def _fit(
    plan: FitPlan,
    out: Path,
    config: PaperConfig,
    train: Any,
    device: str,
    meter: _Meter,
) -> None:
    """One five-horizon fit: resumed where a model kept a checkpoint, else started (over)."""
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

    (out / RUNS).mkdir(exist_ok=True)
    model = ModelConfig(concat_position=plan.concat_position)
    fit_horizons(build_dir, run_dir, HORIZONS_S, model, train, device, resume, progress)
    meter.advance(_Meter.TRAIN_UNITS * left * batches)


def _evaluate(plan: FitPlan, out: Path, device: str, meter: _Meter) -> Any:
    """The fit's models on the test split, as the paper reports them (evaluate_horizons)."""
    from aigem.evaluation import evaluate_horizons

    calls = [0]

    def progress(_done: int, _total: int) -> None:
        calls[0] += 1
        meter.at(f"evaluating {plan.describe()}", calls[0])

    result = evaluate_horizons(out / RUNS / plan.name, None, "test", device, progress=progress)
    meter.advance(calls[0])
    return result


def run_paper(
    raw_paths: Sequence[Path],
    out: Path,
    config: PaperConfig,
    call: PaperCall,
    progress: Progress | None = None,
) -> PaperResult:
    """The paper's experiments into `out` (see the module's docstring); returns the report."""
    from aigem.report import paper_report, write_report
    from ngsim_graphs.landing import check_outside_inputs

    show = progress or (lambda _what, _done, _total: None)
    start = time.monotonic()
    deadline = start + 3600 * call.max_hours if call.max_hours is not None else math.inf
    timings: dict[str, float] = {}
    check_outside_inputs(out, list(raw_paths))
    document = paper_document(raw_paths, config)
    claim_folder(out, document, call.overwrite)
    _builds(list(raw_paths), out, document["inputs"], call, show)
    timings["builds"] = time.monotonic() - start
    fits = plan_fits(call.parts)
    to_train = [plan for plan in fits if epochs_left(out / RUNS / plan.name, config)]
    meter = _Meter(show, _work_units(out, fits, to_train, config))
    for index, plan in enumerate(to_train):
        began = time.monotonic()
        max_minutes = fit_minutes(deadline - began, len(to_train) - index)
        _fit(plan, out, config, _train_config(config, call, max_minutes), call.device, meter)
        timings[f"fit {plan.name}"] = time.monotonic() - began
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
    )
    timings["report"] = time.monotonic() - began
    timings["total"] = time.monotonic() - start
    report = write_report(out, report, {k: round(v, 1) for k, v in timings.items()})
    return PaperResult(out, report, timings)


def fit_minutes(left_s: float, fits_left: int) -> float | None:
    """A fit's time limit (TrainConfig.max_minutes): its equal share of the time left to the
    fits still to train, at least a second (a model to evaluate: one step, then validation);
    None without a limit (left_s infinite)."""
    if math.isinf(left_s):
        return None
    return max(left_s / 60 / fits_left, 1 / 60)


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
        units += len(HORIZONS_S) * _batches(build_dir, "test", 64)  # evaluate's batch size
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
