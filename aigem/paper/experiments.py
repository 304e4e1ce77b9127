"""`aigem paper`: the paper's experimental section in one call, into one folder.

    DIR/paper.json            written first: the folder is ours, and the settings of its work
    DIR/builds/dmin-{0,25,50}m   the three builds (BuildConfig's defaults but d_min_m)
    DIR/runs/dmin-25m         the paper's model: one per horizon, 1..5 s (fit_horizons)
    DIR/runs/dmin-25m-no-concat  the concatenation ablation (ModelConfig.concat_position False)
    DIR/runs/dmin-0m, DIR/runs/dmin-50m   the d_min ablation
    DIR/runs/FIT-seedS        with --seeds N: each fit again at seed S, paper.json's seed + 1
                              .. + N - 1 (the first seed's runs are those above: run_name)
    DIR/figures/*.png, DIR/report.md, DIR/report.json   written last (aigem.paper.report); report.json
                              last of all: its presence says the call finished

`--only` selects the parts of the report (PARTS) and so the builds and fits they need (NEEDS);
`--seeds` how many times each fit is trained, each time its own run (aigem.paper.plan). What
does not depend on the seed is shared: each build is made once for all seeds, and constant
velocity is reported once per fit (the first seed's evaluation's).

A second call with the same settings continues: a finished build is reused once its config and
inputs (the trajectory files, by name and sha256) are checked, a finished run is reused, an
interrupted one resumes from its last checkpoint (a run killed before its first starts over:
aigem.runs.unfinished), and the evaluations are redone; more --seeds train the new seeds' runs
alone. Other settings against a folder of ours are refused unless `overwrite`: it rebuilds the
builds whose config or inputs differ and discards the runs trained on them, and all runs where
the training settings make other models (more epochs continue them: folder.retrains); a
folder that is not ours and not empty is refused (aigem.paper.folder). Every check is made
before the folder is touched: a refused call leaves it, an earlier report included, as it was.

`max_hours` bounds the training (aigem.paper.training). A report with a run left unfinished
says so (its "finished" is false); a run without a whole epoch cannot be evaluated: no report
(TimeLimitError). The report is aigem.paper.report's.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aigem.paper.folder import (
    HORIZONS_S,
    PaperConfig,
    build_config,
    build_state,
    check_folder,
    claim_folder,
    discard_run,
    epochs_left,
    fit_record,
    paper_document,
    partly_synthetic,
    runs_of,
)
from aigem.paper.plan import (
    FITS,
    PAPER_FIT,
    PaperCall,
    SeedRun,
    plan_builds,
    plan_fits,
    plan_runs,
    plan_seeds,
)
from aigem.paper.training import (
    EVALUATION_BATCH,
    FitEpochCallback,
    Meter,
    Progress,
    batches,
    check_reportable,
    train_runs,
    work_units,
)
from aigem.paper_layout import BUILDS, RUNS, build_name
from aigem.runs.records import member_dir
from aigem.runs.run_log import EpochRow, read_metrics
from ngsim_graphs.errors import NgsimOutputError


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
    a stale one, every seed's (they start over). The raw files are read and cleaned once for all
    of them; every seed's runs train on the same builds."""
    from ngsim_graphs.pipeline import run_builds

    for name in runs_of(out, [fit.name for fit in FITS if fit.d_min_m in plan.stale]):
        discard_run(out / RUNS / name)
    todo = sorted(plan.missing + plan.stale)
    if todo:
        (out / BUILDS).mkdir(exist_ok=True)
        show(f"builds: {len(todo)} of {len(plan.dirs)} to make", 0, 0)
        building = lambda what, done, total: show(f"builds: {what}", done, total)
        targets = [(plan.dirs[d], build_config(d)) for d in todo]
        run_builds(raw_paths, targets, bool(plan.stale), building, jobs=call.jobs)


def _evaluate(run: SeedRun, out: Path, device: str, meter: Meter) -> Any:
    """The run's models on the test split, as the paper reports them (evaluate)."""
    from aigem.evaluation.evaluate import evaluate

    run_dir, build_dir = out / RUNS / run.name, out / BUILDS / run.plan.build_name
    units = batches(build_dir, "test", EVALUATION_BATCH)  # the pass's share of the bar
    progress = lambda done, total: meter.at(f"evaluating {run.describe()}", done * units // total)
    result = evaluate(run_dir, None, "test", device, EVALUATION_BATCH, progress)
    meter.advance(units)
    return result


def run_paper(
    raw_paths: Sequence[Path],
    out: Path,
    config: PaperConfig,
    call: PaperCall,
    progress: Progress | None = None,
    on_epoch: FitEpochCallback | None = None,
) -> PaperResult:
    """The paper's experiments into `out` (see the module's docstring); returns the report,
    whose "finished" is false where --max-hours left a fit unfinished. `progress` follows the
    stages (the builds' among them), `on_epoch` gets each model's losses at each epoch's end. Raises TimeLimitError
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
        return _run(raw_paths, out, document, config, call, show, start, on_epoch)


def _run(
    raw_paths: Sequence[Path],
    out: Path,
    document: dict[str, Any],
    config: PaperConfig,
    call: PaperCall,
    show: Progress,
    start: float,
    on_epoch: FitEpochCallback | None,
) -> PaperResult:
    """run_paper's work, `out` locked: every check (claim_folder's again, another call may have
    come before) before the folder is touched."""
    from aigem.paper.report import write_report
    from aigem.paper.report_plots import report_figures

    timings: dict[str, float] = {}
    builds = _plan_builds(out, document["inputs"], call)
    claim_folder(out, document, call.overwrite, runs_of(out, [plan.name for plan in FITS]))
    _builds(list(raw_paths), out, builds, call, show)
    timings["builds"] = time.monotonic() - start
    runs = plan_runs(config, call)
    to_train = [run for run in runs if epochs_left(out / RUNS / run.name, config)]
    meter = Meter(show, work_units(out, runs, to_train, config))
    timings |= train_runs(out, to_train, config, call, meter, on_epoch)
    unfinished = [run for run in runs if epochs_left(out / RUNS / run.name, config)]
    check_reportable(out, unfinished, config)
    evaluations: dict[str, list[Any]] = {}  # by fit, in the seeds' order (runs are seed by seed)
    with _threads(call.threads):
        for run in runs:
            began = time.monotonic()
            evaluations.setdefault(run.plan.name, []).append(
                _evaluate(run, out, call.device, meter)
            )
            timings[f"evaluate {run.name}"] = time.monotonic() - began
    began = time.monotonic()
    show("writing the report", meter.total, meter.total)
    report = _report(out, document, config, call, runs, evaluations, unfinished)
    timings["report"] = time.monotonic() - began
    timings["total"] = time.monotonic() - start
    timings = {k: round(v, 1) for k, v in timings.items()}
    report = write_report(out, report, report_figures(report), timings)
    return PaperResult(out, report, timings)


def _report(
    out: Path,
    document: dict[str, Any],
    config: PaperConfig,
    call: PaperCall,
    runs: Sequence[SeedRun],
    evaluations: dict[str, list[Any]],
    unfinished: Sequence[SeedRun],
) -> dict[str, Any]:
    """report.json's numbers (aigem.paper.report.paper_report) from the runs' records and their
    evaluations, every list in the seeds' order."""
    from aigem.paper.report import paper_report

    fits = {
        plan.name: {
            "d_min_m": plan.d_min_m,
            "concat_position": plan.concat_position,
            "runs": [
                {
                    "seed": run.seed,
                    "run": run.name,
                    "models": fit_record(out / RUNS / run.name, config),
                }
                for run in runs
                if run.plan == plan
            ],
        }
        for plan in plan_fits(call.parts)
    }
    curves = [_curves(out / RUNS / run.name) for run in runs if run.plan.name == PAPER_FIT]
    return paper_report(
        document,
        call.parts,
        plan_seeds(config, call),
        fits,
        evaluations,
        curves,
        [run.name for run in unfinished],
        partly_synthetic([out / BUILDS / build_name(d) for d in plan_builds(call.parts)]),
    )


def _curves(run_dir: Path) -> dict[str, list[EpochRow]]:
    """Each member's metrics rows (its kept epochs), by member name."""
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
