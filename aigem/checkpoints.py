"""What a run records of its build and model, and its files read back safely and checked.

A build's identity is its config hash and the sha256 of its manifest's bytes: builds are
byte-deterministic, so an identical rebuild keeps it. Run info (run.json, and every checkpoint's
`info`) records it beside the build's path, config and fitted scaler, and the model and train
configs. Checkpoints are loaded with `weights_only=True` (tensors and plain data only: loading
never runs code from the file) and checked against what `aigem fit` writes; anything else is one
`NgsimInputError` naming the file.
"""

from __future__ import annotations

import hashlib
import io
import re
import warnings
from dataclasses import fields
from pathlib import Path
from typing import Any

import torch

from aigem.config import ModelConfig, TrainConfig
from aigem.model import AiGem
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import manifest_path, read_manifest
from ngsim_graphs.manifest import Manifest, json_form

IDENTITY = ("build_config_hash", "build_manifest_sha256")  # a build's identity, as a run records it
INFO_KEYS = ("build_dir", *IDENTITY, "build_config", "scaler", "model", "train")
BEST_KEYS, LAST_KEYS = ("info", "model", "epoch"), ("info", "model", "optimizer", "state")


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


# ------------------------------------------------------------------------------------------------
# Reading checkpoints.


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
    try:
        TrainConfig(**info["train"])
    except (TypeError, ValueError) as err:
        raise NgsimInputError(path, f"unknown train config: {err}") from None


def model_config(info: dict[str, Any], path: Path) -> ModelConfig:
    """The model config a run recorded; an error for settings or types this aigem does not know."""
    values, defaults = info.get("model"), ModelConfig()
    if not isinstance(values, dict):
        raise NgsimInputError(path, "no model config")
    known = {f.name for f in fields(ModelConfig)}
    unknown, missing = sorted(set(values) - known), sorted(known - set(values))
    if unknown or missing:
        raise NgsimInputError(
            path, f"a model config this aigem does not know (unknown {unknown}, missing {missing})"
        )
    for name, value in values.items():
        default = getattr(defaults, name)
        if type(value) is not type(default) and not (type(default) is float and type(value) is int):
            raise NgsimInputError(
                path, f"model config {name} = {value!r}: expected a {type(default).__name__}"
            )
    return ModelConfig(**values)


def load_checkpoint(path: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    """A checkpoint written by `aigem fit`, loaded without running anything from the file."""
    data = path.read_bytes()  # a file-system error is an OSError naming the file; after this,
    if not data:  # any error is the content's
        raise NgsimInputError(path, "empty checkpoint (0 bytes): the run is damaged")
    try:
        with warnings.catch_warnings():  # torch warns about what it then refuses: one line only
            warnings.simplefilter("ignore")
            checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - damaged bytes raise RuntimeError, OSError, EOFError,
        # UnpicklingError, UnicodeDecodeError, KeyError, ValueError, ... (found by fuzzing)
        blocked = re.search(r"GLOBAL (\S+)", str(err))
        if blocked:
            raise NgsimInputError(
                path,
                f"refused: loading it would call {blocked.group(1)}; a checkpoint "
                "holds tensors and plain data only (nothing in it was run)",
            ) from None
        raise NgsimInputError(
            path,
            f"unreadable checkpoint: truncated, damaged or not a torch file ({type(err).__name__})",
        ) from None
    if not isinstance(checkpoint, dict) or not all(key in checkpoint for key in keys):
        found = (
            f"keys {sorted(map(str, checkpoint))[:4]}"
            if isinstance(checkpoint, dict)
            else type(checkpoint).__name__
        )
        raise NgsimInputError(
            path, f"not an aigem checkpoint: expected {', '.join(keys)}, found {found}"
        )
    check_info(checkpoint["info"], path)
    return checkpoint


def check_weights(expected: dict[str, torch.Tensor], weights: object, path: Path) -> None:
    """Refuse a state dict that does not fit `expected` (a model's) exactly, in one line."""
    if not isinstance(weights, dict) or not all(torch.is_tensor(v) for v in weights.values()):
        raise NgsimInputError(path, "its model weights are not a state dict of tensors")
    missing = [k for k in expected if k not in weights]
    unexpected = [k for k in weights if k not in expected]
    reshaped = [k for k in expected if k in weights and weights[k].shape != expected[k].shape]
    if missing or unexpected or reshaped:
        parts = [
            f"{label} {names[:2]}{'...' if len(names) > 2 else ''}"
            for label, names in (
                ("missing", missing),
                ("unexpected", unexpected),
                ("other shape", reshaped),
            )
            if names
        ]
        raise NgsimInputError(path, f"its weights do not fit its model config: {'; '.join(parts)}")


def fitted_model(info: dict[str, Any], weights: object, path: Path) -> AiGem:
    """The model of a checkpoint's config with its weights; checked on the meta device first, so
    that a foreign config (a huge width, say) allocates nothing before it is refused."""
    config = model_config(info, path)
    try:
        with torch.device("meta"):
            skeleton = AiGem(config)
    except (RuntimeError, ValueError, TypeError) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise NgsimInputError(path, f"a model config this aigem cannot build: {reason}") from None
    check_weights(skeleton.state_dict(), weights, path)
    model = AiGem(config)
    model.load_state_dict(weights)  # type: ignore[arg-type]
    return model
