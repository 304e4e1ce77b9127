"""`aigem evaluate`: the best model of a run and the constant-velocity baseline on one split.

Both are scored on the same samples and targets, with the metrics of aigem.metrics (metres). By
default on the run's own build; another build (say, trained on US-101, tested on I-80) only when
asked, and then with the run's scaler: the model only knows its inputs as scaled in training.

A run is a group of one model per horizon (aigem.runs.records.Group; a run of one horizon is a group of
one, the paper's protocol a group of five). Its models are scored in one pass over the split
(aigem.evaluation.scoring.score_members: the split loaded once, the models run as one ensemble, constant
velocity computed once), each model getting the numbers `evaluate` gives its run directory, and
reported as the paper does: RMSE at h s from the model trained for h s (in general: from the
shortest-horizon model that predicts that far), ADE and FDE from the longest-horizon model;
constant velocity likewise, so that each number of the baseline is on the same targets as the
model's beside it. Each number over all actors carries its 95 % bootstrap interval, and so does
its difference to constant velocity (aigem.intervals: whole samples resampled, the same
resamples for both), each taken from the member its number comes from.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aigem.config import horizon_steps
from aigem.devices import pick_device
from aigem.evaluation.results import Evaluation, ModelEvaluation, Rows, Scores
from aigem.evaluation.scoring import NonFinitePredictionError, score_members
from aigem.intervals import RESAMPLES, SampleIntervals, bootstrap_intervals
from aigem.metrics import ErrorTotals, step_errors, summarize_errors, whole_horizon_keys
from aigem.model.data import GraphDataset, run_scaler
from aigem.model.network import AiGem, count_parameters
from aigem.paper_layout import refuse_paper_folder_as_run
from aigem.runs.checkpoints import load_model
from aigem.runs.course import course_of, training_record
from aigem.runs.records import BEST, Group, RunInfo, group_of_member, read_group
from aigem.runs.refusals import Member, check_build, check_one_fit, resolve_build
from ngsim_graphs.build import OpenBuild
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.schema import Protocol, Split
from ngsim_graphs.synth.marker import synthetic_build


def describe_protocol(config: BuildConfig) -> str:
    """Which samples a build's protocol makes, in words (from the build's config)."""
    if config.protocol is Protocol.CS_LSTM:
        return (
            f"the literature's samples: CS-LSTM's kept rows on the {config.time_step_s:g} s "
            "grid, the sample's vehicle as the only target"
        )
    ego = "the ego and " if config.ego_is_target else ""
    return (
        f"AiGem's samples: ego windows every {config.stride_s:g} s, {ego}the actors within "
        f"{config.d_sense_m:g} m of the ego at the present as targets"
    )


def _step_lists(totals: ErrorTotals) -> dict[str, dict[str, list]]:
    """metrics.step_errors as JSON-ready lists (None for NaN)."""
    return {
        region: {
            key: [None if v != v else (int(v) if key == "n" else float(v)) for v in values]
            for key, values in curves.items()
        }
        for region, curves in step_errors(totals).items()
    }


def _distinct_samples(order: np.ndarray, sample: np.ndarray, count: int) -> np.ndarray:
    """The first `count` of `order` (indices of targets) whose sample is not taken before."""
    _, first = np.unique(sample[order], return_index=True)
    return order[np.sort(first)][:count]


def target_choice(
    sample_of_target: np.ndarray, final_error_m: np.ndarray, per_group: int = 3
) -> dict[str, np.ndarray]:
    """The targets to draw (indices into the given arrays: those valid at the last step):
    `worst`, `median` and `best`, `per_group` each (worst first, then from the median on, then
    best first), by final displacement error, each group's in distinct samples (a scene draws
    one). With few targets the groups overlap; ties go to the lower index."""
    sample = np.asarray(sample_of_target)
    error_m = np.asarray(final_error_m, dtype=np.float64)
    best_first = np.argsort(error_m, kind="stable")
    worst_first = np.argsort(-error_m, kind="stable")
    middle = max((len(error_m) - per_group) // 2, 0)
    return {
        "worst": _distinct_samples(worst_first, sample, per_group),
        "median": _distinct_samples(best_first[middle:], sample, per_group),
        "best": _distinct_samples(best_first, sample, per_group),
    }


@dataclass(frozen=True)
class LoadedRun:
    """A run's best model, loaded for evaluation, with what its run records: `info` (the
    checkpoint's run info), the build to score on, whether that is the run's own build and the
    run's scaler (the one the model was trained with)."""

    run_dir: Path
    model: AiGem
    info: RunInfo
    build_dir: Path
    same_build: bool
    scaler: MinMaxScaler

    def steps(self, dataset: GraphDataset) -> int:
        """The model's future steps at `dataset`'s time step (checked: check_build)."""
        return horizon_steps(self.info.train.horizon_s, dataset.config.time_step_s)


def load_run(
    run_dir: Path,
    build_dir: Path | None,
    device: torch.device,
    other_build: bool,
    opened: dict[Path, OpenBuild] | None = None,
) -> LoadedRun:
    """The run's best model on `device` and the build to score it on (None: the run's own).
    Another build than the run's is refused unless `other_build` (aigem.runs.refusals.check_build;
    `opened`: the builds opened so far, each opened once)."""
    model, info = load_model(run_dir, device)
    build_dir = resolve_build(info, build_dir)
    same_build = check_build(info, build_dir, run_dir, model.config, other_build, opened=opened)
    scaler = run_scaler(info.build.scaler, run_dir / BEST)
    return LoadedRun(run_dir, model, info, build_dir, same_build, scaler)


def _open_split(run: LoadedRun, split: Split | str) -> GraphDataset:
    """`split` of the run's build as its model reads it, scaled with the run's scaler; an empty
    split is refused."""
    dataset = GraphDataset(run.build_dir, split, run.model.config.history_steps_read, run.scaler)
    if len(dataset) == 0:
        raise NgsimInputError(
            run.build_dir, f"its {dataset.split.value} split is empty: nothing to evaluate"
        )
    return dataset


def _not_finite(run: LoadedRun, dataset: GraphDataset, where: str, who: str = "model") -> str:
    """The refusal of non-finite predictions (on run's checkpoint); `where`: which batch."""
    return (
        f"the {who}'s predictions on {run.build_dir} ({dataset.split.value} split, {where}) "
        "are not finite (NaN or infinite); no metrics"
    )


def _evaluation(
    run: LoadedRun,
    dataset: GraphDataset,
    scores: Scores,
    training: dict[str, Any],
    resamples: int,
) -> ModelEvaluation:
    """A member's evaluation from its scores on `dataset`; `training`: what its records say of
    its training (aigem.runs.course.training_record); with `resamples` > 0, the bootstrap's
    intervals of its metrics over all actors around its rows' numbers."""
    config = dataset.config
    model = summarize_errors(scores.model, config.time_step_s)
    baseline = summarize_errors(scores.constant_velocity, config.time_step_s)
    intervals = None
    if resamples:
        by_sample = scores.model_by_sample, scores.constant_velocity_by_sample
        drawn = bootstrap_intervals(*by_sample, config.time_step_s, resamples)
        intervals = drawn.at(model["all"], baseline["all"])
    return ModelEvaluation(
        split=dataset.split.value,
        horizon_steps=run.steps(dataset),
        samples=len(dataset),
        parameters=count_parameters(run.model),
        model=model,
        constant_velocity=baseline,
        build_dir=str(run.build_dir),
        same_build=run.same_build,
        synthetic=synthetic_build(dataset.build.manifest),
        time_step_s=config.time_step_s,
        protocol=config.protocol.value,
        protocol_description=describe_protocol(config),
        steps={
            "model": _step_lists(scores.model),
            "constant_velocity": _step_lists(scores.constant_velocity),
        },
        training=training,
        intervals=intervals,
        final=scores.final,
    )


def protocol_rows(members: dict[str, ModelEvaluation]) -> tuple[Rows, Rows, dict[str, str]]:
    """(model rows, constant-velocity rows, sources) of one model per horizon, given ascending by
    horizon: a per-second metric at s seconds (RMSE, its count) from the first model that reaches
    s, a metric of the whole horizon (ADE, FDE) from the last."""
    longest = list(members)[-1]

    def first(key: str) -> str:
        return next(name for name, result in members.items() if key in result.model["all"])

    whole = whole_horizon_keys()
    sources = {
        key: longest if key in whole else first(key) for key in members[longest].model["all"]
    }

    def rows(kind: str) -> Rows:  # kind: "model" or "constant_velocity"
        return {
            region: {
                key: getattr(members[source], kind)[region][key] for key, source in sources.items()
            }
            for region in members[longest].model
        }

    return rows("model"), rows("constant_velocity"), sources


def evaluate(
    run_dir: str | os.PathLike[str],
    build_dir: str | os.PathLike[str] | None = None,
    split: Split | str = Split.TEST,
    device_choice: str = "auto",
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    other_build: bool = False,
    resident: bool | None = None,
    resamples: int = RESAMPLES,
) -> Evaluation:
    """Score the best model of each member of the run and the constant-velocity baseline on
    `split` of `build_dir` (None: the run's own build), in one pass over the split
    (score_members: the split loaded once, the models run together, constant velocity once;
    `progress(done, total)` over its batches), and combine them as the paper reports
    (protocol_rows). Another build than the run's is refused unless `other_build`; inputs are
    always scaled with the run's scaler, the one the models were trained with. The members must
    share a model config, a scaler and a build. `resident` (None: on CUDA): the split scored on
    the device in static batches (aigem.evaluation.scoring). `resamples`: of the bootstrap's 95 % intervals
    of the metrics over all actors (aigem.intervals, seed SEED); 0: none."""
    if resamples < 0:
        raise ValueError(f"{resamples} resamples: the bootstrap takes 0 (no intervals) or more")
    run_dir, build_dir = Path(run_dir), None if build_dir is None else Path(build_dir)
    refuse_paper_folder_as_run(run_dir)
    group = read_group(run_dir)
    device = pick_device(device_choice)
    opened: dict[Path, OpenBuild] = {}  # the members' build, its files checked once
    runs = [load_run(member, build_dir, device, other_build, opened) for member in group.members]
    check_one_fit(
        run_dir, [Member(r.run_dir, r.model.config, r.scaler.to_dict(), r.build_dir) for r in runs]
    )
    dataset = _open_split(runs[0], split)
    steps = [run.steps(dataset) for run in runs]
    try:
        models = [r.model for r in runs]
        scores = score_members(models, dataset, steps, device, batch_size, progress, resident)
    except NonFinitePredictionError as err:
        run = runs[err.member]
        who = group.model(run.run_dir)
        raise NgsimInputError(
            run.run_dir / BEST, _not_finite(run, dataset, str(err), who)
        ) from None
    courses = {run.run_dir.name: course_of(run.run_dir) for run in runs}
    owner = group_of_member(run_dir)  # a member evaluated alone is continued by its run's command
    members = {  # each member's training as `evaluate` of the member says it
        name: _evaluation(
            run, dataset, score, training_record({name: courses[name]}, owner), resamples
        )
        for (name, run), score in zip(zip(courses, runs, strict=True), scores, strict=True)
    }
    return _combined(group, members, training_record(courses, owner))


def _combined(
    group: Group, members: dict[str, ModelEvaluation], training: dict[str, Any]
) -> Evaluation:
    """The members' evaluations (ascending by horizon) as the paper reports them, with what
    the run's records say of their `training`."""
    model, baseline, sources = protocol_rows(members)
    longest = members[sources["ade_m"]]
    drawn = {name: member.intervals for name, member in members.items()}
    intervals = None
    if all(member is not None for member in drawn.values()):
        intervals = SampleIntervals.combined(drawn, sources)  # type: ignore[arg-type]
    return Evaluation(
        split=longest.split,
        horizons_s=group.horizons_s,
        samples=longest.samples,
        parameters=longest.parameters,
        model=model,
        constant_velocity=baseline,
        sources=sources,
        members=members,
        build_dir=longest.build_dir,
        same_build=longest.same_build,
        synthetic=longest.synthetic,
        protocol=longest.protocol,
        protocol_description=longest.protocol_description,
        training=training,
        intervals=intervals,
    )
