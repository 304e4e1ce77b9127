"""Dividing ego windows into train, validation and test (SPEC section 3).

Splits are decided per ego window; actor nodes are never filtered by split: an ego's neighbours
are whoever was there.
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.schema import Split, SplitMode

SPLIT_ORDER = (Split.TRAIN, Split.VAL, Split.TEST)


def _by_thresholds(value: pl.Expr, first: pl.Expr, second: pl.Expr) -> pl.Expr:
    return (
        pl.when(value <= first)
        .then(pl.lit(Split.TRAIN.value))
        .when(value <= second)
        .then(pl.lit(Split.VAL.value))
        .otherwise(pl.lit(Split.TEST.value))
    )


def split_by_vehicle(windows: pl.DataFrame, max_vehicle_id: int, config: BuildConfig) -> pl.Series:
    """Ego Vehicle_ID <= round(0.7 * max ID) train, <= round(0.8 * max ID) validation, else test.

    `max_vehicle_id` is the largest Vehicle_ID of the recording (CS-LSTM's convention). round()
    is MATLAB's, as in CS-LSTM's preprocessing: halves go away from zero (10.5 -> 11), not to
    the even neighbour as Python's round() does.
    """
    first, second = _vehicle_cuts(max_vehicle_id, config)
    return windows.select(
        _by_thresholds(pl.col(s.EGO_VEHICLE_ID), pl.lit(first), pl.lit(second)).alias(s.SPLIT)
    ).to_series()


def split_by_time(windows: pl.DataFrame, config: BuildConfig) -> pl.Series:
    """Contiguous blocks of present time: the first 70 % of windows by present step train, the
    next 10 % validation, the rest test; windows within one window length after a block's end are
    dropped (null), so that no future of one split lies in the history of another.
    """
    train, val, _ = config.split_fractions
    present = windows[s.PRESENT_STEP].to_numpy()
    if len(present) == 0:
        return pl.Series(s.SPLIT, [], dtype=pl.String)
    ordered = np.sort(present)
    # floor, with a tolerance: (0.7 + 0.1) * 20 is 15.999999999999998 in floating point.
    cut = lambda fraction: ordered[
        min(len(ordered) - 1, math.floor(fraction * len(ordered) + 1e-9))
    ]  # noqa: E731
    first, second = cut(train), cut(train + val)
    gap = config.window_steps
    label = np.where(
        present < first,
        Split.TRAIN.value,
        np.where(present < second, Split.VAL.value, Split.TEST.value),
    )
    in_gap = ((present >= first) & (present < first + gap)) | (
        (present >= second) & (present < second + gap)
    )
    return pl.Series(s.SPLIT, np.where(in_gap, None, label), dtype=pl.String)


def split_randomly(windows: pl.DataFrame, recording_index: int, config: BuildConfig) -> pl.Series:
    """Seeded, by ego track: all windows of one track land in the same split."""
    tracks = np.unique(windows[s.EGO_TRACK_ID].to_numpy())
    rng = np.random.default_rng([config.seed, recording_index])
    draw = rng.random(len(tracks))
    train, val, _ = config.split_fractions
    label = np.where(
        draw < train,
        Split.TRAIN.value,
        np.where(draw < train + val, Split.VAL.value, Split.TEST.value),
    )
    lookup = dict(zip(tracks.tolist(), label.tolist(), strict=True))
    return windows[s.EGO_TRACK_ID].replace_strict(lookup, return_dtype=pl.String).alias(s.SPLIT)


def assign_splits(
    windows: pl.DataFrame, max_vehicle_id: int, recording_index: int, config: BuildConfig
) -> pl.DataFrame:
    """`windows` with a s.SPLIT column; windows in a time-split gap are dropped."""
    if config.split is SplitMode.VEHICLE:
        labels = split_by_vehicle(windows, max_vehicle_id, config)
    elif config.split is SplitMode.TIME:
        labels = split_by_time(windows, config)
    else:
        labels = split_randomly(windows, recording_index, config)
    return windows.with_columns(labels.alias(s.SPLIT)).drop_nulls(s.SPLIT)


MIN_SPLIT_SHARE = 0.02  # a split with a smaller share of the samples is worth a warning


def _vehicle_cuts(max_vehicle_id: int, config: BuildConfig) -> tuple[int, int]:
    train, val, _ = config.split_fractions
    return _matlab_round(train * max_vehicle_id), _matlab_round((train + val) * max_vehicle_id)


def _matlab_round(x: float) -> int:
    """MATLAB's round() for x >= 0: halves go away from zero (10.5 -> 11)."""
    return math.floor(x + 0.5)


def _why_vehicle_split_is_small(
    samples: dict[str, dict[str, int]],
    split: Split,
    top_vehicle_ids: dict[str, tuple[int, int]],
    config: BuildConfig,
) -> str:
    """The rule, and the recordings that give `split` (almost) nothing, with their cuts."""
    reasons = []
    for name, per_split in samples.items():
        n_all, n_split = sum(per_split.values()), per_split.get(split.value, 0)
        if n_split >= MIN_SPLIT_SHARE * n_all:
            continue
        largest, second = top_vehicle_ids[name]
        first_cut, second_cut = _vehicle_cuts(largest, config)
        outlier = f", far above the next largest ({second:,})" if largest > 1.5 * second else ""
        reasons.append(
            f"{name} gives it {n_split:,} of {n_all:,}: its largest Vehicle_ID is {largest:,}{outlier}, "
            f"so the cuts lie at {first_cut:,} and {second_cut:,}"
        )
    train, val, _ = config.split_fractions
    rule = (
        f"the vehicle split (CS-LSTM's rule) trains egos with Vehicle_ID <= round({train:g} * the "
        f"recording's largest ID) and validates those <= round({train + val:g} * it)"
    )
    return f": {rule}; " + "; ".join(reasons[:3]) if reasons else f": {rule}"


def split_warnings(
    samples: dict[str, dict[str, int]],
    top_vehicle_ids: dict[str, tuple[int, int]],
    config: BuildConfig,
) -> list[str]:
    """One line for each split that is empty or holds under MIN_SPLIT_SHARE of the samples, with
    the likely reason. `samples`: each recording's number of samples per split (a split left
    out: none), by "location/period", in the recordings' order; `top_vehicle_ids`: the largest
    and second largest Vehicle_ID of each recording, by the same names."""
    total = sum(sum(per_split.values()) for per_split in samples.values())
    warnings = []
    for split in SPLIT_ORDER:
        n = sum(per_split.get(split.value, 0) for per_split in samples.values())
        if total == 0 or n >= MIN_SPLIT_SHARE * total:
            continue
        what = "is empty" if n == 0 else f"holds {n:,} of {total:,} samples ({n / total:.1%})"
        if config.split_fractions[SPLIT_ORDER.index(split)] == 0:
            why = ": its fraction is 0"
        elif config.split is SplitMode.VEHICLE:
            why = _why_vehicle_split_is_small(samples, split, top_vehicle_ids, config)
        else:
            why = f": {total:,} samples are too few for a {config.split.value} split"
        warnings.append(f"the {split.value} split {what}{why}")
    return warnings
