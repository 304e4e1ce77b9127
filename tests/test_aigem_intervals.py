"""Intervals over seeds: hand-computed means and t intervals, the t quantiles against the table
and the expansion, and the coverage of the interval on draws of a known normal. Intervals within
a run (the bootstrap over whole samples): a hand-computed case, a plain loop's percentiles, the
coverage of a known ratio, the paired difference, the seed, and what it refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aigem.intervals import (
    RESAMPLES,
    SEED,
    Interval,
    bootstrap_intervals,
    resampled_sums,
    seed_interval,
    t_975,
)
from aigem.metrics import SampleTotals, compute_ade_m, compute_fde_m, compute_rmse_m


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


# The bootstrap within one run: whole samples resampled, metrics recomputed from the sums.


def _sample_totals(errors: list[np.ndarray], masks: list[np.ndarray]) -> SampleTotals:
    """SampleTotals of samples given as their targets' (A_i, K) errors (m) and masks."""
    totals = SampleTotals(len(errors), errors[0].shape[1])
    for sample, (error, mask) in enumerate(zip(errors, masks, strict=True)):
        totals.add(np.where(mask, error, 0.0), mask, np.full(len(error), sample))
    return totals


def test_three_samples_by_hand() -> None:
    """One target a sample, off by 1, 2 and 4 m at each of its 5 steps (1 s); constant velocity
    1 m further off everywhere. ADE is 7/3 and RMSE at 1 s sqrt(21 / 3). Of the 27 equally
    likely resamples, each sample drawn thrice (1/27 = 3.7 % > 2.5 % each) gives the extremes:
    the interval runs from 1 to 4 m. The paired difference of ADE is -1 m on every resample."""
    ours = [np.full((1, 5), e) for e in (1.0, 2.0, 4.0)]
    masks = [np.ones((1, 5), bool)] * 3
    model = _sample_totals(ours, masks)
    baseline = _sample_totals([e + 1.0 for e in ours], masks)
    result = bootstrap_intervals(model, baseline, 0.2, resamples=4000, seed=0)
    assert list(result.metrics) == ["ade_m", "fde_m", "rmse_1s_m"]  # not the counts
    assert (result.resamples, result.seed, result.samples) == (4000, 0, 3)
    ade = result.metrics["ade_m"]
    assert ade.model == Interval(pytest.approx(7 / 3), 1.0, 4.0)
    assert ade.constant_velocity == Interval(pytest.approx(10 / 3), 2.0, 5.0)
    assert ade.difference == Interval(pytest.approx(-1.0), pytest.approx(-1.0), pytest.approx(-1.0))
    rmse = result.metrics["rmse_1s_m"].model
    assert rmse == Interval(pytest.approx(math.sqrt(7.0)), 1.0, 4.0)


def _resampled_metrics(
    errors: list[np.ndarray], masks: list[np.ndarray], drawn: np.ndarray
) -> np.ndarray:
    """(resamples, 4) ADE, FDE, RMSE at 1 and 2 s of each resample, by the functions over arrays
    on the drawn samples' targets put together (a plain loop: the reference)."""
    rows = []
    for samples in drawn:
        error = np.concatenate([errors[s] for s in samples])  # (A, K) metres
        mask = np.concatenate([masks[s] for s in samples])
        predicted = np.stack([error, np.zeros_like(error)], axis=-1)  # off by `error` along x
        arrays = (predicted, np.zeros_like(predicted), mask)
        rows.append(
            [compute_ade_m(*arrays), compute_fde_m(*arrays)]
            + [compute_rmse_m(*arrays, step) for step in (5, 10)]
        )
    return np.array(rows)


def test_the_bootstrap_against_a_plain_loop() -> None:
    """Random samples of 1 to 3 targets, some steps masked: each bound is the percentile of the
    metric recomputed on the drawn samples' targets, drawn as default_rng(seed).integers(0, S)
    gives them (120 resamples: not a whole number of the bootstrap's chunks)."""
    rng = np.random.default_rng(5)
    sizes = (1, 3, 2, 2, 1)
    ours = [rng.gamma(2.0, 1.0, (a, 10)) for a in sizes]
    theirs = [e + rng.gamma(1.0, 0.5, e.shape) for e in ours]
    masks = [rng.random((a, 10)) > 0.2 for a in sizes]
    result = bootstrap_intervals(
        _sample_totals(ours, masks), _sample_totals(theirs, masks), 0.2, resamples=120, seed=9
    )
    drawn = np.random.default_rng(9).integers(0, len(sizes), size=(120, len(sizes)))
    model, baseline = (_resampled_metrics(e, masks, drawn) for e in (ours, theirs))
    everything = [np.arange(len(sizes))]
    point = (_resampled_metrics(e, masks, everything)[0] for e in (ours, theirs))
    for index, (key, value, value_cv) in enumerate(
        zip(("ade_m", "fde_m", "rmse_1s_m", "rmse_2s_m"), *point, strict=True)
    ):
        paired = result.metrics[key]
        for interval, values, expected in (
            (paired.model, model[:, index], value),
            (paired.constant_velocity, baseline[:, index], value_cv),
            (paired.difference, model[:, index] - baseline[:, index], value - value_cv),
        ):
            kept = values[~np.isnan(values)]  # a resample with no target at the step counts not
            low, high = np.quantile(kept, [0.025, 0.975])
            assert interval.value == pytest.approx(expected, rel=1e-12)
            assert (interval.low, interval.high) == (pytest.approx(low), pytest.approx(high))


def test_the_interval_covers_a_known_ratio_95_percent_of_the_time() -> None:
    """Samples of 1 + Poisson(2) targets whose errors share the sample's factor u (Gamma, mean 1,
    variance 1/8: the targets of a scene are not independent) times Gamma(16, 1/8) (mean 2,
    second moment 4.25), at 5 steps: ADE and FDE tend to 2 m, RMSE at 1 s to
    sqrt(E[u^2] 4.25) = sqrt(1.125 * 4.25). 300 draws of 200 samples, 1,000 resamples each."""
    rng = np.random.default_rng(0)
    truth = {"ade_m": 2.0, "fde_m": 2.0, "rmse_1s_m": math.sqrt(1.125 * 4.25)}
    draws, covered = 300, dict.fromkeys(truth, 0)
    for draw in range(draws):
        targets = 1 + rng.poisson(2.0, 200)
        sample = np.repeat(np.arange(200), targets)
        factor = rng.gamma(8.0, 1 / 8, 200)[sample, None]
        error = factor * rng.gamma(16.0, 1 / 8, size=(len(sample), 5))
        totals = SampleTotals(200, 5)
        totals.add(error, np.ones(error.shape, bool), sample)
        result = bootstrap_intervals(totals, totals, 0.2, seed=draw)
        for key, value in truth.items():
            covered[key] += result.metrics[key].model.low <= value <= result.metrics[key].model.high
    # binomial sd of the share over 300 draws: sqrt(0.95 * 0.05 / 300) = 0.0126; 3 sd either side
    # (too narrow an interval fails below, too wide above)
    for key in truth:
        assert abs(covered[key] / draws - 0.95) < 0.038, (key, covered[key] / draws)


def test_the_paired_difference_is_narrower_than_the_two_apart() -> None:
    """Where model and constant velocity err alike in a sample (a scene hard for both), the
    difference on the same resamples varies far less than each; on identical inputs it is 0."""
    rng = np.random.default_rng(1)
    hard = rng.gamma(2.0, 1.0, 300)  # how hard each sample's scene is
    ours = [np.full((1, 5), h) + rng.normal(0, 0.05, (1, 5)) for h in hard]
    theirs = [1.5 * e for e in ours]
    masks = [np.ones((1, 5), bool)] * len(hard)
    result = bootstrap_intervals(_sample_totals(ours, masks), _sample_totals(theirs, masks), 0.2)
    width = lambda interval: interval.high - interval.low  # noqa: E731
    for paired in result.metrics.values():
        apart = math.hypot(width(paired.model), width(paired.constant_velocity))
        assert width(paired.difference) < 0.5 * apart
        assert paired.difference.excludes(0.0)
    same = _sample_totals(ours, masks)
    for paired in bootstrap_intervals(same, same, 0.2, resamples=50).metrics.values():
        # 0 to the rounding of the resampled sums (a product sums each column in its own order)
        zero = pytest.approx(0.0, abs=1e-12)
        assert paired.difference == Interval(0.0, zero, zero)
        ours, theirs = paired.model, paired.constant_velocity
        assert (ours.value, ours.low, ours.high) == pytest.approx(
            (theirs.value, theirs.low, theirs.high)
        )


def test_a_seed_gives_the_same_intervals() -> None:
    rng = np.random.default_rng(2)
    errors = [rng.gamma(2.0, 1.0, (2, 5)) for _ in range(20)]
    masks = [np.ones((2, 5), bool)] * 20
    totals = _sample_totals(errors, masks)
    one, two = (bootstrap_intervals(totals, totals, 0.2, resamples=300) for _ in range(2))
    assert one == two and (one.seed, one.resamples) == (SEED, 300) and SEED == 0
    other = bootstrap_intervals(totals, totals, 0.2, resamples=300, seed=1)
    assert other.metrics["ade_m"].model != one.metrics["ade_m"].model
    assert bootstrap_intervals(totals, totals, 0.2).resamples == RESAMPLES == 1000


def test_what_the_bootstrap_refuses() -> None:
    errors, masks = [np.ones((1, 5))], [np.ones((1, 5), bool)]
    totals = _sample_totals(errors, masks)
    with pytest.raises(ValueError, match="at least 1"):
        bootstrap_intervals(totals, totals, 0.2, resamples=0)
    fewer = _sample_totals(errors, [np.array([[True] * 4 + [False]])])
    with pytest.raises(ValueError, match="not scored on the same targets"):
        bootstrap_intervals(totals, fewer, 0.2)
    with pytest.raises(ValueError, match="at least one sample"):
        next(resampled_sums(np.zeros((0, 3)), 10))


def test_a_metric_where_no_target_counts_has_no_interval() -> None:
    """No target reaches the last step (2 s): FDE and RMSE at 2 s have no value and no interval;
    a resample that draws only samples without a target at a step leaves that resample out."""
    masks = [np.array([[True] * 10]), np.array([[True] * 5 + [False] * 5])]
    masks[0][0, 9] = False
    totals = _sample_totals([np.ones((1, 10)), 2 * np.ones((1, 10))], masks)
    result = bootstrap_intervals(totals, totals, 0.2, resamples=200)
    assert set(result.metrics) == {"ade_m", "rmse_1s_m"}
    assert result.metrics["rmse_1s_m"].model == Interval(pytest.approx(math.sqrt(2.5)), 1.0, 2.0)
