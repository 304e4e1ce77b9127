"""The loss of `aigem fit`, written once: the squared error in metres^2 over the valid (unmasked)
future steps of each target.

Predictions are made in scaled coordinates and mapped back to metres before the loss, so x and y
weigh alike. `member_sums` gives each of M models' sums (training's mean, validation's pooled
mean and the ensemble's losses are its ratios), each member's bitwise its model's alone;
`masked_mse_m2` is the mean of one model's.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from aigem.model.batch import Batch
from aigem.model.data import xy_to_metres
from ngsim_graphs.scaling import MinMaxScaler


def member_sums(
    model_out: torch.Tensor,
    batch: Batch,
    scaler: MinMaxScaler,
    steps: Sequence[int] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(M,) each model's squared error in metres^2 summed over the valid target steps it is
    scored on, and (M,) their count; `model_out` (M, A, K, 2) scaled predictions of the batch's
    first K future steps; `steps` (M,) each model's first steps that count (None: all K).

    Member m's sums are bitwise those of its model alone (of `model_out[m, :, :steps[m]]`):
    each is summed over its own (A, steps[m]) errors, laid out as a model alone's, since a sum
    over (M, A, K) would add in another order. Its checkpoints record them (the best validation
    loss), so a member's are its model's alone."""
    members, _, longest, _ = model_out.shape
    steps = (longest,) * members if steps is None else steps
    predicted = xy_to_metres(scaler, model_out)  # (M, A, K, 2)
    mask = batch.target_mask[:, :longest].to(predicted.dtype)  # (A, K)
    squared = ((predicted - batch.target_xy[:, :longest]) ** 2).sum(dim=-1) * mask  # (M, A, K)
    sums = [squared[m, :, :k].contiguous().sum() for m, k in enumerate(steps)]
    # counts are whole numbers, exact in any order: each member's from the counts per step
    upto = mask.sum(0).cumsum(0)  # (K,) the valid target steps up to each step
    return torch.stack(sums), torch.stack([upto[k - 1] for k in steps])


def masked_mse_m2(
    model_out: torch.Tensor, batch: Batch, scaler: MinMaxScaler, steps: int
) -> torch.Tensor:
    """Mean squared error in metres^2 over the valid steps of one model's (A, steps, 2) scaled
    predictions (0 where no step is valid)."""
    squared, count = member_sums(model_out[None, :, :steps], batch, scaler)
    return squared[0] / count[0].clamp(min=1.0)
