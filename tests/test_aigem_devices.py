"""The device of `--device` (a batch moved onto it: tests/test_aigem_batch.py)."""

from __future__ import annotations

import pytest
import torch

from aigem.devices import DeviceUnavailableError, pick_device


def test_pick_device() -> None:
    assert pick_device("cpu") == torch.device("cpu")
    has_cuda = torch.cuda.is_available()
    assert pick_device("auto").type == ("cuda" if has_cuda else "cpu")
    if not has_cuda:
        with pytest.raises(DeviceUnavailableError, match="--device cuda: no CUDA device"):
            pick_device("cuda")
