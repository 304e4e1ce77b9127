"""The device of `--device`, and a batch moved onto it."""

from __future__ import annotations

import pytest
import torch

from aigem.devices import DeviceUnavailableError, pick_device, to_device


def test_pick_device() -> None:
    assert pick_device("cpu") == torch.device("cpu")
    has_cuda = torch.cuda.is_available()
    assert pick_device("auto").type == ("cuda" if has_cuda else "cpu")
    if not has_cuda:
        with pytest.raises(DeviceUnavailableError, match="--device cuda: no CUDA device"):
            pick_device("cuda")


def test_to_device_moves_tensors_and_keeps_the_rest() -> None:
    batch = {"target_xy": torch.ones(2, 3, 2), "graphs": 2, "plan": None}
    moved = to_device(batch, torch.device("cpu"))
    assert set(moved) == set(batch) and moved["graphs"] == 2 and moved["plan"] is None
    assert torch.equal(moved["target_xy"], batch["target_xy"])
    assert moved["target_xy"].device == torch.device("cpu")
