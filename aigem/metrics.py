"""Trajectory metrics in metres (docs/conventions.md): functions over arrays, and their sums over a
split, batch by batch.

- RMSE at h s: sqrt of the mean squared Euclidean error over all valid (sample, actor) pairs at
  future step 5h, pooled over the whole split (the CS-LSTM / PiP convention; DeepTrack instead
  averages the five steps inside each second, and some papers take the root per sample first).
- ADE: mean Euclidean error over all valid (sample, actor, step); FDE: mean over valid pairs at
  the last predicted step. Masked steps (the actor left the section) count nowhere.
- Breakdown by the actor's present position: front (y > 15 m), rear (y < -15 m), mid.

The functions over arrays (`compute_ade_m`, `compute_fde_m`, `compute_rmse_m`) score anyone's
predictions: A targets, K future steps of the build's time step. Each is a ratio of per-step
sums (`ade_of_sums_m`, `mean_error_of_sums_m`, `rmse_of_sums_m`) of `displacement_errors_m`;
ErrorTotals adds up those same errors batch by batch, per region, and METRICS takes each metric
from its sums with the same ratios, so a split scored in batches gets the numbers of the
functions over the whole split (to float rounding). SampleTotals keeps the same sums per sample
(all regions), for the bootstrap intervals of aigem.intervals.

Every public function, and ErrorTotals.add and SampleTotals.add, takes numpy arrays, anything
np.asarray reads (lists), or PyTorch tensors on any device, with or without gradients
(`as_array` reads them); the results are numpy's.

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


def as_array(values: object) -> np.ndarray:
    """`values` as a numpy array: a PyTorch tensor (on any device, with or without gradients:
    anything with `detach`) copied to the host; anything else as np.asarray reads it. numpy
    itself cannot read a tensor on a GPU or one that requires grad."""
    if hasattr(values, "detach") and hasattr(values, "cpu"):
        tensor = values.detach().cpu()  # type: ignore[attr-defined]
        try:
            return tensor.numpy()
        except TypeError:  # a dtype numpy lacks (bfloat16): as float32
            return tensor.float().numpy()
    return np.asarray(values)


def _shape(array: np.ndarray) -> str:
    """(18, 25) for an array of that shape: the same words for numpy's and PyTorch's."""
    return str(tuple(int(n) for n in array.shape))


def displacement_errors_m(predicted_m: object, truth_m: object, mask: object) -> np.ndarray:
    """(A, K) Euclidean distance in metres between each predicted and true position, 0 where
    `mask` is False (whatever was predicted there). `predicted_m`, `truth_m`: (A, K, 2) x, y in
    metres; `mask`: (A, K) bool, True where the target's position is recorded (numpy arrays or
    tensors: as_array). Other shapes are a ValueError: numpy would broadcast them into wrong
    numbers."""
    predicted_m, truth_m, mask = as_array(predicted_m), as_array(truth_m), as_array(mask)
    if predicted_m.shape != truth_m.shape or truth_m.ndim != 3 or truth_m.shape[-1] != 2:
        raise ValueError(
            f"predictions of shape {_shape(predicted_m)} and targets of shape {_shape(truth_m)}: "
            "both must be (A, K, 2), the same"
        )
    if mask.shape != truth_m.shape[:2]:
        raise ValueError(
            f"mask of shape {_shape(mask)}: must be (A, K) = {_shape(truth_m[..., 0])}, as the "
            "targets' (A, K, 2)"
        )
    if mask.dtype != np.bool_:
        raise ValueError(
            f"mask of dtype {mask.dtype}: must be bool (True where the target's position is "
            "recorded)"
        )
    return np.where(mask, np.sqrt(((predicted_m - truth_m) ** 2).sum(axis=-1)), 0.0)


def ade_of_sums_m(error_m: object, count: object) -> float | np.ndarray:
    """ADE in metres from (..., K) per-step sums of displacement errors (metres) and counts of
    valid targets of the same shape: every valid (target, step) weighs alike. A float for (K,)
    sums, else (...); NaN where none is valid."""
    error_m, count = as_array(error_m), as_array(count)
    total = count.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ade = np.where(total > 0, error_m.sum(axis=-1) / total, np.nan)
    return float(ade) if ade.ndim == 0 else ade


def mean_error_of_sums_m(error_m: object, count: object) -> np.ndarray:
    """(..., K) mean displacement error in metres at each step, from sums and counts of the same
    shape; NaN where no target is valid. FDE is the last step's."""
    error_m, count = as_array(error_m), as_array(count)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, error_m / count, np.nan)


def rmse_of_sums_m(squared_m2: object, count: object) -> np.ndarray:
    """(..., K) RMSE in metres at each step (the root of the pooled mean squared error), from
    sums of squared displacement errors (metres^2) and counts of the same shape; NaN where no
    target is valid. RMSE at h s is step 5h's (on the 0.2 s grid)."""
    squared_m2, count = as_array(squared_m2), as_array(count)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.where(count > 0, squared_m2 / count, np.nan))


def _step_sums(
    predicted_m: object, truth_m: object, mask: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K,) each, over the targets: summed displacement errors (m), summed squares (m^2), counts."""
    error = displacement_errors_m(predicted_m, truth_m, mask).astype(np.float64)  # (A, K)
    return error.sum(axis=0), (error**2).sum(axis=0), as_array(mask).sum(axis=0)


def compute_ade_m(predicted_m: object, truth_m: object, mask: object) -> float:
    """ADE in metres: the mean Euclidean error over every valid (target, step). `predicted_m`,
    `truth_m`: (A, K, 2) positions in metres; `mask`: (A, K) bool, True where the target's
    position is recorded. NaN where nothing is valid."""
    error_m, _, count = _step_sums(predicted_m, truth_m, mask)
    return ade_of_sums_m(error_m, count)


def compute_fde_m(predicted_m: object, truth_m: object, mask: object) -> float:
    """FDE in metres: the mean Euclidean error over the targets valid at the last step K (the
    horizon). Arrays as compute_ade_m's; NaN where no target is valid at step K."""
    error_m, _, count = _step_sums(predicted_m, truth_m, mask)
    return float(mean_error_of_sums_m(error_m, count)[-1])


def compute_rmse_m(predicted_m: object, truth_m: object, mask: object, step: int) -> float:
    """RMSE in metres at future step `step` (1..K): the root of the mean squared Euclidean error
    over the targets valid at that step. RMSE at h s is step h / time_step_s (5h on the 0.2 s
    grid: 1 s is step 5). Arrays as compute_ade_m's; NaN where no target is valid there."""
    _, squared_m2, count = _step_sums(predicted_m, truth_m, mask)
    if not 1 <= step <= len(count):
        raise ValueError(f"step {step}: the predictions have future steps 1..{len(count)}")
    return float(rmse_of_sums_m(squared_m2, count)[step - 1])


def region_of(present_y_m: object) -> np.ndarray:
    """(A,) region index into REGIONS[1:] (0 front, 1 mid, 2 rear) from the (A,) present y (m)."""
    present_y_m = as_array(present_y_m)
    return np.where(present_y_m > FRONT_Y_M, 0, np.where(present_y_m < -FRONT_Y_M, 2, 1))


@dataclass
class ErrorTotals:
    """Sums per region and future step of displacement_errors_m: errors (m), squared errors
    (m^2) and valid counts. (4, K) each, regions as REGIONS."""

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
        self, predicted: object, truth: object, mask: object, present_y_m: object
    ) -> np.ndarray:
        """Add (A, K, 2) predictions and truths with their (A, K) bool mask, positions in metres,
        and (A,) present y in metres; returns the (A, K) displacement errors it added."""
        error = displacement_errors_m(predicted, truth, mask)  # (A, K)
        mask, present_y_m = as_array(mask), as_array(present_y_m)
        one_hot = np.zeros((len(REGIONS), len(error)))
        one_hot[0] = 1.0
        one_hot[1 + region_of(present_y_m), np.arange(len(error))] = 1.0
        self.error_m += one_hot @ error
        self.squared_m2 += one_hot @ (error**2)
        self.count += (one_hot @ mask.astype(np.float64)).astype(np.int64)
        self.actors += len(error)
        return error


@dataclass
class SampleTotals:
    """Sums per sample and future step of displacement_errors_m over the sample's targets (all
    regions): errors (m), squared errors (m^2) and valid counts, (S, K) each, row i the split's
    sample i. What aigem.intervals resamples: the targets of one sample share a scene, so a
    bootstrap draws whole samples."""

    samples: int
    steps: int
    error_m: np.ndarray = field(init=False)
    squared_m2: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        shape = (self.samples, self.steps)
        self.error_m, self.squared_m2 = np.zeros(shape), np.zeros(shape)
        self.count = np.zeros(shape, dtype=np.int32)  # targets a sample: far below 2^31

    def add(self, error_m: object, mask: object, sample: object) -> None:
        """Add (A, K) displacement errors (metres, 0 where masked, as ErrorTotals.add returns
        them) with their (A, K) bool mask and (A,) each target's sample id."""
        error_m, mask, sample = as_array(error_m), as_array(mask), as_array(sample)
        if not len(sample):
            return
        # One bincount per sum over the rows of the batch's samples (np.add.at on rows is some
        # ten times slower); each (sample, step) sums its targets in their order, as add.at does.
        first = int(sample.min())
        rows = int(sample.max()) + 1 - first
        cells = ((sample - first)[:, None] * self.steps + np.arange(self.steps)).ravel()
        for total, values in (
            (self.error_m, error_m),
            (self.squared_m2, error_m**2),  # squared as ErrorTotals squares them
            (self.count, mask),
        ):
            summed = np.bincount(cells, values.ravel(), minlength=rows * self.steps)
            total[first : first + rows] += summed.reshape(rows, self.steps).astype(total.dtype)


# A metric from sums (..., K) of errors (m), squared errors (m^2) and counts at step index k:
# (...) values, NaN where nothing counts.
OfSums = Callable[[np.ndarray, np.ndarray, np.ndarray, int], np.ndarray | float]


@dataclass(frozen=True)
class Metric:
    """A number per region that `aigem evaluate` reports. `key` names it in summarize_errors'
    rows and in --json; a key with "{s}" stands for one number per whole second s of the horizon.
    `label` heads its column in the printed table ("{s}" likewise); `unit` is "m" (or another
    unit) for a column, "" for a count, which gets none. `of_sums(error_m, squared_m2, count, k)`
    computes it from sums of any leading shape (..., K) at future step index k (second s's step
    for a per-second metric, else the last predicted step): a region's totals for evaluate's
    rows (`value`), a block of bootstrap resamples for aigem.intervals, by one function."""

    key: str
    label: str
    unit: str
    of_sums: OfSums

    @property
    def per_second(self) -> bool:
        return "{s}" in self.key

    def value(self, totals: ErrorTotals, region: int, k: int) -> float | int | None:
        """The metric of REGIONS[region]'s totals at step index k as evaluate reports it: a
        count as an int, metres as a float, None where nothing counts."""
        rows = totals.error_m[region], totals.squared_m2[region], totals.count[region]
        number = np.asarray(self.of_sums(*rows, k))
        if np.issubdtype(number.dtype, np.integer):
            return int(number)
        return None if np.isnan(number) else float(number)


def _ade_m(
    error_m: np.ndarray, squared_m2: np.ndarray, count: np.ndarray, k: int
) -> np.ndarray | float:
    return ade_of_sums_m(error_m, count)


def _mean_error_m(
    error_m: np.ndarray, squared_m2: np.ndarray, count: np.ndarray, k: int
) -> np.ndarray | float:
    return mean_error_of_sums_m(error_m, count)[..., k]


def _rmse_m(
    error_m: np.ndarray, squared_m2: np.ndarray, count: np.ndarray, k: int
) -> np.ndarray | float:
    return rmse_of_sums_m(squared_m2, count)[..., k]


def _count(
    error_m: np.ndarray, squared_m2: np.ndarray, count: np.ndarray, k: int
) -> np.ndarray | float:
    return count[..., k]


# What evaluate reports, in the order of its rows, its --json and its table's columns.
METRICS: tuple[Metric, ...] = (
    Metric("ade_m", "ADE", "m", _ade_m),
    Metric("fde_m", "FDE", "m", _mean_error_m),
    Metric("rmse_{s}s_m", "RMSE {s} s", "m", _rmse_m),
    Metric("n_{s}s", "n {s} s", "", _count),  # the targets that count at second s
)


def metric_steps(steps: int, time_step_s: float) -> list[tuple[str, Metric, int]]:
    """(key, metric, k) of each number evaluate reports over `steps` future steps of
    `time_step_s`, in its rows' order: the whole horizon's metrics (k: the last step index),
    then each whole second s's (k: its step index, 5s - 1 on the 0.2 s grid)."""
    steps_per_s = round(1.0 / time_step_s)
    keyed = [(m.key, m, steps - 1) for m in METRICS if not m.per_second]
    for second in range(1, steps // steps_per_s + 1):
        k = second * steps_per_s - 1
        keyed += [(m.key.format(s=second), m, k) for m in METRICS if m.per_second]
    return keyed


def summarize_errors(totals: ErrorTotals, time_step_s: float) -> dict[str, dict[str, float | None]]:
    """Each metric of METRICS per region, in metres (None where nothing counts): the whole
    horizon's first, then each whole second's (rmse_1s_m, n_1s, rmse_2s_m, ...)."""
    keyed = metric_steps(totals.steps, time_step_s)
    return {
        region: {key: metric.value(totals, index, k) for key, metric, k in keyed}
        for index, region in enumerate(REGIONS)
    }


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
    rmse = rmse_of_sums_m(totals.squared_m2, totals.count)  # (4, K)
    mean = mean_error_of_sums_m(totals.error_m, totals.count)
    return {
        region: {"rmse_m": rmse[i], "mean_error_m": mean[i], "n": totals.count[i]}
        for i, region in enumerate(REGIONS)
    }
