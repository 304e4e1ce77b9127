"""`aigem evaluate`: the best model of a run and the constant-velocity baseline on one split.

Both are scored on the same samples and targets, with the metrics of aigem.metrics (metres). By
default on the run's own build; another build (say, trained on US-101, tested on I-80) only when
asked, and then with the run's scaler: the model only knows its inputs as scaled in training.

A multi-horizon run (one model per horizon, the paper's protocol) is scored as the paper reports:
RMSE at h s from the model trained for h s (in general: from the shortest-horizon model that
predicts that far), ADE and FDE from the longest-horizon model; constant velocity likewise, so
that each number of the baseline is on the same targets as the model's beside it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from aigem.baseline import constant_velocity
from aigem.data import Collate, GraphDataset, run_scaler, xy_to_metres
from aigem.devices import pick_device, to_device
from aigem.metrics import ErrorTotals, step_errors, summarize_errors, whole_horizon_keys
from aigem.model import AiGem, count_parameters
from aigem.records import BEST, member_dir, read_horizons
from aigem.refusals import check_build, resolve_build
from aigem.results import Evaluation, FinalErrors, HorizonsEvaluation, Rows, Scores
from aigem.runs import load_model
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
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


class NonFinitePredictionError(ValueError):
    """The model predicted NaN or infinite positions: no metric of them would mean anything."""


def score_targets(
    model: AiGem,
    dataset: GraphDataset,
    steps: int,
    device: torch.device,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
) -> Scores:
    """Error totals (metres) of the model and of constant velocity over `dataset`'s targets,
    `steps` future steps, and each target's final error; inputs scaled with `dataset.scaler`."""
    collate = Collate(dataset.scaler, layers=model.config.layers)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, collate_fn=collate)
    ours, baseline = ErrorTotals(steps), ErrorTotals(steps)
    finals: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    with torch.no_grad():
        for index, batch in enumerate(loader):
            predicted = xy_to_metres(dataset.scaler, model(to_device(batch, device), steps))
            if not bool(torch.isfinite(predicted).all()):
                raise NonFinitePredictionError(f"batch {index + 1} of {len(loader)}")
            truth = batch["target_xy"][:, :steps].numpy()
            mask = batch["target_mask"][:, :steps].numpy()
            state = batch["target_state"].numpy().astype(np.float64)
            cv = constant_velocity(state, steps, dataset.config.time_step_s)
            predicted = predicted.cpu().numpy()
            ours.add(predicted, truth, mask, state[:, 1])
            baseline.add(cv, truth, mask, state[:, 1])
            first = index * batch_size  # the loader's batches are consecutive indices
            ids = dataset.batch_order(np.arange(first, first + batch["graphs"]))
            last = mask[:, -1]
            finals.append(
                (
                    ids[batch["target_sample"].numpy()[last]],
                    np.linalg.norm(predicted[last, -1] - truth[last, -1], axis=-1).astype(float),
                    np.linalg.norm(cv[last, -1] - truth[last, -1], axis=-1),
                )
            )
            if progress:
                progress(index + 1, len(loader))
    if not finals:  # no batch: an empty split
        finals = [(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))]
    final = FinalErrors(*(np.concatenate(part) for part in zip(*finals, strict=True)))
    return Scores(ours, baseline, final)


def _step_lists(totals: ErrorTotals) -> dict[str, dict[str, list]]:
    """metrics.step_errors as JSON-ready lists (None for NaN)."""
    return {
        region: {
            key: [None if v != v else (int(v) if key == "n" else float(v)) for v in values]
            for key, values in curves.items()
        }
        for region, curves in step_errors(totals).items()
    }


def scene_choice(
    sample_of_target: np.ndarray, final_error_m: np.ndarray, per_group: int = 3
) -> dict[str, np.ndarray]:
    """The samples to draw: `worst`, `median` and `best`, `per_group` sample ids each (worst
    first, then around the median, then best first), by scene error: the mean final displacement
    error over a sample's targets (those given: valid at the last step). With fewer than
    3 * per_group samples the groups overlap; ties go to the lower sample id."""
    samples, inverse = np.unique(np.asarray(sample_of_target), return_inverse=True)
    scene_m = np.bincount(inverse, weights=final_error_m) / np.bincount(inverse)
    ranked = samples[np.argsort(scene_m, kind="stable")]  # best first
    group = min(per_group, len(ranked))
    middle = (len(ranked) - group) // 2
    worst = samples[np.argsort(-scene_m, kind="stable")][:group]
    return {"worst": worst, "median": ranked[middle : middle + group], "best": ranked[:group]}


def evaluate(
    run_dir: Path,
    build_dir: Path | None = None,
    split: Split | str = Split.TEST,
    device_choice: str = "auto",
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    other_build: bool = False,
) -> Evaluation:
    """Score the run's best model and the constant-velocity baseline on `split` of `build_dir`
    (None: the run's own build). Another build than the run's is refused unless `other_build`;
    inputs are always scaled with the run's scaler, the one the model was trained with."""
    device = pick_device(device_choice)
    model, info = load_model(run_dir, device)
    build_dir = resolve_build(info, build_dir)
    same_build = check_build(info, build_dir, run_dir, model.config, other_build)
    scaler = run_scaler(info["scaler"], run_dir / BEST)
    dataset = GraphDataset(build_dir, split, model.config.history_steps_read, scaler)
    if len(dataset) == 0:
        raise NgsimInputError(
            build_dir, f"its {dataset.split.value} split is empty: nothing to evaluate"
        )
    steps = round(info["train"]["horizon_s"] / dataset.config.time_step_s)
    try:
        scores = score_targets(model, dataset, steps, device, batch_size, progress)
    except NonFinitePredictionError as err:
        raise NgsimInputError(
            run_dir / BEST,
            f"the model's predictions on {build_dir} ({Split(split).value} "
            f"split, {err}) are not finite (NaN or infinite); no metrics",
        ) from None
    return Evaluation(
        split=Split(split).value,
        horizon_steps=steps,
        samples=len(dataset),
        parameters=count_parameters(model),
        model=summarize_errors(scores.model, dataset.config.time_step_s),
        constant_velocity=summarize_errors(scores.constant_velocity, dataset.config.time_step_s),
        build_dir=str(build_dir),
        same_build=same_build,
        synthetic=synthetic_build(open_build(build_dir).manifest),
        time_step_s=dataset.config.time_step_s,
        protocol=dataset.config.protocol.value,
        protocol_description=describe_protocol(dataset.config),
        steps={
            "model": _step_lists(scores.model),
            "constant_velocity": _step_lists(scores.constant_velocity),
        },
        final=scores.final,
    )


def protocol_rows(members: dict[str, Evaluation]) -> tuple[Rows, Rows, dict[str, str]]:
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


def evaluate_horizons(
    run_dir: Path,
    build_dir: Path | None = None,
    split: Split | str = Split.TEST,
    device_choice: str = "auto",
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    other_build: bool = False,
) -> HorizonsEvaluation:
    """Score every member of a multi-horizon run as `evaluate` does, and combine them as the paper
    reports (protocol_rows)."""
    horizons_s = read_horizons(run_dir)
    if horizons_s is None:
        raise NgsimInputError(run_dir, "not a multi-horizon run: no horizons.json")
    members = {
        member_dir(run_dir, h).name: evaluate(
            member_dir(run_dir, h),
            build_dir,
            split,
            device_choice,
            batch_size,
            progress,
            other_build,
        )
        for h in horizons_s
    }
    model, baseline, sources = protocol_rows(members)
    longest = members[sources["ade_m"]]
    return HorizonsEvaluation(
        split=longest.split,
        horizons_s=horizons_s,
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
    )
