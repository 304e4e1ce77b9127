"""What a run directory records, read and written without PyTorch: its file names, run.json and
the info every checkpoint carries (RunInfo, RunRecord), the progress last.pt carries (RunState),
horizons.json and the layouts of a run folder (Group). This is the one module that reads
run.json's keys: the rest of aigem gets frozen dataclasses of typed fields (aigem.runs.run_log does
the same for metrics.jsonl and baseline.json; aigem.runs.provenance compares a run's build with
another).

run.json also records the sha256 of each checkpoint that the run keeps (DIGESTS), and a
checkpoint is loaded only if its bytes have one of them (aigem.runs.checkpoints); a run written before
they were recorded (aigem 0.1.0's) has none, and its checkpoints are used unchecked, with a
warning.

Run info records each config as a mapping of its settings. A setting that a run lacks was added
to aigem after the run was written and takes its default (a new setting's default keeps what
aigem did before it), so that every older run loads; a setting this aigem does not know (a newer
aigem's) is one error line. Older values that no longer validate are adapted here and only here
(`--max-minutes inf`, no limit, reads as None).

Run info (run.json, and every checkpoint's `info`) records the build's identity (IDENTITY), path,
settings (`build_config`) and fitted scaler (aigem.runs.provenance.BuildRecord), and the model and
train configs.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig, TrainConfig, check_horizons_s
from aigem.runs.provenance import BuildIdentity, BuildRecord, build_record
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.partial_files import write_atomic

RUN_INFO, METRICS, LAST, BEST, CURVES = (
    "run.json",
    "metrics.jsonl",
    "last.pt",
    "best.pt",
    "curves.png",
)
HORIZONS = "horizons.json"  # a multi-horizon run's members
BASELINE = "baseline.json"  # constant velocity's validation loss
FIT_LOG = "fit.log"  # `aigem fit`'s stderr lines, each after its time, appended (RUN/fit.log)
# fit's marker in a folder it set up, until a checkpoint is kept there: a fresh fit may start
# over in such a folder, and only in such a one (besides a new or empty folder)
STARTED = ".fit-started"
STARTED_LINE = b"aigem fit: no checkpoint kept here yet; a new fit may start over in this folder\n"
RUN_FILES = frozenset({RUN_INFO, METRICS, LAST, BEST, CURVES, BASELINE, HORIZONS, FIT_LOG})
EARLY_FILES = frozenset({RUN_INFO, METRICS, BEST, CURVES, BASELINE, FIT_LOG})  # before a last.pt
IDENTITY = ("build_config_hash", "build_manifest_sha256")  # a build's identity, as a run records it
# run.json's record of its checkpoints' bytes: name -> the sha256 values the file may have (one;
# two while fit replaces it). Run info that checkpoints carry has no such key.
DIGESTS = "checkpoint_sha256"
SHA256 = re.compile(r"[0-9a-f]{64}")
UNRECORDED = (
    f"its {RUN_INFO} records no sha256 of its checkpoints (a run of an aigem before they were "
    "recorded): used as it is, unchecked"
)
INFO_KEYS = ("build_dir", *IDENTITY, "build_config", "scaler", "model", "train")


# ------------------------------------------------------------------------------------------------
# The record, typed.


@dataclass(frozen=True)
class RunInfo:
    """What a model was trained on and how: run.json's record but the checkpoints' digests, and
    what every checkpoint carries as its `info`."""

    build: BuildRecord
    model: ModelConfig
    train: TrainConfig

    def to_json(self) -> dict[str, Any]:
        """The JSON object run.json and the checkpoints hold (INFO_KEYS, in that order)."""
        return {
            "build_dir": str(self.build.build_dir),
            "build_config_hash": self.build.identity.config_hash,
            "build_manifest_sha256": self.build.identity.manifest_sha256,
            "build_config": self.build.settings,
            "scaler": self.build.scaler,
            "model": self.model.to_dict(),
            "train": self.train.to_dict(),
        }


@dataclass(frozen=True)
class RunRecord:
    """A model's run.json: its info and the sha256 values each checkpoint may have (None: a run
    of an aigem before they were recorded, UNRECORDED)."""

    info: RunInfo
    digests: dict[str, tuple[str, ...]] | None


@dataclass(frozen=True)
class RunState:
    """A model's progress as its last.pt carries it: the next epoch to train (from 0), the best
    epoch so far (from 0; -1: none) and its validation loss (m²)."""

    next_epoch: int = 0
    best_epoch: int = -1
    best_val_loss: float = math.inf


def run_info(build_dir: Path, model_config: ModelConfig, train: TrainConfig) -> RunInfo:
    """What run.json and every checkpoint of a fit of `build_dir` record (aigem.runs.provenance's
    record of the build, and the configs)."""
    return RunInfo(build_record(build_dir), model_config, train)


# ------------------------------------------------------------------------------------------------
# Run info read back: every older form adapted here.


def info_of(info: object, path: Path) -> RunInfo:
    """Run info as run.json or a checkpoint (`path`) holds it; refused where `aigem fit` did not
    write it: missing keys, unknown configs."""
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
    identity = BuildIdentity(*(info[key] for key in IDENTITY))
    settings = info["build_config"]
    time_step_s = settings.get("time_step_s")
    time_step_s = float(time_step_s) if isinstance(time_step_s, int | float) else math.nan
    build = BuildRecord(Path(info["build_dir"]), identity, time_step_s, settings, info["scaler"])
    return RunInfo(build, model_config(info, path), train_config(info, path))


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
    """The train config that run info records, settings it lacks at their defaults
    (_recorded_values). An aigem before the settings were checked finite took `--max-minutes
    inf`, no limit, which reads as the None that says it now."""
    values = _recorded_values(info, "train", TrainConfig, path)
    if values.get("max_minutes") == math.inf:
        values = {**values, "max_minutes": None}
    try:
        return TrainConfig(**values)
    except (TypeError, ValueError) as err:
        raise NgsimInputError(path, f"a train config this aigem cannot use: {err}") from None


def model_config(info: dict[str, Any], path: Path) -> ModelConfig:
    """The model config that run info records, settings it lacks at their defaults
    (_recorded_values); an error for a value of another type than the setting's, or one that
    ModelConfig refuses (no layer, a dropout of 1)."""
    values, defaults = dict(_recorded_values(info, "model", ModelConfig, path)), ModelConfig()
    for name, value in values.items():
        default = getattr(defaults, name)
        if isinstance(default, tuple) and isinstance(value, list):  # JSON's form of a tuple
            values[name] = value = tuple(value)
        if type(value) is not type(default) and not (type(default) is float and type(value) is int):
            raise NgsimInputError(
                path, f"model config {name} = {value!r}: expected a {type(default).__name__}"
            )
    try:
        return ModelConfig(**values)
    except ValueError as err:
        raise NgsimInputError(path, f"a model config this aigem cannot use: {err}") from None


def state_of(saved: object, path: Path) -> RunState:
    """The progress that a last.pt (`path`) carries, as `state_json` wrote it."""
    names = [f.name for f in fields(RunState)]
    number = lambda v: isinstance(v, int | float) and not isinstance(v, bool)
    if (
        not isinstance(saved, dict)
        or sorted(saved) != sorted(names)
        or not all(map(number, saved.values()))
    ):
        raise NgsimInputError(
            path, f"its progress record is not aigem's (expected {', '.join(names)})"
        )
    return RunState(
        next_epoch=int(saved["next_epoch"]),
        best_epoch=int(saved["best_epoch"]),
        best_val_loss=float(saved["best_val_loss"]),
    )


def state_json(state: RunState) -> dict[str, Any]:
    """The progress as a last.pt carries it (its fields by name)."""
    return {f.name: getattr(state, f.name) for f in fields(RunState)}


# ------------------------------------------------------------------------------------------------
# run.json: read, written, and its record of the checkpoints' bytes.


def read_record(run_dir: Path) -> RunRecord:
    """run.json of a run directory; one clear error for a directory that is not a run."""
    if not run_dir.exists():
        raise NgsimInputError(run_dir, "no such run directory")
    path = run_dir / RUN_INFO
    if not run_dir.is_dir() or not path.is_file():
        raise NgsimInputError(
            run_dir, f"not a run directory: no {RUN_INFO} (written by `aigem fit`)"
        )
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise NgsimInputError(path, f"unreadable run description: {err}") from None
    info = info_of(document, path)
    return RunRecord(info, _digests(document, path))


def write_record(run_dir: Path, info: RunInfo, digests: dict[str, tuple[str, ...]]) -> None:
    """run.json: the run `info` and the sha256 values each checkpoint may have (DIGESTS)."""
    recorded = {name: list(accepted) for name, accepted in digests.items()}
    text = json.dumps({**info.to_json(), DIGESTS: recorded}, indent=2) + "\n"
    write_atomic(run_dir / RUN_INFO, text.encode())


def _digests(document: dict[str, Any], path: Path) -> dict[str, tuple[str, ...]] | None:
    """The sha256 values that run.json (`document`, read from `path`) accepts for each
    checkpoint; None for a run written before they were recorded."""
    if DIGESTS not in document:
        return None
    digests = document[DIGESTS]
    if not isinstance(digests, dict) or not all(
        isinstance(accepted, list) and accepted and all(SHA256.fullmatch(str(d)) for d in accepted)
        for accepted in digests.values()
    ):
        raise NgsimInputError(path, f"its {DIGESTS} is not aigem's record of its checkpoints")
    return {name: tuple(accepted) for name, accepted in digests.items()}


def accepted_digests(run: RunRecord, run_dir: Path, name: str) -> tuple[str, ...] | None:
    """The sha256 values that checkpoint `name` of the run in `run_dir` (its run.json: `run`)
    may have; None for a run that records none (UNRECORDED). A run that records them but none of
    `name` refuses it: a checkpoint that the run did not keep."""
    if run.digests is None:
        return None
    if name not in run.digests:
        raise NgsimInputError(
            run_dir / name, f"{RUN_INFO} records no sha256 of it: not a checkpoint this run kept"
        )
    return run.digests[name]


def unrecorded_checkpoints(run_dir: Path, names: tuple[str, ...] = (BEST, LAST)) -> list[Path]:
    """The checkpoints `names` of each model of a run whose run.json records no sha256 of them
    (UNRECORDED): used unchecked."""
    return [
        member / name
        for member in read_group(run_dir).members
        if (member / RUN_INFO).is_file() and read_record(member).digests is None
        for name in names
        if (member / name).is_file()
    ]


# ------------------------------------------------------------------------------------------------
# A run is a group: one model per horizon. The one place that knows the layouts of a run folder.


@dataclass(frozen=True)
class Group:
    """A run: one model per horizon (`horizons_s`, ascending), each in its run directory
    (`members`, in the same order). A group of one model is its own folder (RUN/run.json,
    RUN/best.pt, ...); a group of several holds one member folder per horizon (RUN/h1s, ...) and
    horizons.json, which names them."""

    run_dir: Path
    horizons_s: tuple[float, ...]
    members: tuple[Path, ...]

    @property
    def named(self) -> bool:
        """Whether horizons.json names the members (the members are folders of `run_dir`)."""
        return self.members != (self.run_dir,)

    @property
    def longest(self) -> Path:
        """The member of the longest horizon: the model that predicts and is drawn."""
        return self.members[-1]

    def model(self, member: Path) -> str:
        """How a message names a member's model: "2 s model" in a group of several, "model"
        alone."""
        if not self.named:
            return "model"
        return f"{self.horizons_s[self.members.index(member)]:g} s model"

    def who(self, member: Path) -> str:
        """The prefix of a member's lines: "the 2 s model: " in a group of several, "" alone."""
        return f"the {self.model(member)}: " if self.named else ""


def planned_group(run_dir: Path, horizons_s: tuple[float, ...]) -> Group:
    """The run that a fit of `horizons_s` writes into `run_dir`: one model in the folder itself,
    or several, each in its member folder (member_dir)."""
    if len(horizons_s) == 1:
        return Group(run_dir, horizons_s, (run_dir,))
    return Group(run_dir, horizons_s, tuple(member_dir(run_dir, h) for h in horizons_s))


def recorded_members(run_dir: Path) -> tuple[Path, ...]:
    """The model folders that `run_dir` records, without reading their run.json: those its
    horizons.json names, or else the folder itself."""
    horizons_s = read_horizons(run_dir)
    return (run_dir,) if horizons_s is None else planned_group(run_dir, horizons_s).members


def read_group(run_dir: Path) -> Group:
    """The run in `run_dir` as a group, whichever aigem wrote it: the members that its
    horizons.json names, or, without that file, the one model whose run.json the folder holds (a
    run of one horizon, as aigem 0.1.0 and every later aigem write it). One error line for a
    folder that holds neither."""
    horizons_s = read_horizons(run_dir)
    if horizons_s is not None:
        return planned_group(run_dir, horizons_s)
    return Group(run_dir, (read_record(run_dir).info.train.horizon_s,), (run_dir,))


def group_of_member(run_dir: Path) -> Group:
    """The run whose model `run_dir` holds: the group whose horizons.json (in the parent folder)
    names it, or else the run in `run_dir` itself (read_group)."""
    try:
        parent = read_horizons(run_dir.parent)
    except NgsimInputError:  # not a run's horizons.json: `run_dir` is no member of it
        parent = None
    if parent is not None and run_dir in planned_group(run_dir.parent, parent).members:
        return planned_group(run_dir.parent, parent)
    return read_group(run_dir)


def member_dir(run_dir: Path, horizon_s: float) -> Path:
    """The run directory of a multi-horizon run's model for `horizon_s`: RUN/h2s, RUN/h2.5s."""
    return run_dir / f"h{horizon_s:g}s"


def read_horizons(run_dir: Path) -> tuple[float, ...] | None:
    """The horizons of a multi-horizon run, from its horizons.json; None without that file."""
    path = run_dir / HORIZONS
    if not path.is_file():
        return None
    try:  # a JSONDecodeError is a ValueError; a list of other things, a TypeError
        return check_horizons_s(json.loads(path.read_text())["horizons_s"])
    except (ValueError, TypeError, KeyError, UnicodeDecodeError):
        raise NgsimInputError(path, "not aigem's list of horizons (damaged?)") from None


def write_horizons(group: Group) -> None:
    """A multi-horizon run's horizons.json: its horizons and the folders of their models."""
    names = [member.name for member in group.members]
    text = json.dumps({"horizons_s": list(group.horizons_s), "members": names}, indent=2) + "\n"
    write_atomic(group.run_dir / HORIZONS, text.encode())
