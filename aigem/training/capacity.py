"""The capacities of static batches (docs/aigem.md): how many nodes and edges a padded batch holds.

A static batch (aigem.training.resident) lays its nodes out in segments by level (the last layer that
needs a node: L at the targets, down to 0 at the input steps that only the first layer reads),
and each edge type's edges in segments by their destination's level (L down to 1). Each segment
is padded to a fixed size, so that every batch of one `Capacity` has the same shapes and one
captured step replays for all of them.

The sizes come from the split's own statistics: per sample, its count in each segment (`counts`,
(S, Q) for Q = (L + 1) + types * L quantities). A batch of B samples holds B times the mean of
each count give or take sqrt(B) standard deviations; its capacity is the mean plus Z_SPREAD
standard deviations of that sum, rounded up to a multiple of ROUND. A batch that exceeds it takes
the next tier, the capacity times GROWTH^t: a tier is a few more captured steps, never a batch
cut or dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

Z_SPREAD = 4.0  # standard deviations of a batch's sum above its mean: few batches exceed it
GROWTH = 1.25  # each tier holds this much more than the one before
ROUND = 8  # segment sizes are multiples of this


def quantities(layers: int, edge_types: int) -> int:
    """Q: node segments (levels L..0) and each edge type's segments (destination levels L..1)."""
    return layers + 1 + edge_types * layers


def edge_columns(layers: int, type_index: int) -> slice:
    """Where edge type `type_index`'s L segments sit among the Q quantities."""
    first = layers + 1 + type_index * layers
    return slice(first, first + layers)


@dataclass(frozen=True)
class Capacity:
    """A static batch's padded sizes: `samples` graphs; `sizes` (Q,) the real entries each
    segment holds, in the order of `quantities` (node segments, then each edge type's)."""

    samples: int
    sizes: tuple[int, ...]
    layers: int

    @property
    def nodes(self) -> tuple[int, ...]:
        """(L + 1,) node segments, levels L..0; segment 0 holds the targets."""
        return self.sizes[: self.layers + 1]

    def edges(self, type_index: int) -> tuple[int, ...]:
        """(L,) the edge segments of edge type `type_index`, destination levels L..1."""
        return self.sizes[edge_columns(self.layers, type_index)]

    @property
    def targets(self) -> int:
        return self.sizes[0]

    def holds(self, need: np.ndarray) -> bool:
        """Whether a batch of these counts ((Q,) sums over its samples) fits."""
        return bool((np.asarray(need) <= np.asarray(self.sizes)).all())


def _round_up(value: float) -> int:
    return max(ROUND, int(math.ceil(value / ROUND)) * ROUND)


def base_capacity(counts: np.ndarray, batch_size: int, layers: int) -> Capacity:
    """Tier 0 for batches of `batch_size` samples of a split whose per-sample counts are `counts`
    (S, Q): each segment the mean of a batch's sum plus Z_SPREAD standard deviations."""
    counts = np.asarray(counts, dtype=np.float64)
    if counts.ndim != 2 or not len(counts):
        raise ValueError("a capacity needs the counts of at least one sample")
    mean, spread = counts.mean(0), counts.std(0)
    sizes = batch_size * mean + Z_SPREAD * math.sqrt(batch_size) * spread
    return Capacity(batch_size, tuple(_round_up(v) for v in sizes), layers)


def tier(base: Capacity, t: int) -> Capacity:
    """The capacity of tier t: tier 0's sizes times GROWTH^t, rounded up."""
    if t == 0:
        return base
    return Capacity(base.samples, tuple(_round_up(v * GROWTH**t) for v in base.sizes), base.layers)


def tier_of(base: Capacity, need: np.ndarray) -> int:
    """The first tier that holds a batch of these counts (Q,)."""
    ratio = float((np.asarray(need, dtype=np.float64) / np.asarray(base.sizes)).max())
    t = 0 if ratio <= 1 else max(0, math.ceil(math.log(ratio) / math.log(GROWTH)) - 1)
    while not tier(base, t).holds(need):  # the rounding: at most a step or two more
        t += 1
    return t
