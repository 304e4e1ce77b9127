"""The learning rate of every step of `aigem fit`, and gradient clipping (each model's own).

The rate is a pure function of where the step is (its epoch and its batch in the epoch): a resumed
run sets exactly the rates an uninterrupted one would, with nothing to keep in the checkpoint.

- `constant` (the paper's Adam at `learning_rate`), or `cosine`: from `learning_rate` down to 0
  at the end of the last epoch (`epochs`) along half a cosine.
- `warmup_epochs` > 0: the rate first rises linearly from `learning_rate / warm-up steps` to
  `learning_rate` over that many epochs (fractions allowed); a cosine decay starts after it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch

from aigem.config import TrainConfig


def learning_rate_at(train: TrainConfig, epoch: int, batch: int, batches_per_epoch: int) -> float:
    """The rate of the step on batch `batch` (0-based) of epoch `epoch` (0-based)."""
    step = epoch * batches_per_epoch + batch  # steps before this one
    warmup_steps = train.warmup_epochs * batches_per_epoch
    if step < warmup_steps:  # a warm-up ending within a step reaches the full rate at that step
        return train.learning_rate * min((step + 1) / warmup_steps, 1.0)
    if train.lr_schedule == "cosine":
        decay_steps = train.epochs * batches_per_epoch - warmup_steps
        done = min((step - warmup_steps) / decay_steps, 1.0)
        return train.learning_rate * 0.5 * (1.0 + math.cos(math.pi * done))
    return train.learning_rate


def set_learning_rate(optimizer: torch.optim.Optimizer, rate: float) -> None:
    """The rate of the next step; a capturable optimizer's is a device tensor, filled in place
    (a captured step reads it there, aigem.training.engine)."""
    for group in optimizer.param_groups:
        if isinstance(group["lr"], torch.Tensor):
            group["lr"].fill_(rate)
        else:
            group["lr"] = rate


def clip_gradients(parameters: Iterable[torch.Tensor], max_norm: float | None) -> None:
    """Scale each member's gradients down to a total L2 norm of `max_norm` where it is larger
    (None: leave them): `parameters` stacked over M members (M, ...), member m's total the norm
    of all its gradients, as `torch.nn.utils.clip_grad_norm_` of its model alone (whose 1e-6
    it keeps: a clipped member steps as its model alone, tests/test_aigem_ensemble.py). On the
    device, without reading the norm back: the step does not wait for the GPU."""
    if max_norm is None:
        return
    grads = [p.grad for p in parameters if p.grad is not None]
    norms = torch.stack([torch.linalg.vector_norm(g.flatten(1), dim=1) for g in grads])
    total = torch.linalg.vector_norm(norms, dim=0)  # (M,)
    scale = torch.clamp(max_norm / (total + 1e-6), max=1.0)
    for grad in grads:
        grad.mul_(scale.view(-1, *[1] * (grad.dim() - 1)))
