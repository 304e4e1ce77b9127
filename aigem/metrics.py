"""Trajectory metrics in metres (SPEC section 6), accumulated batch by batch.

- RMSE at h s: sqrt of the mean squared Euclidean error over all valid (sample, actor) pairs at
  future step 5h, pooled over the whole split (the CS-LSTM / PiP convention; DeepTrack instead
  averages the five steps inside each second, and some papers take the root per sample first).
- ADE: mean Euclidean error over all valid (sample, actor, step); FDE: mean over valid pairs at
  the last predicted step. Masked steps (the actor left the section) count nowhere.
- Breakdown by the actor's present position: front (y > 15 m), rear (y < -15 m), mid.
"""

from __future__ import annotations

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


def summarize_errors(totals: ErrorTotals, time_step_s: float) -> dict[str, dict[str, float | None]]:
    """ADE, FDE and RMSE at each whole second, per region, in metres (None where nothing counts)."""
    steps_per_s = round(1.0 / time_step_s)
    result: dict[str, dict[str, float | None]] = {}
    for index, region in enumerate(REGIONS):
        count, last = totals.count[index], totals.steps - 1
        ratio = lambda num, den: float(num / den) if den else None  # noqa: E731
        row: dict[str, float | None] = {
            "ade_m": ratio(totals.error_m[index].sum(), count.sum()),
            "fde_m": ratio(totals.error_m[index, last], count[last]),
        }
        for second in range(1, totals.steps // steps_per_s + 1):
            k = second * steps_per_s - 1
            mean_sq = ratio(totals.squared_m2[index, k], count[k])
            row[f"rmse_{second}s_m"] = None if mean_sq is None else float(np.sqrt(mean_sq))
            row[f"n_{second}s"] = int(count[k])
        result[region] = row
    return result


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
