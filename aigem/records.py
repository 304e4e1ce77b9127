"""What a run directory records, read and checked without PyTorch: its file names, run.json,
horizons.json and baseline.json, and the build a run belongs to. aigem.refusals, aigem.runs and
aigem.checkpoints read runs through these.

run.json also records the sha256 of each checkpoint that the run keeps (DIGESTS), and a
checkpoint is loaded only if its bytes have one of them (aigem.checkpoints); a run written before
they were recorded (aigem 0.1.0's) has none, and its checkpoints are used unchecked, with a
warning.

Run info records each config as a mapping of its settings. A setting that a run lacks was added
to aigem after the run was written and takes its default (a new setting's default keeps what
aigem did before it), so that every older run loads; a setting this aigem does not know (a newer
aigem's) is one error line.

A build's identity is its config hash and the sha256 of its manifest's bytes: builds are
byte-deterministic, so an identical rebuild keeps it. Run info (run.json, and every checkpoint's
`info`) records it beside the build's path, settings (`build_config`: its config and its
source's physical limits, what the config hash covers) and fitted scaler, and the model and
train configs. Where a build's config hash is not the run's, the settings that differ are named.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from aigem.config import ModelConfig, TrainConfig, check_horizons_s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import manifest_path, read_manifest
from ngsim_graphs.manifest import Manifest, json_form
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
    """What run.json and every checkpoint record: INFO_KEYS (the build's scaler as its
    manifest.json holds it, its settings as its config hash covers them: `Manifest.settings`)."""
    manifest, identity = build_identity(build_dir)
    return {
        "build_dir": str(Path(build_dir).resolve()),
        **identity,
        "build_config": manifest.settings(),
        "scaler": json_form(manifest.scaler.to_dict()),
        "model": model_config.to_dict(),
        "train": train.to_dict(),
    }


def identity_difference(
    run: dict[str, Any], identity: dict[str, str], settings: dict[str, Any] | None = None
) -> str | None:
    """How a build's identity differs from the one a run recorded (None: the same build); with
    the build's `settings` (`Manifest.settings`), the settings that differ from the run's
    build_config, named ("d_min_m 25.0 -> 50.0", "limits.max_frame_id 72000 -> 180000")."""
    if identity["build_config_hash"] != run["build_config_hash"]:
        changed = settings_changed(run["build_config"], settings) if settings else []
        return (
            f"its config hash {identity['build_config_hash'][:12]} is not the run's "
            f"{run['build_config_hash'][:12]}" + (f": {'; '.join(changed)}" if changed else "")
        )
    if identity["build_manifest_sha256"] != run["build_manifest_sha256"]:
        return "same config, but its manifest.json differs from the run's build (other inputs, or edited)"
    return None


def _flat(settings: Any) -> dict[str, Any]:
    """A build's settings one per key, nested ones (the limits) as "limits.max_speed_mps"."""
    if not isinstance(settings, dict):
        return {}
    return {
        f"{name}.{key}" if isinstance(value, dict) else name: inner
        for name, value in settings.items()
        for key, inner in (value.items() if isinstance(value, dict) else [(name, value)])
    }


def settings_changed(before: Any, now: dict[str, Any]) -> list[str]:
    """The settings of `now` that differ from `before` (a run's build_config), in words: a
    highD build made before its limits were its own recorded max_frame_id in NGSIM's 10 Hz
    frames, so that built again it reads "limits.max_frame_id 72000 -> 180000"."""
    old, new = _flat(before), _flat(now)
    return [
        f"{name} {old.get(name)} -> {new.get(name)}"
        for name in sorted(old.keys() | new.keys())
        if old.get(name) != new.get(name)
    ]


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
    """The train config a run recorded, settings it lacks at their defaults (_recorded_values).
    An aigem before the settings were checked finite took `--max-minutes inf`, no limit, which
    reads as the None that says it now."""
    values = _recorded_values(info, "train", TrainConfig, path)
    if values.get("max_minutes") == math.inf:
        values = {**values, "max_minutes": None}
    try:
        return TrainConfig(**values)
    except (TypeError, ValueError) as err:
        raise NgsimInputError(path, f"a train config this aigem cannot use: {err}") from None


def model_config(info: dict[str, Any], path: Path) -> ModelConfig:
    """The model config a run recorded, settings it lacks at their defaults (_recorded_values);
    an error for a value of another type than the setting's."""
    values, defaults = dict(_recorded_values(info, "model", ModelConfig, path)), ModelConfig()
    for name, value in values.items():
        default = getattr(defaults, name)
        if isinstance(default, tuple) and isinstance(value, list):  # JSON's form of a tuple
            values[name] = value = tuple(value)
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


def recorded_digests(run: dict[str, Any], path: Path) -> dict[str, list[str]] | None:
    """The sha256 values that run.json (`run`, read from `path`) accepts for each checkpoint;
    None for a run written before they were recorded."""
    if DIGESTS not in run:
        return None
    digests = run[DIGESTS]
    if not isinstance(digests, dict) or not all(
        isinstance(accepted, list) and accepted and all(SHA256.fullmatch(str(d)) for d in accepted)
        for accepted in digests.values()
    ):
        raise NgsimInputError(path, f"its {DIGESTS} is not aigem's record of its checkpoints")
    return digests


def accepted_digests(run: dict[str, Any], run_dir: Path, name: str) -> list[str] | None:
    """The sha256 values that checkpoint `name` of the run in `run_dir` (its run.json: `run`)
    may have; None for a run that records none (UNRECORDED). A run that records them but none of
    `name` refuses it: a checkpoint that the run did not keep."""
    recorded = recorded_digests(run, run_dir / RUN_INFO)
    if recorded is None:
        return None
    if name not in recorded:
        raise NgsimInputError(
            run_dir / name, f"{RUN_INFO} records no sha256 of it: not a checkpoint this run kept"
        )
    return recorded[name]


def unrecorded_checkpoints(run_dir: Path, names: tuple[str, ...] = (BEST, LAST)) -> list[Path]:
    """The checkpoints `names` of each model of a run whose run.json records no sha256 of them
    (UNRECORDED): used unchecked."""
    return [
        member / name
        for member in read_group(run_dir).members
        if (member / RUN_INFO).is_file() and DIGESTS not in read_run_info(member)
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
    info = read_run_info(run_dir)
    return Group(run_dir, (train_config(info, run_dir / RUN_INFO).horizon_s,), (run_dir,))


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


# ------------------------------------------------------------------------------------------------
# baseline.json: constant velocity's validation loss (aigem.baseline measures it).


def write_baseline(run_dir: Path, val_loss_m2: float, steps: int) -> None:
    """Record constant velocity's validation loss (metres^2) over `steps` future steps."""
    text = json.dumps({"constant_velocity_val_loss_m2": val_loss_m2, "steps": steps}) + "\n"
    write_atomic(run_dir / BASELINE, text.encode())


def read_baseline(run_dir: Path) -> float | None:
    """Constant velocity's validation loss (metres^2) as fit recorded it; None when the run has
    none (a run of an older aigem) or it is unreadable: a missing baseline only costs the line."""
    try:
        value = json.loads((run_dir / BASELINE).read_text())["constant_velocity_val_loss_m2"]
    except (OSError, ValueError, TypeError, KeyError):
        return None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def read_metrics(run_dir: Path) -> list[dict[str, float]]:
    """The rows of metrics.jsonl; one line naming the file and line where it is damaged."""
    path = run_dir / METRICS
    if not path.exists():
        return []
    rows = []
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        try:
            row = json.loads(line) if line.strip() else None
        except json.JSONDecodeError:
            row = "damaged"
        if row is None:
            continue
        if not isinstance(row, dict) or not isinstance(row.get("epoch"), int):
            raise NgsimInputError(path, "not a row of aigem's metrics log (damaged?)", line=number)
        rows.append(row)
    return rows
