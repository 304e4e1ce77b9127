"""The capacities of static batches, computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from aigem.training import capacity
from aigem.training.capacity import Capacity


def test_a_capacity_is_the_mean_of_a_batch_plus_four_deviations_rounded_up() -> None:
    # Two quantities; per sample 1 or 3 (mean 2, sd 1), and 10 always (sd 0).
    counts = np.array([[1, 10], [3, 10], [1, 10], [3, 10]])
    base = capacity.base_capacity(counts, batch_size=4, layers=0)
    # 4 * 2 + 4 * sqrt(4) * 1 = 16; 4 * 10 + 0 = 40; both multiples of 8 already
    assert base == Capacity(4, (16, 40), 0)
    # one sample: 2 + 4 = 6 -> 8; 10 -> 16 (rounded up to a multiple of 8)
    assert capacity.base_capacity(counts, 1, 0).sizes == (8, 16)


def test_segments_of_nodes_then_each_edge_types() -> None:
    layers = 2
    assert capacity.quantities(layers, edge_types=2) == 3 + 2 * 2
    cap = Capacity(8, (1, 2, 3, 4, 5, 6, 7), layers)
    assert cap.nodes == (1, 2, 3) and cap.targets == 1
    assert cap.edges(0) == (4, 5) and cap.edges(1) == (6, 7)


def test_a_batch_takes_the_first_tier_that_holds_it() -> None:
    base = Capacity(4, (16, 40), 0)
    assert capacity.tier(base, 0) is base
    assert capacity.tier(base, 1).sizes == (24, 56)  # 20 -> 24, 50 -> 56
    assert capacity.tier(base, 2).sizes == (32, 64)  # 25 -> 32, 62.5 -> 64
    assert capacity.tier_of(base, np.array([16, 40])) == 0  # met exactly
    assert capacity.tier_of(base, np.array([17, 0])) == 1
    assert capacity.tier_of(base, np.array([0, 57])) == 2
    assert capacity.tier_of(base, np.array([25, 0])) == 2
    big = capacity.tier_of(base, np.array([1000, 0]))
    assert capacity.tier(base, big).holds(np.array([1000, 0]))
    assert not capacity.tier(base, big - 1).holds(np.array([1000, 0]))


def test_no_sample_no_capacity() -> None:
    with pytest.raises(ValueError, match="at least one sample"):
        capacity.base_capacity(np.zeros((0, 3)), 4, 1)
