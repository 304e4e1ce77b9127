"""Intervals over seeds: hand-computed means and t intervals, the t quantiles against the table
and the expansion, and the coverage of the interval on draws of a known normal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aigem.intervals import Interval, seed_interval, t_975


def test_seed_interval_of_three_values_by_hand() -> None:
    # mean 2, sd 1 (deviations -1, 0, 1 over N - 1 = 2), half-width 4.303 / sqrt(3)
    interval = seed_interval([1.0, 2.0, 3.0])
    half = 4.303 / math.sqrt(3)
    assert interval.value == 2.0
    assert interval.low == pytest.approx(2.0 - half)
    assert interval.high == pytest.approx(2.0 + half)
    assert interval.known and interval.excludes(4.6) and not interval.excludes(-0.4)


def test_one_seed_has_a_value_and_no_interval() -> None:
    interval = seed_interval([1.5])
    assert interval == Interval(1.5)
    assert not interval.known and not interval.excludes(100.0)
    assert interval.as_dict() == {"value": 1.5, "low": None, "high": None}


def test_missing_values_and_no_values_are_refused() -> None:
    with pytest.raises(ValueError, match="missing"):
        seed_interval([1.0, float("nan")])
    with pytest.raises(ValueError, match="at least one"):
        seed_interval([])
    with pytest.raises(ValueError, match="degrees of freedom"):
        t_975(0)


def test_t_quantiles_meet_the_normal_and_join_the_table() -> None:
    assert t_975(1) == 12.706 and t_975(30) == 2.042
    assert t_975(31) == pytest.approx(2.0395, abs=1e-3)  # tables: 2.040
    assert t_975(60) == pytest.approx(2.000, abs=1e-3)
    assert t_975(120) == pytest.approx(1.980, abs=1e-3)
    assert t_975(10**6) == pytest.approx(1.95996, abs=1e-4)


def test_the_interval_covers_the_mean_95_percent_of_the_time() -> None:
    rng = np.random.default_rng(0)
    trials, covered = 4000, 0
    for draws in rng.normal(10.0, 2.0, size=(trials, 3)):
        interval = seed_interval(draws.tolist())
        covered += interval.low <= 10.0 <= interval.high
    # binomial sd of the share over 4000 trials: 0.0034; 4 sd either side
    assert abs(covered / trials - 0.95) < 0.014
