"""95 % intervals: how far a number of one run, or the mean over several seeds, may be from the
number that many more seeds or many more samples would give.

- `Interval`: a value (the estimate) and the bounds of its 95 % interval, in the value's unit.
- `seed_interval`: over N runs that differ only in their seed (`aigem paper --seeds N`), the
  mean and Student's t interval of the mean (N - 1 degrees of freedom); none for one seed.
- `bootstrap_intervals`: within one run (`aigem evaluate`), the percentile bootstrap interval
  of each metric over the split's samples, resampled whole, of the model, of constant velocity
  and of their paired difference (`SampleIntervals`, a `Paired` per metric).

Every interval here is at 95 % (`LEVEL`): the level is a convention of the field, not a setting.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from aigem.metrics import SampleTotals, metric_steps

LEVEL = 0.95
Z_975 = 1.959963984540054  # the standard normal's 0.975 quantile

# Student's t 0.975 quantiles for 1..30 degrees of freedom (any statistics table); above 30 the
# Cornish-Fisher expansion around Z_975 (`t_975`) is within 0.001 of the exact value.
_T_975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
)  # fmt: skip


def t_975(dof: int) -> float:
    """Student's t distribution's 0.975 quantile for `dof` >= 1 degrees of freedom: the factor
    of a two-sided 95 % interval of a mean."""
    if dof < 1:
        raise ValueError(f"{dof} degrees of freedom: a t interval needs at least 1")
    if dof <= len(_T_975):
        return _T_975[dof - 1]
    z = Z_975
    return z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)


@dataclass(frozen=True)
class Interval:
    """A number and its 95 % interval [low, high], in the number's unit. `low` and `high` are
    None where no interval can be given (one seed; nothing to resample)."""

    value: float
    low: float | None = None
    high: float | None = None

    @property
    def known(self) -> bool:
        """Whether the interval has bounds."""
        return self.low is not None and self.high is not None

    def excludes(self, reference: float) -> bool:
        """Whether `reference` lies outside the interval (a difference whose interval excludes 0
        is beyond the noise that the interval measures); False where the interval is unknown."""
        return self.known and not (self.low <= reference <= self.high)

    def as_dict(self) -> dict[str, float | None]:
        """The interval as --json and report.json write it."""
        return {"value": self.value, "low": self.low, "high": self.high}


def seed_interval(values: Sequence[float]) -> Interval:
    """The mean of `values` (one per seed, in the values' unit) and Student's t 95 % interval of
    that mean: mean +- t_975(N - 1) * sd / sqrt(N), sd with N - 1 in its denominator. One value
    has no interval. NaNs are a ValueError: a seed whose number is missing is not averaged away."""
    if not values:
        raise ValueError("an interval over seeds needs at least one value")
    if any(math.isnan(v) for v in values):
        raise ValueError(f"{list(values)}: a seed's value is missing (NaN)")
    n = len(values)
    mean = math.fsum(values) / n
    if n == 1:
        return Interval(mean)
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in values) / (n - 1))
    half = t_975(n - 1) * sd / math.sqrt(n)
    return Interval(mean, mean - half, mean + half)


# The bootstrap of one run's metrics over its samples (`aigem evaluate`).

RESAMPLES = 1000  # evaluate's default number of bootstrap resamples (--bootstrap)
SEED = 0  # the bootstrap's fixed seed: a run's intervals are the same at every call
_CHUNK = 50  # resamples drawn at a time: a (50, S) block of weights, some 8 MB at S = 21,000


@dataclass(frozen=True)
class Paired:
    """One metric's intervals (metres): the model's, constant velocity's, and their difference
    model - constant velocity, taken on the same resamples (paired)."""

    model: Interval
    constant_velocity: Interval
    difference: Interval

    def as_dict(self) -> dict[str, dict[str, float | None]]:
        """The three intervals as --json writes them, by kind."""
        return {
            "model": self.model.as_dict(),
            "constant_velocity": self.constant_velocity.as_dict(),
            "difference": self.difference.as_dict(),
        }


@dataclass(frozen=True)
class SampleIntervals:
    """The bootstrap intervals of a run's metrics in metres (metric key -> Paired; a metric
    with no value, where no target counts, has none), from `resamples` resamples of its
    `samples` samples drawn with numpy's default_rng(`seed`)."""

    resamples: int
    seed: int
    samples: int
    metrics: dict[str, Paired]

    def as_dict(self) -> dict[str, Any]:
        """The intervals as --json writes them."""
        return {
            "level": LEVEL,
            "resamples": self.resamples,
            "seed": self.seed,
            "samples": self.samples,
            "metrics": {key: paired.as_dict() for key, paired in self.metrics.items()},
        }

    def at(
        self, model: Mapping[str, float | None], baseline: Mapping[str, float | None]
    ) -> SampleIntervals:
        """These intervals around the values `model` and `baseline` report (metric key -> metres):
        the numbers of the per-region sums, which equal the per-sample sums' to float rounding."""
        metrics = {
            key: Paired(
                replace(paired.model, value=model[key]),
                replace(paired.constant_velocity, value=baseline[key]),
                replace(paired.difference, value=model[key] - baseline[key]),
            )
            for key, paired in self.metrics.items()
        }
        return replace(self, metrics=metrics)

    @staticmethod
    def combined(
        members: Mapping[str, SampleIntervals], sources: Mapping[str, str]
    ) -> SampleIntervals:
        """The intervals of a group's members (member name -> its intervals, one split, one
        seed) taken as its rows are (`sources`: metric key -> member): each metric's interval
        from the member its number comes from."""
        first = next(iter(members.values()))
        metrics = {
            key: members[name].metrics[key]
            for key, name in sources.items()
            if key in members[name].metrics
        }
        return replace(first, metrics=metrics)


def resampled_sums(columns: np.ndarray, resamples: int, seed: int = SEED) -> Iterator[np.ndarray]:
    """The column sums of `resamples` bootstrap resamples of the S rows of `columns` (S, C),
    as (chunk, C) blocks in order (chunks of at most 50 resamples: the memory is a (50, S) block
    of weights, never (resamples, S)). A resample draws S rows uniformly with replacement (row
    i then weighs the number of times it was drawn); the draws come from
    numpy.random.default_rng(`seed`), so a seed gives the same resamples at any S x C."""
    samples = len(columns)
    if samples == 0:
        raise ValueError("a bootstrap needs at least one sample")
    rng = np.random.default_rng(seed)
    for first in range(0, resamples, _CHUNK):
        rows = min(_CHUNK, resamples - first)
        drawn = rng.integers(0, samples, size=(rows, samples))  # (rows, S) row indices
        flat = (drawn + samples * np.arange(rows)[:, None]).ravel()
        weights = np.bincount(flat, minlength=rows * samples).reshape(rows, samples)
        yield weights.astype(np.float64) @ columns


def _percentile(value: float, resampled: np.ndarray) -> Interval:
    """`value` and the 2.5th and 97.5th percentiles of its resampled values (numpy's linear
    interpolation), the resamples where nothing counts (NaN) left out; no bounds if all are."""
    kept = resampled[~np.isnan(resampled)]
    if not len(kept):
        return Interval(value)
    low, high = np.quantile(kept, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return Interval(value, float(low), float(high))


def bootstrap_intervals(
    model: SampleTotals,
    baseline: SampleTotals,
    time_step_s: float,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> SampleIntervals:
    """95 % percentile bootstrap intervals of each metric in metres that `aigem evaluate`
    reports (metrics.metric_steps: ADE, FDE, RMSE at each whole second; not the counts), of the
    model, of constant velocity (`baseline`, on the same targets) and of their difference.

    A resample draws whole samples, S of the S with replacement (resampled_sums): the targets
    of a sample share a scene, so their errors are not independent. Each metric is recomputed
    on the resample's summed errors and counts with the function evaluate uses (a ratio of
    sums, then the root for RMSE), not averaged over per-sample metrics. The difference is taken
    on the same resamples as both, so what the samples share cancels. The values are those of
    all the samples' sums (SampleIntervals.at puts the reported numbers in their place). The
    interval of a metric is the 2.5th to 97.5th percentile of its B resampled values."""
    if resamples < 1:
        raise ValueError(f"{resamples} resamples: a bootstrap needs at least 1")
    if model.count.shape != baseline.count.shape or not np.array_equal(model.count, baseline.count):
        raise ValueError("the model and the baseline are not scored on the same targets")
    keyed = [(key, m, k) for key, m, k in metric_steps(model.steps, time_step_s) if m.unit]
    parts = (model.error_m, model.squared_m2, model.count, baseline.error_m, baseline.squared_m2)
    columns = np.concatenate(parts, axis=1)  # (S, 5K)

    def metrics_of(sums: np.ndarray) -> np.ndarray:  # (rows, 5K) -> (2, metrics, rows)
        e_m, s_m, count, e_b, s_b = np.split(sums, 5, axis=1)
        pairs = ((e_m, s_m), (e_b, s_b))
        return np.array([[m.of_sums(e, s, count, k) for _, m, k in keyed] for e, s in pairs])

    point = metrics_of(columns.sum(axis=0, keepdims=True))[..., 0]  # (2, metrics)
    drawn = np.concatenate(list(map(metrics_of, resampled_sums(columns, resamples, seed))), -1)
    intervals = {}
    for index, (key, _, _) in enumerate(keyed):
        ours, theirs = point[:, index]
        if np.isnan(ours) or np.isnan(theirs):
            continue
        intervals[key] = Paired(
            _percentile(float(ours), drawn[0, index]),
            _percentile(float(theirs), drawn[1, index]),
            _percentile(float(ours - theirs), drawn[0, index] - drawn[1, index]),
        )
    return SampleIntervals(resamples, seed, model.samples, intervals)
