"""95 % intervals: how far a number of one run, or the mean over several seeds, may be from the
number that many more seeds or many more samples would give.

- `Interval`: a value (the estimate) and the bounds of its 95 % interval, in the value's unit.
- `seed_interval`: over N runs that differ only in their seed (`aigem paper --seeds N`), the
  mean and Student's t interval of the mean (N - 1 degrees of freedom); none for one seed.

Every interval here is at 95 % (`LEVEL`): the level is a convention of the field, not a setting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

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
