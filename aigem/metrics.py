"""Trajectory metrics in metres (docs/conventions.md), accumulated batch by batch.

- RMSE at h s: sqrt of the mean squared Euclidean error over all valid (sample, actor) pairs at
  future step 5h, pooled over the whole split (the CS-LSTM / PiP convention; DeepTrack instead
  averages the five steps inside each second, and some papers take the root per sample first).
- ADE: mean Euclidean error over all valid (sample, actor, step); FDE: mean over valid pairs at
  the last predicted step. Masked steps (the actor left the section) count nowhere.
- Breakdown by the actor's present position: front (y > 15 m), rear (y < -15 m), mid.

METRICS lists what `aigem evaluate` reports, each with its label and unit: a new metric is an
entry there (and, if it needs sums of its own, their accumulation in ErrorTotals); its rows,
--json and the printed table follow.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

REGIONS = ("all", "front", "mid", "rear")
FRONT_Y_M = 15.0


def region_of(present_y_m: np.ndarray) -> np.ndarray:
    """(A,) region index into REGIONS[1:] (0 front, 1 mid, 2 rear) from the present y."""
    return np.where(present_y_m > FRONT_Y_M, 0, np.where(present_y_m < -FRONT_Y_M, 2, 1))


@dataclass
class ErrorTotals:
    """Sums per region and future step: errors, squared errors and valid counts. (4, K) each."""

    steps: int
    error_m: np.ndarray = field(init=False)
    squared_m2: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)
    actors: int = 0

    def __post_init__(self) -> None:
        shape = (len(REGIONS), self.steps)
        self.error_m, self.squared_m2 = np.zeros(shape), np.zeros(shape)
        self.count = np.zeros(shape, dtype=np.int64)

    def add(
        self, predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray, present_y_m: np.ndarray
    ) -> None:
        """Add (A, K, 2) predictions and truths with their (A, K) mask; positions in metres."""
        error = np.sqrt(((predicted - truth) ** 2).sum(axis=-1)) * mask  # (A, K)
        one_hot = np.zeros((len(REGIONS), len(error)))
        one_hot[0] = 1.0
        one_hot[1 + region_of(present_y_m), np.arange(len(error))] = 1.0
        self.error_m += one_hot @ error
        self.squared_m2 += one_hot @ (error**2)
        self.count += (one_hot @ mask.astype(np.float64)).astype(np.int64)
        self.actors += len(error)


Value = Callable[[ErrorTotals, int, int], float | int | None]


@dataclass(frozen=True)
class Metric:
    """A number per region that `aigem evaluate` reports. `key` names it in summarize_errors'
    rows and in --json; a key with "{s}" stands for one number per whole second s of the horizon.
    `label` heads its column in the printed table ("{s}" likewise); `unit` is "m" (or another
    unit) for a column, "" for a count, which gets none. `value(totals, region, k)` computes it
    from the totals of REGIONS[region] at future step index k: second s's step for a per-second
    metric, else the last predicted step."""

    key: str
    label: str
    unit: str
    value: Value

    @property
    def per_second(self) -> bool:
        return "{s}" in self.key


def _ratio(numerator: float, denominator: float) -> float | None:
    return float(numerator / denominator) if denominator else None


def _ade_m(totals: ErrorTotals, region: int, k: int) -> float | None:
    return _ratio(totals.error_m[region].sum(), totals.count[region].sum())


def _mean_error_m(totals: ErrorTotals, region: int, k: int) -> float | None:
    return _ratio(totals.error_m[region, k], totals.count[region, k])


def _rmse_m(totals: ErrorTotals, region: int, k: int) -> float | None:
    mean_sq = _ratio(totals.squared_m2[region, k], totals.count[region, k])
    return None if mean_sq is None else float(np.sqrt(mean_sq))


def _count(totals: ErrorTotals, region: int, k: int) -> int:
    return int(totals.count[region, k])


# What evaluate reports, in the order of its rows, its --json and its table's columns.
METRICS: tuple[Metric, ...] = (
    Metric("ade_m", "ADE", "m", _ade_m),
    Metric("fde_m", "FDE", "m", _mean_error_m),
    Metric("rmse_{s}s_m", "RMSE {s} s", "m", _rmse_m),
    Metric("n_{s}s", "n {s} s", "", _count),  # the targets that count at second s
)


def summarize_errors(totals: ErrorTotals, time_step_s: float) -> dict[str, dict[str, float | None]]:
    """Each metric of METRICS per region, in metres (None where nothing counts): the whole
    horizon's first, then each whole second's (rmse_1s_m, n_1s, rmse_2s_m, ...)."""
    steps_per_s = round(1.0 / time_step_s)
    last = totals.steps - 1
    result: dict[str, dict[str, float | None]] = {}
    for region_index, region in enumerate(REGIONS):
        row = {m.key: m.value(totals, region_index, last) for m in METRICS if not m.per_second}
        for second in range(1, totals.steps // steps_per_s + 1):
            k = second * steps_per_s - 1
            for metric in (m for m in METRICS if m.per_second):
                row[metric.key.format(s=second)] = metric.value(totals, region_index, k)
        result[region] = row
    return result


def table_columns(seconds: int) -> list[tuple[str, str]]:
    """(key, label) of the evaluate table's columns over `seconds` whole seconds: every metric of
    METRICS with a unit, a per-second one once per second."""
    return [
        (metric.key.format(s=second), metric.label.format(s=second))
        for metric in METRICS
        if metric.unit
        for second in (range(1, seconds + 1) if metric.per_second else (0,))
    ]


def whole_horizon_keys() -> set[str]:
    """The keys of the metrics over the whole horizon (ADE, FDE): a multi-horizon run takes them
    from its longest model, the per-second ones from the first model that reaches the second."""
    return {metric.key for metric in METRICS if not metric.per_second}


def step_errors(totals: ErrorTotals) -> dict[str, dict[str, np.ndarray]]:
    """Per region of REGIONS, at each future step k = 1..K: `rmse_m` (sqrt of the pooled mean
    squared error), `mean_error_m` (mean displacement error) and `n` (valid targets), each (K,);
    NaN where no target counts. At step 5h, `rmse_m` is summarize_errors' RMSE at h s; at the
    last step, `mean_error_m` is its FDE."""
    count = totals.count.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_sq = np.where(count > 0, totals.squared_m2 / count, np.nan)  # (4, K)
        mean = np.where(count > 0, totals.error_m / count, np.nan)
    return {
        region: {"rmse_m": np.sqrt(mean_sq[i]), "mean_error_m": mean[i], "n": totals.count[i]}
        for i, region in enumerate(REGIONS)
    }
