"""Where a model runs: the device chosen for `--device` (a batch moves itself: `Batch.to`)."""

from __future__ import annotations

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
