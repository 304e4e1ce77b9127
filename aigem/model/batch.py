"""A batch of graphs as AiGem reads it: one typed dataclass for every kind of batch.

`aigem.model.data.Collate` makes it from the loader's graphs, `aigem.training.resident.ResidentSplit.batch`
assembles a static one on the device, and `aigem.model.pyg.to_model_batch` turns a PyTorch Geometric
batch into one. The model, the loss, the training step, validation and scoring read its fields
by name. It moves to a device with `to` and pins its memory with `pin_memory` (a DataLoader's
`pin_memory=True` calls it), and a DataLoader's worker processes hand it over as they hand over
tensors.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import torch

from aigem.model.plan import Plan


@dataclass(frozen=True)
class Edges:
    """One edge type's edges: `index` (2, E) int64, each edge's source and destination node in
    the batch; `attr` (E, 1) float32, its attribute as the build's scaler gives it (spatial: the
    distance scaled to (0, 1); temporal: the time step, seconds, not scaled)."""

    index: torch.Tensor
    attr: torch.Tensor


@dataclass(frozen=True)
class Batch:
    """B graphs of N nodes in all, A target actors, K future steps of 0.2 s (the build's time
    step), in the sample frame of each graph's ego (x lateral, y along the road, metres, the ego
    at (0, 0) at the present step).

    x             (N, 4) float32: each node's [x, y, heading, speed], scaled by the scaler
                  (x, y, heading to (-1, 1), speed to (0, 1))
    target_node   (A,) int64: each target's node (its present step)
    target_sample (A,) int64: each target's graph, 0..B-1 (-1: a padded target of a static
                  batch, which counts in no loss or metric)
    target_xy     (A, K, 2) float32: each target's recorded future positions, metres; 0 where
                  masked
    target_mask   (A, K) bool: True where the target's position is recorded
    edges         each edge type of the build by name, in its order (`Edges`); empty in a
                  static batch, whose edges are its plan's
    node_sample   (N,) int64: each node's graph (None in a static batch)
    target_state  (A, 4) float32: each target's present [x m, y m, heading rad, speed m/s],
                  not scaled (None from PyG)
    cv_step       (A, 2) float32: constant velocity's displacement over one time step (the
                  present speed along the present heading), scaled units; what a model with
                  `cv_residual` adds to each step (None from PyG)
    plan          the encoder's plan of L layers (`aigem.model.plan.Plan`: which nodes each layer
                  computes, host sizes), made beforehand so that a step reads no number back;
                  None: the model makes it
    graphs        B, a Python int (a static batch: its capacity's, padding included)
    """

    x: torch.Tensor
    target_node: torch.Tensor
    target_sample: torch.Tensor
    target_xy: torch.Tensor
    target_mask: torch.Tensor
    edges: dict[str, Edges] = field(default_factory=dict)
    node_sample: torch.Tensor | None = None
    target_state: torch.Tensor | None = None
    cv_step: torch.Tensor | None = None
    plan: Plan | None = None
    graphs: int = 0

    @property
    def edge_types(self) -> tuple[str, ...]:
        """The names of the batch's edge types (the build's), in their order."""
        return tuple(self.edges)

    def edge_inputs(
        self, names: tuple[str, ...] | None = None
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(index (2, E), attr (E, 1)) of each edge type `names` (None: the batch's own), in
        that order: what `aigem.model.plan.make_plan` takes."""
        return [(self.edges[name].index, self.edges[name].attr) for name in names or self.edges]

    def to(
        self,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
        non_blocking: bool = False,
    ) -> Batch:
        """The batch on `device` (None: where it is), its floating tensors as `dtype` (None: as
        they are); copies from pinned memory need not wait with `non_blocking`."""
        cast = lambda t: dtype if dtype is not None and t.is_floating_point() else None  # noqa: E731
        return self._map(
            lambda t: t.to(device=device, dtype=cast(t), non_blocking=non_blocking),
            lambda plan: plan.to(device, non_blocking, dtype),
        )

    def pin_memory(self) -> Batch:
        """The batch in pinned host memory (a DataLoader's `pin_memory=True` calls it)."""
        return self._map(lambda t: t.pin_memory(), lambda plan: plan.pin_memory())

    def _map(
        self, each: Callable[[torch.Tensor], torch.Tensor], plan_of: Callable[[Plan], Plan]
    ) -> Batch:
        """The batch with `each` applied to every tensor and `plan_of` to its plan."""
        tensors = {name: getattr(self, name) for name in _TENSORS}
        return replace(
            self,
            **{name: None if t is None else each(t) for name, t in tensors.items()},
            edges={name: Edges(each(e.index), each(e.attr)) for name, e in self.edges.items()},
            plan=None if self.plan is None else plan_of(self.plan),
        )


_TENSORS = (  # Batch's tensor fields (its edges and plan hold the others)
    "x",
    "target_node",
    "target_sample",
    "target_xy",
    "target_mask",
    "node_sample",
    "target_state",
    "cv_step",
)
