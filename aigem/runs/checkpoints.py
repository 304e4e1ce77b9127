"""A run's checkpoints, written and read back safely and checked (what they record:
aigem.runs.records), and a run's models loaded from them (`load_model`).

    best.pt   {"info": run info, "model": weights, "epoch": from 0}
    last.pt   {"info": run info, "model": weights, "optimizer": Adam's state, "state": progress}

Every checkpoint carries run.json's content but the digests as its `info` (aigem.runs.records.RunInfo),
so a checkpoint alone says which build it belongs to and how its inputs are scaled. Checkpoints
are loaded with `weights_only=True` (tensors and plain data only: loading never runs code from
the file) and checked against what `aigem fit` writes, their bytes against the sha256 that the
run's run.json records (aigem.runs.records.DIGESTS), their info against run.json's, and last.pt's
epochs against the log (`check_log`); anything else is one `NgsimInputError` naming the file.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import warnings
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from aigem.model.network import AiGem
from aigem.runs.records import (
    BEST,
    IDENTITY,
    LAST,
    METRICS,
    RUN_INFO,
    Group,
    RunInfo,
    RunState,
    accepted_digests,
    info_of,
    read_record,
    state_json,
    state_of,
)
from aigem.runs.run_log import read_metrics
from ngsim_graphs.errors import NgsimInputError

BEST_KEYS, LAST_KEYS = ("info", "model", "epoch"), ("info", "model", "optimizer", "state")
ALTERED = (
    "its bytes do not match the sha256 that run.json records for it: damaged or edited since "
    "fit kept it"
)


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint as `aigem fit` keeps it: the run info it carries, its model's weights (a
    state dict, checked where a model loads them: check_weights) and, a last.pt's, the
    optimiser's state and the run's progress."""

    info: RunInfo
    weights: object
    optimizer: object = None
    state: RunState | None = None


# ------------------------------------------------------------------------------------------------
# Writing and reading checkpoints.


def _serialised(payload: dict[str, Any]) -> bytes:
    buffer = io.BytesIO()  # serialised in memory, so that every disk error is Python's OSError
    torch.save(payload, buffer)
    return buffer.getvalue()


def best_bytes(info: RunInfo, weights: dict[str, torch.Tensor], epoch: int) -> bytes:
    """best.pt's bytes: the model of epoch `epoch` (from 0) of the run `info`."""
    return _serialised({"info": info.to_json(), "model": weights, "epoch": epoch})


def last_bytes(
    info: RunInfo, weights: dict[str, torch.Tensor], optimizer: dict[str, Any], state: RunState
) -> bytes:
    """last.pt's bytes: the model, its optimiser's state and the run's progress `state`."""
    payload = {"info": info.to_json(), "model": weights, "optimizer": optimizer}
    return _serialised({**payload, "state": state_json(state)})


def checkpoint_sha256(data: bytes) -> str:
    """The sha256 of a checkpoint's bytes, as run.json records it (integrity.file_sha256's, of
    the bytes in hand: those checked are those loaded)."""
    return hashlib.sha256(data).hexdigest()


def load_checkpoint(
    path: Path, keys: tuple[str, ...], accepted: Collection[str] | None
) -> Checkpoint:
    """A checkpoint written by `aigem fit` (BEST_KEYS or LAST_KEYS), loaded without running
    anything from the file; its bytes must have one of the sha256 values `accepted`
    (aigem.runs.records.accepted_digests; None: a run that records none, unchecked)."""
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
    info = info_of(checkpoint["info"], path)
    state = state_of(checkpoint["state"], path) if "state" in keys else None
    if accepted is not None and checkpoint_sha256(data) not in accepted:
        raise NgsimInputError(path, ALTERED)
    return Checkpoint(info, checkpoint["model"], checkpoint.get("optimizer"), state)


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


def fitted_model(info: RunInfo, weights: object, path: Path) -> AiGem:
    """The model of a checkpoint's config with its weights; checked on the meta device first, so
    that a foreign config (a huge width, say) allocates nothing before it is refused. Loading
    leaves torch's global generator as it was (the model's initial draws are forked off)."""
    config = info.model
    try:
        with torch.device("meta"):
            skeleton = AiGem(config)
    except (RuntimeError, ValueError, TypeError) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise NgsimInputError(path, f"a model config this aigem cannot build: {reason}") from None
    check_weights(skeleton.state_dict(), weights, path)
    with torch.random.fork_rng(devices=[]):  # to_empty: 0.3 s to import torch.fx's shapes
        model = AiGem(config)
    model.load_state_dict(weights)  # type: ignore[arg-type]
    return model


# ------------------------------------------------------------------------------------------------
# A run's models, loaded and checked against its records.


def check_same_run(saved: RunInfo, run: RunInfo, path: Path) -> None:
    """A checkpoint (`path`, carrying `saved`) from another run (another build, model or
    horizon) than the one run.json records (`run`) is not this run's. The model configs are
    compared as read (settings a best.pt kept before a resume rewrote run.json lacks take their
    defaults)."""
    ours, theirs = saved.build.identity, run.build.identity
    sameness = (
        ours.config_hash == theirs.config_hash,
        ours.manifest_sha256 == theirs.manifest_sha256,
    )
    for name, same in zip(IDENTITY, sameness, strict=True):
        if not same:
            raise NgsimInputError(
                path, f"belongs to another run: its {name} differs from {RUN_INFO}'s"
            )
    if saved.model != run.model:
        raise NgsimInputError(path, f"belongs to another run: its model differs from {RUN_INFO}'s")
    if saved.train.horizon_s != run.train.horizon_s:
        raise NgsimInputError(
            path, f"belongs to another run: its horizon differs from {RUN_INFO}'s"
        )


def load_model(
    run_dir: str | os.PathLike[str], device: torch.device | str = "cpu"
) -> tuple[AiGem, RunInfo]:
    """The best model of a run and the run info its checkpoint carries."""
    run_dir = Path(run_dir)
    run = read_record(run_dir)
    path = run_dir / BEST
    if not path.is_file():
        raise NgsimInputError(run_dir, f"not a finished run: no {BEST} (no epoch has finished yet)")
    checkpoint = load_checkpoint(path, BEST_KEYS, accepted_digests(run, run_dir, BEST))
    check_same_run(checkpoint.info, run.info, path)
    if (run_dir / LAST).is_file():  # a run kept without it has no other record of its epochs
        check_log(run_dir, epochs_kept(run_dir))
    model = fitted_model(checkpoint.info, checkpoint.weights, path)
    return model.to(device).eval(), checkpoint.info


def epochs_kept(run_dir: Path) -> int:
    """The epochs whose checkpoint a run directory holds (its last.pt's), 0 without one."""
    path = run_dir / LAST
    if not path.is_file():
        return 0
    accepted = accepted_digests(read_record(run_dir), run_dir, LAST)
    return load_checkpoint(path, LAST_KEYS, accepted).state.next_epoch


def check_log(run_dir: Path, kept: int) -> None:
    """Refuse a run whose metrics.jsonl disagrees with its last.pt, which holds `kept` epochs:
    the log holds epochs 1, 2, ... in order, up to last.pt's or one more (a fit stopped between
    logging an epoch and keeping its last.pt; a resume redoes that epoch). A log that lost its
    last line would have evaluate call the run unfinished while it scores a later model, and a
    resume leave a hole in it."""
    logged = [row.epoch for row in read_metrics(run_dir)]
    in_order = logged == list(range(1, len(logged) + 1))
    if in_order and kept <= len(logged) <= kept + 1:
        return
    if not logged:
        said = "logs no epoch"
    elif in_order:
        said = f"ends at epoch {logged[-1]}"
    else:
        said = f"logs epochs {', '.join(map(str, logged))}, not 1 to {max(logged)} in order,"
    raise NgsimInputError(
        run_dir,
        f"its {METRICS} {said} but its {LAST} holds epoch {kept}: the log lost lines or was "
        f"edited; put back the {METRICS} this run wrote, or fit a new run into another --out",
    )


def check_logs(group: Group) -> None:
    """check_log for each model of `group` that holds a last.pt (before a resume writes)."""
    for member in group.members:
        if (member / LAST).is_file():
            check_log(member, epochs_kept(member))
