"""Dividing ego windows into train, validation and test (docs/conventions.md).

Splits are decided per ego window; actor nodes are never filtered by split: an ego's neighbours
are whoever was there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.schema import Split, SplitMode

SPLIT_ORDER = (Split.TRAIN, Split.VAL, Split.TEST)


def split_named(name: Split | str) -> Split:
    """The split called `name` ("train", "val", "test"); a ValueError naming the valid ones."""
    try:
        return Split(name)
    except ValueError:
        valid = ", ".join(split.value for split in SPLIT_ORDER)
        raise ValueError(f"split {name!r}: must be one of {valid}") from None


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
# A Vehicle_ID above this many times the recording's median id, plus the margin, is a stray (one
# damaged id, 99999): the vehicle split's cuts are taken from the largest of the others. A
# recording numbers its vehicles from about 1 up, so its largest id is about twice its median.
STRAY_ID_FACTOR = 3.0
STRAY_ID_MARGIN = 100


@dataclass(frozen=True)
class VehicleIds:
    """A recording's Vehicle_IDs as the vehicle split sees them."""

    largest: int  # the id its cuts are taken from: the largest that is not a stray
    next_largest: int  # the largest id below it (0 if none)
    strays: tuple[int, ...] = ()  # ids far above the others, which the cuts ignore

    @classmethod
    def of(cls, ids: np.ndarray, strays_allowed: bool = True) -> VehicleIds:
        """From a recording's Vehicle_IDs (any order, repeats allowed). Without
        `strays_allowed` (CS-LSTM's script) the largest id is the largest, whatever it is."""
        unique = np.unique(np.asarray(ids, dtype=np.int64))
        if len(unique) == 0:
            return cls(0, 0)
        stray = np.zeros(len(unique), dtype=bool)
        if strays_allowed:
            stray = unique > STRAY_ID_FACTOR * np.median(unique) + STRAY_ID_MARGIN
        kept = unique[~stray]
        return cls(
            largest=int(kept[-1]),
            next_largest=int(kept[-2]) if len(kept) > 1 else 0,
            strays=tuple(int(i) for i in unique[stray]),
        )


def _vehicle_cuts(max_vehicle_id: int, config: BuildConfig) -> tuple[int, int]:
    train, val, _ = config.split_fractions
    return _matlab_round(train * max_vehicle_id), _matlab_round((train + val) * max_vehicle_id)


def _matlab_round(x: float) -> int:
    """MATLAB's round() for x >= 0: halves go away from zero (10.5 -> 11)."""
    return math.floor(x + 0.5)


def _cuts_of(name: str, ids: VehicleIds, config: BuildConfig) -> str:
    """Where the vehicle split cuts recording `name`, and why there."""
    first_cut, second_cut = _vehicle_cuts(ids.largest, config)
    if ids.next_largest == 0 and not ids.strays:  # one vehicle: no other id to compare with
        largest = f"its only Vehicle_ID is {ids.largest:,}"
    elif ids.next_largest > 0 and 1.5 * ids.next_largest < ids.largest:
        largest = (
            f"its largest Vehicle_ID is {ids.largest:,}, far above the next largest "
            f"({ids.next_largest:,})"
        )
    else:
        largest = f"its largest Vehicle_ID is {ids.largest:,}"
    return f"{largest}, so the cuts lie at {first_cut:,} and {second_cut:,}"


def _vehicle_rule(config: BuildConfig) -> str:
    train, val, _ = config.split_fractions
    return (
        f"the vehicle split (CS-LSTM's rule) trains egos with Vehicle_ID <= round({train:g} * the "
        f"recording's largest ID) and validates those <= round({train + val:g} * it)"
    )


def _short_recordings(
    samples: dict[str, dict[str, int]], split: Split, share: float
) -> list[tuple[str, int, int]]:
    """(name, samples of `split`, samples) of the recordings with samples that give `split`
    no more than `share` of theirs (0: none), in the recordings' order."""
    found = []
    for name, per_split in samples.items():
        n_all, n_split = sum(per_split.values()), per_split.get(split.value, 0)
        if n_all and (n_split == 0 if share == 0 else n_split < share * n_all):
            found.append((name, n_split, n_all))
    return found


def _why(
    short: list[tuple[str, int, int]], vehicle_ids: dict[str, VehicleIds], config: BuildConfig
) -> str:
    """Why these recordings give a split (almost) nothing: the split's rule, and each one's cuts."""
    if config.split is not SplitMode.VEHICLE:
        n_all = sum(n for _, _, n in short)
        return f"{n_all:,} samples are too few for a {config.split.value} split"
    reasons = [
        f"{name} gives it {n:,} of {n_all:,}: {_cuts_of(name, vehicle_ids[name], config)}"
        for name, n, n_all in short[:3]
    ]
    return "; ".join([_vehicle_rule(config), *reasons])


def split_warnings(
    samples: dict[str, dict[str, int]],
    vehicle_ids: dict[str, VehicleIds],
    config: BuildConfig,
) -> list[str]:
    """One line for each split that is empty or holds under MIN_SPLIT_SHARE of the samples, or
    that some recording with samples gives none, with the likely reason; and one for each
    recording whose vehicle split ignored stray Vehicle_IDs. `samples`: each recording's number
    of samples per split (a split left out: none), by "location/period", in the recordings'
    order; `vehicle_ids`: each recording's `VehicleIds`, by the same names."""
    warnings = [
        _stray_note(name, ids, config)
        for name, ids in vehicle_ids.items()
        if ids.strays and config.split is SplitMode.VEHICLE and name in samples
    ]
    total = sum(sum(per_split.values()) for per_split in samples.values())
    for split in SPLIT_ORDER:
        n = sum(per_split.get(split.value, 0) for per_split in samples.values())
        if total == 0:
            continue
        if config.split_fractions[SPLIT_ORDER.index(split)] == 0:
            if n < MIN_SPLIT_SHARE * total:
                warnings.append(f"the {split.value} split {_size(n, total)}: its fraction is 0")
        elif n < MIN_SPLIT_SHARE * total:  # the recordings that give it little, or all
            short = _short_recordings(samples, split, MIN_SPLIT_SHARE) or _short_recordings(
                samples, split, 1.0
            )
            warnings.append(
                f"the {split.value} split {_size(n, total)}: {_why(short, vehicle_ids, config)}"
            )
        elif short := _short_recordings(samples, split, 0):
            names = ", ".join(name for name, _, _ in short)
            warnings.append(
                f"the {split.value} split has no sample of {names}: {_why(short, vehicle_ids, config)}"
            )
    return warnings


def _stray_note(name: str, ids: VehicleIds, config: BuildConfig) -> str:
    one = len(ids.strays) == 1
    listed = ", ".join(f"{i:,}" for i in ids.strays)
    first_cut, second_cut = _vehicle_cuts(ids.largest, config)
    return (
        f"{name}: Vehicle_ID{'' if one else 's'} {listed} {'lies' if one else 'lie'} far above "
        f"the others (the largest of which is {ids.largest:,}): the vehicle split ignores "
        f"{'it' if one else 'them'} and cuts at {first_cut:,} and {second_cut:,}"
    )


def _size(n: int, total: int) -> str:
    return "is empty" if n == 0 else f"holds {n:,} of {total:,} samples ({n / total:.1%})"
