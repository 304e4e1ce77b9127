"""What a run directory records, read and checked without PyTorch: its paths, run.json and
horizons.json, the build a run belongs to, and every refusal that `aigem fit` and `evaluate` can
make before they load a model. The CLI calls these first, so that a mistake costs a fraction of
a second (importing PyTorch takes seconds); aigem.runs and aigem.checkpoints call the same ones.

A build's identity is its config hash and the sha256 of its manifest's bytes: builds are
byte-deterministic, so an identical rebuild keeps it. Run info (run.json, and every checkpoint's
`info`) records it beside the build's path, config and fitted scaler, and the model and train
configs.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
from dataclasses import fields
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig, TrainConfig, check_horizons_s
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.layout import MANIFEST_NAME, manifest_path, read_manifest
from ngsim_graphs.manifest import Manifest, json_form
from ngsim_graphs.partial_files import create_exclusive, partial_of, write_failure
from ngsim_graphs.schema import N_TARGETS, Split

RUN_INFO, METRICS, LAST, BEST, CURVES = (
    "run.json",
    "metrics.jsonl",
    "last.pt",
    "best.pt",
    "curves.png",
)
HORIZONS = "horizons.json"  # a multi-horizon run's members
BASELINE = "baseline.json"  # constant velocity's validation loss
# fit's marker in a folder it set up, until a checkpoint is kept there: a fresh fit may start
# over in such a folder, and only in such a one (besides a new or empty folder)
STARTED = ".fit-started"
STARTED_LINE = b"aigem fit: no checkpoint kept here yet; a new fit may start over in this folder\n"
RUN_FILES = frozenset({RUN_INFO, METRICS, LAST, BEST, CURVES, BASELINE, HORIZONS})
EARLY_FILES = frozenset({RUN_INFO, METRICS, BEST, CURVES, BASELINE})  # before the first last.pt
IDENTITY = ("build_config_hash", "build_manifest_sha256")  # a build's identity, as a run records it
INFO_KEYS = ("build_dir", *IDENTITY, "build_config", "scaler", "model", "train")
# Train settings that a resumed run must keep: they change what it learns. Epochs (unless the
# schedule decays over them), time limit, patience, workers and threads may change.
RESUME_FIXED = (
    "horizon_s",
    "batch_size",
    "learning_rate",
    "lr_schedule",
    "warmup_epochs",
    "clip_grad_norm",
    "seed",
)


# ------------------------------------------------------------------------------------------------
# A build, as a run records it.


def build_identity(build_dir: Path) -> tuple[Manifest, dict[str, str]]:
    """A finished build's manifest and identity: {"build_config_hash", "build_manifest_sha256"}."""
    manifest = read_manifest(build_dir)  # refuses unfinished builds and other format versions
    digest = hashlib.sha256(manifest_path(build_dir).read_bytes()).hexdigest()
    return manifest, {
        "build_config_hash": str(manifest.config_hash),
        "build_manifest_sha256": digest,
    }


def run_info(build_dir: Path, model_config: ModelConfig, train: TrainConfig) -> dict[str, Any]:
    """What run.json and every checkpoint record: INFO_KEYS (the build's config and scaler as
    its manifest.json holds them)."""
    manifest, identity = build_identity(build_dir)
    return {
        "build_dir": str(Path(build_dir).resolve()),
        **identity,
        "build_config": json_form(manifest.config.to_dict()),
        "scaler": json_form(manifest.scaler.to_dict()),
        "model": model_config.to_dict(),
        "train": train.to_dict(),
    }


def identity_difference(run: dict[str, Any], identity: dict[str, str]) -> str | None:
    """How a build's identity differs from the one a run recorded (None: the same build)."""
    if identity["build_config_hash"] != run["build_config_hash"]:
        return (
            f"its config hash {identity['build_config_hash'][:12]} is not the run's "
            f"{run['build_config_hash'][:12]}"
        )
    if identity["build_manifest_sha256"] != run["build_manifest_sha256"]:
        return "same config, but its manifest.json differs from the run's build (other inputs, or edited)"
    return None


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
# run.json and horizons.json.


def check_info(info: object, path: Path) -> None:
    """Refuse run info that `aigem fit` did not write: missing keys, unknown configs."""
    if not isinstance(info, dict):
        raise NgsimInputError(path, "not an aigem run description (not a JSON object)")
    missing = [key for key in INFO_KEYS if key not in info]
    if missing:
        raise NgsimInputError(
            path,
            f"not an aigem run: no {', '.join(missing)} (another program's, or an older aigem's)",
        )
    if not all(isinstance(info[key], str) for key in ("build_dir", *IDENTITY)):
        raise NgsimInputError(
            path, f"not an aigem run: build_dir and {', '.join(IDENTITY)} must be strings"
        )
    if not isinstance(info["build_config"], dict):
        raise NgsimInputError(path, "not an aigem run: build_config is not a mapping")
    model_config(info, path)
    train_config(info, path)


def _recorded_values(info: dict[str, Any], key: str, known: type, path: Path) -> dict[str, Any]:
    """The settings of config `known` that run info records under `key`. A setting it lacks was
    added to aigem after the run was written and takes its default, which keeps what runs did
    before it (a new field's default keeps the paper's model); a setting this aigem does not
    know (a newer aigem's) is an error."""
    values = info.get(key)
    if not isinstance(values, dict):
        raise NgsimInputError(path, f"no {key} config")
    unknown = sorted(set(values) - {f.name for f in fields(known)})
    if unknown:
        raise NgsimInputError(
            path,
            f"a {key} config this aigem does not know: unknown {', '.join(map(str, unknown))} "
            "(written by a newer aigem?)",
        )
    return values


def train_config(info: dict[str, Any], path: Path) -> TrainConfig:
    """The train config a run recorded, settings it lacks at their defaults (_recorded_values)."""
    values = _recorded_values(info, "train", TrainConfig, path)
    try:
        return TrainConfig(**values)
    except (TypeError, ValueError) as err:
        raise NgsimInputError(path, f"a train config this aigem cannot use: {err}") from None


def model_config(info: dict[str, Any], path: Path) -> ModelConfig:
    """The model config a run recorded, settings it lacks at their defaults (_recorded_values);
    an error for a value of another type than the setting's."""
    values, defaults = _recorded_values(info, "model", ModelConfig, path), ModelConfig()
    for name, value in values.items():
        default = getattr(defaults, name)
        if type(value) is not type(default) and not (type(default) is float and type(value) is int):
            raise NgsimInputError(
                path, f"model config {name} = {value!r}: expected a {type(default).__name__}"
            )
    return ModelConfig(**values)


def read_run_info(run_dir: Path) -> dict[str, Any]:
    """run.json of a run directory; one clear error for a directory that is not a run."""
    if not run_dir.exists():
        raise NgsimInputError(run_dir, "no such run directory")
    path = run_dir / RUN_INFO
    if not run_dir.is_dir() or not path.is_file():
        raise NgsimInputError(
            run_dir, f"not a run directory: no {RUN_INFO} (written by `aigem fit`)"
        )
    try:
        info = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise NgsimInputError(path, f"unreadable run description: {err}") from None
    check_info(info, path)
    return info


def member_dir(run_dir: Path, horizon_s: float) -> Path:
    """The run directory of a multi-horizon run's model for `horizon_s`: RUN/h2s, RUN/h2.5s."""
    return run_dir / f"h{horizon_s:g}s"


def _seconds(horizons_s: tuple[float, ...]) -> str:
    return ",".join(f"{h:g}" for h in horizons_s)


def read_horizons(run_dir: Path) -> tuple[float, ...] | None:
    """The horizons of a multi-horizon run, from its horizons.json; None without that file."""
    path = run_dir / HORIZONS
    if not path.is_file():
        return None
    try:  # a JSONDecodeError is a ValueError; a list of other things, a TypeError
        return check_horizons_s(json.loads(path.read_text())["horizons_s"])
    except (ValueError, TypeError, KeyError, UnicodeDecodeError):
        raise NgsimInputError(path, "not aigem's list of horizons (damaged?)") from None


# ------------------------------------------------------------------------------------------------
# Refusals of `fit` (a fresh start or a resume) and of `evaluate` (the build to evaluate on).


def check_single_start(run_dir: Path, resume: bool) -> None:
    """A single-horizon fit into `run_dir`: a resume needs a last.pt; a fresh start needs a
    directory without one (`check_fresh_out` says which directories it may write into)."""
    if (horizons_s := read_horizons(run_dir)) is not None:
        raise NgsimInputError(
            run_dir,
            f"holds a multi-horizon run ({_seconds(horizons_s)} s): give "
            f"--horizon-s {_seconds(horizons_s)} to resume it, or choose another --out",
        )
    if resume and not (run_dir / LAST).is_file():
        raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
    if not resume and (run_dir / LAST).exists():
        raise NgsimInputError(
            run_dir, "already holds a run; pass --resume to continue it, or choose another --out"
        )


def check_group_start(run_dir: Path, horizons_s: tuple[float, ...], resume: bool) -> None:
    """A multi-horizon fit into `run_dir`: a resume needs the same horizons and a last.pt in at
    least one member (a member without one, killed before its first checkpoint, starts over); a
    fresh start, no member with one."""
    members = tuple(member_dir(run_dir, h) for h in horizons_s)
    recorded = read_horizons(run_dir)
    if resume:
        if recorded is None:
            raise NgsimInputError(
                run_dir, f"nothing to resume: no {HORIZONS} (not a multi-horizon run)"
            )
        if recorded != horizons_s:
            raise NgsimInputError(
                run_dir,
                f"cannot resume with other horizons ({_seconds(recorded)} -> "
                f"{_seconds(horizons_s)} s): it changes what the run learns",
            )
        if not any((member / LAST).is_file() for member in members):
            raise NgsimInputError(run_dir, f"nothing to resume: no member has a {LAST}")
        return
    if recorded is not None and any((member_dir(run_dir, h) / LAST).exists() for h in recorded):
        raise NgsimInputError(
            run_dir, "already holds a run; pass --resume to continue it, or choose another --out"
        )


def check_resume(
    run_dir: Path, build_dir: Path, saved: dict[str, Any], info: dict[str, Any]
) -> None:
    """Refuse to resume a run that recorded `saved` (its run info) as `info` (run_info of this
    call): another build, another model config, another setting of RESUME_FIXED, or other epochs
    under a decaying schedule."""
    why = identity_difference(saved, info)
    if why:
        raise NgsimInputError(
            build_dir,
            f"not the build that run {run_dir} was trained on ({why}); a run resumes on its own "
            "build only",
        )
    saved_model = model_config(saved, run_dir / LAST).to_dict()
    if saved_model != info["model"]:
        changed = sorted(k for k in info["model"] if saved_model[k] != info["model"][k])
        raise NgsimInputError(
            run_dir,
            f"cannot resume: the model config differs from the run's ({', '.join(changed)})",
        )
    before = train_config(saved, run_dir / LAST).to_dict()
    changed = [
        f"{k} {before[k]} -> {info['train'][k]}"
        for k in RESUME_FIXED
        if before[k] != info["train"][k]
    ]
    if changed:
        raise NgsimInputError(
            run_dir,
            f"cannot resume with another {', '.join(changed)}: it changes what the run learns",
        )
    schedule, epochs = info["train"]["lr_schedule"], before["epochs"]
    if schedule != "constant" and epochs != info["train"]["epochs"]:
        raise NgsimInputError(
            run_dir,
            f"cannot resume with another epochs {epochs} -> {info['train']['epochs']}: the "
            f"{schedule} schedule decays over the run's epochs; resume with --epochs {epochs}",
        )


def check_fit(
    build_dir: Path,
    run_dir: Path,
    horizons_s: tuple[float, ...] | None,
    model: ModelConfig,
    train: TrainConfig,
    resume: bool,
) -> None:
    """Everything `fit_horizons` would refuse before its first checkpoint is read: the build (a
    finished one, with train and validation samples), the run directory (check_single_start,
    check_group_start, check_fresh_out) and, to resume, run.json against this call's settings."""
    check_splits(build_dir)
    plans = [(run_dir, train.horizon_s)]
    if horizons_s is None:
        check_single_start(run_dir, resume)
    else:
        check_group_start(run_dir, horizons_s, resume)
        if not resume:
            check_fresh_group(run_dir, horizons_s, read_horizons(run_dir))
        plans = [(member_dir(run_dir, h), h) for h in horizons_s]
    for member, horizon_s in plans:
        if resume and (member / LAST).is_file():
            member_train = TrainConfig(**{**train.to_dict(), "horizon_s": horizon_s})
            info = run_info(build_dir, model, member_train)
            check_resume(member, build_dir, read_run_info(member), info)
        else:  # a fresh start, or a member that never finished an epoch starting over
            check_fresh_out(member)


def check_fresh_group(
    run_dir: Path, horizons_s: tuple[float, ...], recorded: tuple[float, ...] | None
) -> None:
    """A fresh multi-horizon run goes into a new or empty directory, or one that a fit of the
    same horizons left before any of its models kept a checkpoint (`unfinished_group`); each
    member is checked by `check_fresh_out`."""
    if not os.path.lexists(run_dir):
        return
    if not run_dir.is_dir():
        raise NgsimOutputError(run_dir, "exists and is not a directory")
    if recorded is not None and recorded != horizons_s:
        raise NgsimOutputError(
            run_dir,
            f"holds a multi-horizon run of other horizons ({_seconds(recorded)} s) "
            "that never finished an epoch; choose another --out, or delete it",
        )
    if not any(run_dir.iterdir()) or unfinished_group(run_dir, horizons_s):
        return
    members = {member_dir(run_dir, h).name for h in horizons_s}
    refuse_other_contents(run_dir, "a multi-horizon aigem run", {HORIZONS, *members})


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
        read_run_info(run_dir)  # an error naming run.json unless it is an aigem run's
    if (run_dir / RUN_INFO).is_file() and not _is_started(run_dir):
        raise NgsimOutputError(
            run_dir,
            f"holds an aigem run with no {LAST} to resume, which no fit left unfinished here (a "
            "run kept without its checkpoint, or a copy): its files are not fit's to replace; "
            "choose a new or empty --out",
        )
    refuse_other_contents(run_dir, "an aigem run", EARLY_FILES)


def refuse_other_contents(run_dir: Path, what: str, ours: frozenset[str] | set[str]) -> None:
    """Refuse a directory that is not empty and not `what`, naming what it holds: beside fit's
    marker, the entries that are not among the names `ours` (all of them without the marker)."""
    started = _is_started(run_dir)
    entries = sorted(
        p.name
        for p in run_dir.iterdir()
        if not started
        or not (p.name in ours or p.name == STARTED or partial_of(p.name) in RUN_FILES)
    )
    if entries:
        shown = ", ".join(entries[:3]) + (
            f" and {len(entries) - 3} more" if len(entries) > 3 else ""
        )
        written = ", which fit did not write" if started else ""
        raise NgsimOutputError(
            run_dir,
            f"directory is not empty and is not {what}: it holds {shown}{written}; "
            "choose a new or empty --out",
        )
    raise NgsimOutputError(
        run_dir,
        f"is not {what} that fit left unfinished (its files are links, folders or damaged); "
        "choose a new or empty --out",
    )


# ------------------------------------------------------------------------------------------------
# A run that a fit left before its first checkpoint: the only non-empty folder a fresh fit takes.


def _is_started(folder: Path) -> bool:
    """Whether `folder` holds fit's marker STARTED: a regular file (not a link) of its line."""
    path = folder / STARTED
    try:
        mode = path.lstat().st_mode
        return stat.S_ISREG(mode) and path.read_bytes() == STARTED_LINE
    except OSError:
        return False


def _regular_file(path: Path) -> bool:
    return path.is_file() and not path.is_symlink()


def unfinished_start(run_dir: Path) -> bool:
    """Whether `run_dir` is, beyond doubt, what a fit left before its first checkpoint: fit's
    marker STARTED, and besides it only files of EARLY_FILES (regular files; run.json an aigem
    run's) and partial files of a run's files."""
    if not _is_started(run_dir) or os.path.lexists(run_dir / LAST):
        return False
    for entry in run_dir.iterdir():
        if entry.name == STARTED or partial_of(entry.name) in RUN_FILES:
            continue
        if entry.name not in EARLY_FILES or not _regular_file(entry):
            return False
    if (run_dir / RUN_INFO).exists():
        try:
            read_run_info(run_dir)
        except NgsimInputError:
            return False
    return True


def unfinished_group(run_dir: Path, horizons_s: tuple[float, ...]) -> bool:
    """Whether `run_dir` is, beyond doubt, what a multi-horizon fit of `horizons_s` left before
    any model kept a checkpoint: fit's marker, its horizons.json (if written yet, a regular file
    of these horizons), and member folders each empty or `unfinished_start`."""
    if not _is_started(run_dir):
        return False
    members = {member_dir(run_dir, h).name for h in horizons_s}
    for entry in run_dir.iterdir():
        if entry.name == STARTED or partial_of(entry.name) == HORIZONS:
            continue
        if entry.name == HORIZONS:
            if not _regular_file(entry):
                return False
            continue
        if entry.name not in members or entry.is_symlink() or not entry.is_dir():
            return False
        if any(entry.iterdir()) and not unfinished_start(entry):
            return False
    try:
        return read_horizons(run_dir) in (None, horizons_s)
    except NgsimInputError:
        return False


def mark_started(folder: Path) -> None:
    """Write fit's marker into `folder` (new or empty, or unfinished: it may be there already):
    created exclusively, never through a link."""
    path = folder / STARTED
    if _is_started(folder):
        return
    try:
        with create_exclusive(path) as marker:
            marker.write(STARTED_LINE)
    except OSError as err:
        if not isinstance(err, FileExistsError):  # ours, half written: a full disk
            path.unlink(missing_ok=True)
        raise write_failure(path, err) from None


def unmark_started(folder: Path) -> None:
    """Remove fit's marker from `folder` (its first checkpoint is kept, or it is discarded)."""
    if _is_started(folder):
        (folder / STARTED).unlink(missing_ok=True)


def resolve_build(info: dict[str, Any], data: Path | None) -> Path:
    """The build to evaluate on: `data`, else the run's own (the absolute path recorded by fit)."""
    if data is not None:
        return data
    recorded = Path(info["build_dir"])
    if not (recorded / MANIFEST_NAME).is_file():
        raise NgsimInputError(
            recorded, "the run's build is gone (or unfinished); pass --data to name it"
        )
    return recorded


def check_build(
    info: dict[str, Any],
    build_dir: Path,
    run_dir: Path,
    model: ModelConfig,
    other_build: bool,
    refusal: str = "pass --other-build to evaluate on another build",
) -> bool:
    """Whether `build_dir` is the run's own build. Refuses another build unless `other_build`,
    and, even then, one whose time step or history and future lengths do not fit the run's model
    and horizon."""
    _, identity = build_identity(build_dir)
    why = identity_difference(info, identity)
    if why and not other_build:
        raise NgsimInputError(
            build_dir,
            f"not the build that run {run_dir} was trained on ({why}); {refusal}",
        )
    config = open_build(build_dir).config
    time_step_s = float(info["build_config"].get("time_step_s", math.nan))
    if not math.isclose(config.time_step_s, time_step_s):
        raise NgsimInputError(
            build_dir,
            f"its time step is {config.time_step_s} s; the run was "
            f"trained on {time_step_s} s steps",
        )
    steps = round(info["train"]["horizon_s"] / time_step_s)
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
    """Everything `evaluate` (or `evaluate_horizons`) would refuse before it loads a model: a
    directory that is not a run, or not a finished one; the run's build gone; another build
    without `other_build`, or one that does not fit the model (check_build); an empty split."""
    horizons_s = read_horizons(run_dir)
    members = [run_dir] if horizons_s is None else [member_dir(run_dir, h) for h in horizons_s]
    for member in members:
        info = read_run_info(member)
        if not (member / BEST).is_file():
            raise NgsimInputError(
                member, f"not a finished run: no {BEST} (no epoch has finished yet)"
            )
        build = resolve_build(info, build_dir)
        check_build(info, build, member, model_config(info, member / RUN_INFO), other_build)
        if int(open_build(build).manifest.splits.get(Split(split).value, 0)) == 0:
            raise NgsimInputError(
                build, f"its {Split(split).value} split is empty: nothing to evaluate"
            )
