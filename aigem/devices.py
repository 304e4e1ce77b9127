"""Where a model runs: the device chosen for `--device`, and a batch moved onto it."""

from __future__ import annotations

from typing import Any

import torch


class DeviceUnavailableError(ValueError):
    """The device asked for is not on this machine."""


def pick_device(choice: str) -> torch.device:
    """'auto' takes CUDA when present; 'cuda' without a GPU is an error."""
    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if choice == "cuda" and not torch.cuda.is_available():
        raise DeviceUnavailableError("--device cuda: no CUDA device is available")
    return torch.device(choice)


def to_device(batch: dict[str, Any], device: torch.device) -> dict[str, Any]:
    """The batch's tensors and plan on `device` (copies from pinned memory do not wait)."""
    return {k: v.to(device, non_blocking=True) if hasattr(v, "to") else v for k, v in batch.items()}
