"""Every refusal that `aigem fit` and `evaluate` can make before they load a model: the build
(finished, with train and validation samples; the run's own, or one that fits its model), the run
directory (a fresh start, a resume, a finished run). The CLI calls these first, so that a mistake
costs a fraction of a second (importing PyTorch takes seconds); aigem.runs.folder and aigem.training.fit
call the same ones.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from aigem.config import RESUMABLE, ModelConfig, TrainConfig, horizon_steps
from aigem.paper_layout import refuse_paper_folder_as_run
from aigem.runs.provenance import build_identity, identity_difference
from aigem.runs.records import (
    BEST,
    EARLY_FILES,
    FIT_LOG,
    HORIZONS,
    LAST,
    RUN_INFO,
    Group,
    RunInfo,
    read_group,
    read_horizons,
    read_record,
    recorded_members,
    run_info,
)
from aigem.runs.unfinished import (
    is_started,
    refuse_other_contents,
    unfinished_group,
    unfinished_start,
)
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.layout import MANIFEST_NAME
from ngsim_graphs.schema import N_TARGETS, Split

# Train settings that a resumed run must keep: they change what it learns. Those of
# config.RESUMABLE (epochs, unless the schedule decays over them; the time limit, patience,
# workers, threads, ...) may change.
RESUME_FIXED = tuple(f.name for f in fields(TrainConfig) if f.name not in RESUMABLE)


def check_splits(build_dir: Path) -> None:
    """Refuse a build whose train or validation split has no samples, or no target actors: one
    gives nothing to train on (nor a scaler), the other no validation loss, which picks the best
    checkpoint and stops early; training on would only log a validation MSE of NaN."""
    build = open_build(build_dir)
    why = {
        Split.TRAIN: ("train", "there is nothing to train on (and the scaler is fitted on it)"),
        Split.VAL: (
            "validation",
            "`aigem fit` keeps the best checkpoint and stops early by validation loss",
        ),
    }
    for split, (name, reason) in why.items():
        samples = int(build.manifest.splits.get(split.value, 0))
        if samples == 0:
            raise NgsimInputError(
                build_dir,
                f"the {name} split ({split.value}) is empty: {reason}; "
                "rebuild with other split fractions or more data",
            )
        if int(build.samples(split)[N_TARGETS].sum()) == 0:
            raise NgsimInputError(
                build_dir,
                f"the {name} split ({split.value}) has {samples} samples "
                f"but no target actors: {reason}",
            )


# ------------------------------------------------------------------------------------------------
# `fit`: a fresh start or a resume.


def _seconds(horizons_s: tuple[float, ...]) -> str:
    return ",".join(f"{h:g}" for h in horizons_s)


def check_member_start(run_dir: Path, resume: bool) -> None:
    """A model's fit into its folder `run_dir`: a resume needs a last.pt; a fresh start needs a
    folder without one (`check_fresh_out` says which folders it may write into)."""
    if resume and not (run_dir / LAST).is_file():
        raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
    if not resume and (run_dir / LAST).exists():
        raise NgsimInputError(
            run_dir, "already holds a run; pass --resume to continue it, or choose another --out"
        )


def check_group_start(group: Group, resume: bool) -> None:
    """A fit of `group`: a resume needs a run of the same horizons (read_group) and a last.pt in
    at least one member (a member without one, killed before its first checkpoint, starts over);
    a fresh start, a folder whose recorded members (records.recorded_members) have none
    (`check_fresh_group` and `check_fresh_out` say which folders it may write into)."""
    run_dir = group.run_dir
    if resume:
        if not any((member / LAST).is_file() for member in recorded_members(run_dir)):
            raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
        recorded = read_group(run_dir).horizons_s
        if recorded != group.horizons_s:
            raise NgsimInputError(
                run_dir,
                f"cannot resume with other horizons ({_seconds(recorded)} -> "
                f"{_seconds(group.horizons_s)} s): it changes what the run learns",
            )
        return
    if any((member / LAST).exists() for member in recorded_members(run_dir)):
        raise NgsimInputError(
            run_dir, "already holds a run; pass --resume to continue it, or choose another --out"
        )


def check_resume(run_dir: Path, build_dir: Path, saved: RunInfo, info: RunInfo) -> None:
    """Refuse to resume a run that recorded `saved` (its run info) as `info` (run_info of this
    call): another build, another model config, another setting of RESUME_FIXED, or other epochs
    under a decaying schedule."""
    why = identity_difference(saved.build, info.build.identity, info.build.settings)
    if why:
        raise NgsimInputError(
            build_dir,
            f"not the build that run {run_dir} was trained on ({why}); a run resumes on its own "
            "build only",
        )
    if saved.model != info.model:
        changed = sorted(
            f.name
            for f in fields(ModelConfig)
            if getattr(saved.model, f.name) != getattr(info.model, f.name)
        )
        raise NgsimInputError(
            run_dir,
            f"cannot resume: the model config differs from the run's ({', '.join(changed)})",
        )
    before, now = saved.train, info.train
    changed = [
        f"{k} {getattr(before, k)} -> {getattr(now, k)}"
        for k in RESUME_FIXED
        if getattr(before, k) != getattr(now, k)
    ]
    if changed:
        raise NgsimInputError(
            run_dir,
            f"cannot resume with another {', '.join(changed)}: it changes what the run learns",
        )
    schedule, epochs = now.lr_schedule, before.epochs
    if schedule != "constant" and epochs != now.epochs:
        raise NgsimInputError(
            run_dir,
            f"cannot resume with another epochs {epochs} -> {now.epochs}: the "
            f"{schedule} schedule decays over the run's epochs; resume with --epochs {epochs}",
        )


def model_of_build(model: ModelConfig, build_dir: Path) -> ModelConfig:
    """The model a fit trains on `build_dir`: a GAT per edge type of the build, in its order."""
    return replace(model, edge_types=open_build(build_dir).config.edge_types)


def check_fit(
    build_dir: Path,
    group: Group,
    model: ModelConfig,
    train: TrainConfig,
    resume: bool,
) -> None:
    """Everything `fit_horizons` would refuse before its first checkpoint is read: the build (a
    finished one, with train and validation samples), the run directory (check_group_start,
    check_fresh_group, check_fresh_out) and, to resume, run.json against this call's settings."""
    check_splits(build_dir)
    model = model_of_build(model, build_dir)
    check_group_start(group, resume)
    if not resume:
        check_fresh_group(group)
    for member, horizon_s in zip(group.members, group.horizons_s, strict=True):
        if resume and (member / LAST).is_file():
            member_train = TrainConfig(**{**train.to_dict(), "horizon_s": horizon_s})
            info = run_info(build_dir, model, member_train)
            check_resume(member, build_dir, read_record(member).info, info)
        else:  # a fresh start, or a member that never finished an epoch starting over
            check_fresh_out(member)


def check_fresh_group(group: Group) -> None:
    """A fresh run goes into a new or empty directory, or one that a fit of the same horizons
    left before any of its models kept a checkpoint (`unfinished_group`); each member is checked
    by `check_fresh_out` (a group of one, its own folder, by that alone)."""
    run_dir, horizons_s = group.run_dir, group.horizons_s
    if not os.path.lexists(run_dir):
        return
    if not run_dir.is_dir():
        raise NgsimOutputError(run_dir, "exists and is not a directory")
    recorded = read_horizons(run_dir)
    if recorded is not None and recorded != horizons_s:
        raise NgsimOutputError(
            run_dir,
            f"holds a multi-horizon run of other horizons ({_seconds(recorded)} s) "
            "that never finished an epoch; choose another --out, or delete it",
        )
    if not group.named or not any(run_dir.iterdir()) or unfinished_group(run_dir, horizons_s):
        return
    members = {member.name for member in group.members}
    refuse_other_contents(run_dir, "a multi-horizon aigem run", {HORIZONS, FIT_LOG, *members})


def check_fresh_out(run_dir: Path) -> None:
    """A fresh run goes into a new or empty directory, or one that a fit left before its first
    checkpoint (`unfinished_start`): never into another folder, whose files it would replace,
    even one that holds a run's files (a run kept without its last.pt, a copy)."""
    if not os.path.lexists(run_dir):
        return
    if not run_dir.is_dir():
        raise NgsimOutputError(run_dir, "exists and is not a directory")
    if not any(run_dir.iterdir()) or unfinished_start(run_dir):
        return
    if (run_dir / RUN_INFO).is_file():
        read_record(run_dir)  # an error naming run.json unless it is an aigem run's
    if (run_dir / RUN_INFO).is_file() and not is_started(run_dir):
        raise NgsimOutputError(
            run_dir,
            f"holds an aigem run with no {LAST} to resume, which no fit left unfinished here (a "
            "run kept without its checkpoint, or a copy): its files are not fit's to replace; "
            "choose a new or empty --out",
        )
    refuse_other_contents(run_dir, "an aigem run", EARLY_FILES)


# ------------------------------------------------------------------------------------------------
# `evaluate`: a finished run, and the build to evaluate on.


def resolve_build(info: RunInfo, data: Path | None) -> Path:
    """The build to evaluate on: `data`, else the run's own (the absolute path recorded by fit)."""
    if data is not None:
        return data
    recorded = info.build.build_dir
    if not (recorded / MANIFEST_NAME).is_file():
        raise NgsimInputError(
            recorded, "the run's build is gone (or unfinished); pass --data to name it"
        )
    return recorded


def opened_build(build_dir: Path, opened: dict[Path, OpenBuild] | None) -> OpenBuild:
    """`open_build(build_dir)`, once per build where `opened` keeps the builds a command has
    opened (its files checked against the manifest once, not once per model)."""
    if opened is None:
        return open_build(build_dir)
    if build_dir not in opened:
        opened[build_dir] = open_build(build_dir)
    return opened[build_dir]


def check_build(
    info: RunInfo,
    build_dir: Path,
    run_dir: Path,
    model: ModelConfig,
    other_build: bool,
    refusal: str = "pass --other-build to evaluate on another build",
    opened: dict[Path, OpenBuild] | None = None,
) -> bool:
    """Whether `build_dir` is the run's own build. Refuses another build unless `other_build`,
    and, even then, one whose time step or history and future lengths do not fit the run's model
    and horizon. `opened`: the builds opened so far (opened_build)."""
    manifest, identity = build_identity(build_dir)
    why = identity_difference(info.build, identity, manifest.settings())
    if why and not other_build:
        raise NgsimInputError(
            build_dir,
            f"not the build that run {run_dir} was trained on ({why}); {refusal}",
        )
    config = opened_build(build_dir, opened).config
    time_step_s = info.build.time_step_s
    if not math.isclose(config.time_step_s, time_step_s):
        raise NgsimInputError(
            build_dir,
            f"its time step is {config.time_step_s} s; the run was "
            f"trained on {time_step_s} s steps",
        )
    if config.edge_types != model.edge_types:
        raise NgsimInputError(
            build_dir,
            f"its graphs have edge types {', '.join(config.edge_types)}; the run's model has a "
            f"GAT for each of {', '.join(model.edge_types)}",
        )
    try:
        steps = horizon_steps(info.train.horizon_s, time_step_s)
    except ValueError as err:
        raise NgsimInputError(run_dir / RUN_INFO, f"its horizon cannot be scored: {err}") from None
    if config.history_steps < model.history_steps_read or config.future_steps < steps:
        raise NgsimInputError(
            build_dir,
            f"its graphs have {config.history_steps} history and "
            f"{config.future_steps} future steps; the run's model reads "
            f"{model.history_steps_read} and predicts {steps}",
        )
    return why is None


def check_evaluate(
    run_dir: Path, build_dir: Path | None, split: Split | str, other_build: bool
) -> None:
    """Everything `evaluate` would refuse before it loads a model: a
    directory that is not a run, or not a finished one; the run's build gone; another build
    without `other_build`, or one that does not fit the model (check_build); an empty split; a
    multi-horizon run whose models cannot be scored in one pass (check_one_fit); a folder of
    `aigem paper`, naming its runs."""
    refuse_paper_folder_as_run(run_dir)
    recorded, opened = [], {}
    for member in read_group(run_dir).members:
        info = read_record(member).info
        if not (member / BEST).is_file():
            raise NgsimInputError(
                member, f"not a finished run: no {BEST} (no epoch has finished yet)"
            )
        build = resolve_build(info, build_dir)
        check_build(info, build, member, info.model, other_build, opened=opened)
        if int(opened_build(build, opened).manifest.splits.get(Split(split).value, 0)) == 0:
            raise NgsimInputError(
                build, f"its {Split(split).value} split is empty: nothing to evaluate"
            )
        recorded.append(Member(member, info.model, info.build.scaler, build))
    check_one_fit(run_dir, recorded)


@dataclass(frozen=True)
class Member:
    """A model of a multi-horizon run as scoring it needs: its run directory, its model config,
    its scaler (as its run records it: MinMaxScaler.to_dict's form), the build to score on."""

    run_dir: Path
    model: ModelConfig
    scaler: dict[str, Any]
    build_dir: Path


def check_one_fit(run_dir: Path, members: Sequence[Member]) -> None:
    """Refuse a multi-horizon run whose models cannot be scored in one pass over one split
    (aigem.evaluation.scoring.score_members): they share one model config (so the history they read), one
    scaler and one build, as `fit_horizons` trains them."""
    first = members[0]
    for member in members[1:]:
        for what, same in (
            ("model settings", member.model == first.model),
            ("scalers", member.scaler == first.scaler),
            ("builds", member.build_dir == first.build_dir),
        ):
            if not same:
                raise NgsimInputError(
                    run_dir,
                    f"its models {first.run_dir.name} and {member.run_dir.name} differ in their "
                    f"{what}: not the models of one multi-horizon fit; evaluate each on its own",
                )
