"""A run's checkpoints, read back safely and checked (what they record: aigem.records).

Checkpoints are loaded with `weights_only=True` (tensors and plain data only: loading
never runs code from the file) and checked against what `aigem fit` writes, their bytes against
the sha256 that the run's run.json records (aigem.records.DIGESTS); anything else is one
`NgsimInputError` naming the file.
"""

from __future__ import annotations

import hashlib
import io
import re
import warnings
from collections.abc import Collection
from pathlib import Path
from typing import Any

import torch

from aigem.model import AiGem
from aigem.records import check_info, model_config
from ngsim_graphs.errors import NgsimInputError

BEST_KEYS, LAST_KEYS = ("info", "model", "epoch"), ("info", "model", "optimizer", "state")
ALTERED = (
    "its bytes do not match the sha256 that run.json records for it: damaged or edited since "
    "fit kept it"
)


# ------------------------------------------------------------------------------------------------
# Reading checkpoints.


def checkpoint_sha256(data: bytes) -> str:
    """The sha256 of a checkpoint's bytes, as run.json records it (integrity.file_sha256's, of
    the bytes in hand: those checked are those loaded)."""
    return hashlib.sha256(data).hexdigest()


def load_checkpoint(
    path: Path, keys: tuple[str, ...], accepted: Collection[str] | None
) -> dict[str, Any]:
    """A checkpoint written by `aigem fit`, loaded without running anything from the file; its
    bytes must have one of the sha256 values `accepted` (aigem.records.accepted_digests; None:
    a run that records none, unchecked)."""
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
    if accepted is not None and checkpoint_sha256(data) not in accepted:
        raise NgsimInputError(path, ALTERED)
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
    that a foreign config (a huge width, say) allocates nothing before it is refused. Loading
    leaves torch's global generator as it was (the model's initial draws are forked off)."""
    config = model_config(info, path)
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
