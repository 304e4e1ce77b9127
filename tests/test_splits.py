"""Train / validation / test splits of ego windows: the vehicle rule by hand, the random split by
ego track, the time split in contiguous blocks with a gap of one window."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.schema import SplitMode
from ngsim_graphs.splits import (
    VehicleIds,
    assign_splits,
    split_by_time,
    split_by_vehicle,
    split_randomly,
    split_warnings,
)


def windows_of(ego_tracks: list[int], vehicles: list[int], presents: list[int]) -> pl.DataFrame:
    return pl.DataFrame(
        {
            s.EGO_TRACK_ID: ego_tracks,
            s.EGO_VEHICLE_ID: vehicles,
            s.START_STEP: [p - 15 for p in presents],
            s.PRESENT_STEP: presents,
        },
        schema={
            s.EGO_TRACK_ID: pl.Int32,
            s.EGO_VEHICLE_ID: pl.Int32,
            s.START_STEP: pl.Int32,
            s.PRESENT_STEP: pl.Int32,
        },
    )


def test_vehicle_rule_max_id_100() -> None:
    ids = [1, 69, 70, 71, 75, 80, 81, 99, 100]
    labels = split_by_vehicle(windows_of(ids, ids, [20] * len(ids)), 100, BuildConfig()).to_list()
    assert labels == ["train", "train", "train", "val", "val", "val", "test", "test", "test"]


@pytest.mark.parametrize(
    ("max_id", "last_train", "last_val"),
    [
        (101, 71, 81),  # 70.7 -> 71, 80.8 -> 81
        (11, 8, 9),  # 7.7 -> 8, 8.8 -> 9
        (45, 31, 36),  # 31.49999... -> 31
        (15, 11, 12),  # 0.7 * 15 = 10.5: MATLAB's round (CS-LSTM) goes away from zero, to 11
        (25, 18, 20),  # 17.5 -> 18
        (35, 25, 28),  # 24.5 -> 25 (Python's round would give 24)
    ],
)
def test_vehicle_rule_rounds_like_matlab(max_id: int, last_train: int, last_val: int) -> None:
    ids = list(range(1, max_id + 1))
    labels = split_by_vehicle(windows_of(ids, ids, [20] * max_id), max_id, BuildConfig()).to_list()
    assert labels == ["train"] * last_train + ["val"] * (last_val - last_train) + ["test"] * (
        max_id - last_val
    )


def test_vehicle_split_keeps_each_window_once_and_each_vehicle_in_one_split() -> None:
    rng = np.random.default_rng(3)
    vehicles = rng.integers(1, 300, 2000)
    tracks = vehicles * 2 + rng.integers(0, 2, 2000)  # two tracks per vehicle
    presents = rng.integers(15, 4000, 2000)
    windows = windows_of(tracks.tolist(), vehicles.tolist(), presents.tolist()).unique(
        [s.EGO_TRACK_ID, s.START_STEP], maintain_order=True
    )
    out = assign_splits(windows, 300, 0, BuildConfig(split=SplitMode.VEHICLE))
    assert out.height == windows.height
    assert out.select(s.EGO_TRACK_ID, s.START_STEP).is_duplicated().sum() == 0
    assert out.group_by(s.EGO_VEHICLE_ID).agg(pl.col(s.SPLIT).n_unique())[s.SPLIT].max() == 1


def many_track_windows(n_tracks: int, rng: np.random.Generator) -> pl.DataFrame:
    """1-4 windows per track (stride 40)."""
    per_track = rng.integers(1, 5, n_tracks)
    tracks = np.repeat(np.arange(n_tracks), per_track)
    index = np.concatenate([np.arange(n) for n in per_track])
    presents = rng.integers(15, 3000, n_tracks)[tracks] + 40 * index
    return windows_of(tracks.tolist(), (tracks + 1).tolist(), presents.tolist())


def test_random_split_by_ego_track_seeded() -> None:
    windows = many_track_windows(6000, np.random.default_rng(11))
    config = BuildConfig(split=SplitMode.RANDOM, seed=5)
    labels = split_randomly(windows, 0, config)
    framed = windows.with_columns(labels)
    assert framed.group_by(s.EGO_TRACK_ID).agg(pl.col(s.SPLIT).n_unique())[s.SPLIT].max() == 1
    assert labels.equals(split_randomly(windows, 0, config))  # same seed, same result
    assert not labels.equals(
        split_randomly(windows, 0, BuildConfig(split=SplitMode.RANDOM, seed=6))
    )
    assert not labels.equals(split_randomly(windows, 1, config))  # each recording draws its own
    per_track = framed.unique(s.EGO_TRACK_ID)[s.SPLIT].value_counts(normalize=True)
    share = dict(per_track.iter_rows())
    assert share["train"] == pytest.approx(0.7, abs=0.02)
    assert share["val"] == pytest.approx(0.1, abs=0.015)
    assert share["test"] == pytest.approx(0.2, abs=0.02)
    # assign_splits keeps every window of a random split, with these labels.
    out = assign_splits(windows, 6000, 0, config)
    assert out[s.SPLIT].equals(labels)


def test_time_split_blocks_and_gaps() -> None:
    config = BuildConfig(split=SplitMode.TIME)
    k_h, k_f = config.history_steps, config.future_steps
    windows = many_track_windows(3000, np.random.default_rng(2))
    out = assign_splits(windows, 3000, 0, config)
    blocks = {
        name: out.filter(pl.col(s.SPLIT) == name)[s.PRESENT_STEP]
        for name in ("train", "val", "test")
    }
    train, val, test = (blocks[n] for n in ("train", "val", "test"))
    assert min(len(train), len(val), len(test)) > 0
    # Contiguous blocks of present time, in order, with a gap between them.
    for early, late in ((train, val), (val, test), (train, test)):
        # an earlier window's last future step comes before a later one's first history step
        assert early.max() + k_f < late.min() - k_h + 1
    # Exactly the windows in the gaps are dropped.
    presents = np.sort(windows[s.PRESENT_STEP].to_numpy())
    first, second = presents[int(0.7 * len(presents))], presents[int(0.8 * len(presents))]
    all_presents = windows[s.PRESENT_STEP]
    assert train.len() == (all_presents < first).sum()
    assert val.len() == ((all_presents >= first + 41) & (all_presents < second)).sum()
    assert test.len() == (all_presents >= second + 41).sum()
    assert out.height == train.len() + val.len() + test.len() < windows.height
    assert train.len() / windows.height == pytest.approx(0.7, abs=0.02)


def test_time_split_by_hand() -> None:
    # 100 windows, presents 15, 25, ..., 1005: the 70 % cut is the 71st (present 715), the 80 %
    # cut the 81st (815). Train: present < 715. Dropped: [715, 756) and [815, 856).
    presents = list(range(15, 1015, 10))
    windows = windows_of(list(range(100)), list(range(1, 101)), presents)
    labels = split_by_time(windows, BuildConfig(split=SplitMode.TIME)).to_list()
    assert labels == ["train"] * 70 + [None] * 5 + ["val"] * 5 + [None] * 5 + ["test"] * 15
    assert [p for p, label in zip(presents, labels, strict=True) if label == "val"] == [
        765,
        775,
        785,
        795,
        805,
    ]


def test_time_split_80_percent_cut_of_20_windows() -> None:
    # 20 windows 100 steps apart: train the first 14, validation the next 2, test the last 4;
    # the first window of each later block is within one window length of its start: dropped.
    presents = list(range(100, 2100, 100))
    windows = windows_of(list(range(20)), list(range(1, 21)), presents)
    labels = split_by_time(windows, BuildConfig(split=SplitMode.TIME)).to_list()
    assert labels == ["train"] * 14 + [None, "val"] + [None, "test", "test", "test"]


def test_time_split_of_no_windows() -> None:
    assert split_by_time(windows_of([], [], []), BuildConfig(split=SplitMode.TIME)).len() == 0


def test_split_warnings_say_why_with_the_builds_own_fractions() -> None:
    # Recording r: egos 1..10 (one window each) and an outlying largest Vehicle_ID 1,000.
    windows = pl.DataFrame({
        s.LOCATION: ["us-101"] * 10, s.PERIOD: ["r"] * 10, s.EGO_VEHICLE_ID: list(range(1, 11)),
    })  # fmt: skip
    config = BuildConfig(split_fractions=(0.5, 0.25, 0.25))
    windows = windows.with_columns(split_by_vehicle(windows, 1_000, config).alias(s.SPLIT))
    assert windows[s.SPLIT].to_list() == ["train"] * 10  # cuts at 500 and 750
    ids = {"us-101/r": VehicleIds(1_000, 10)}
    warnings = split_warnings({"us-101/r": {"train": 10}}, ids, config)
    assert [w.split(":")[0] for w in warnings] == [
        "the val split is empty",
        "the test split is empty",
    ]
    assert (
        "<= round(0.5 * the recording's largest ID) and validates those <= round(0.75 * it)"
        in warnings[0]
    )
    assert (
        "us-101/r gives it 0 of 10: its largest Vehicle_ID is 1,000, far above the next largest "
        "(10), so the cuts lie at 500 and 750" in warnings[0]
    )
    one = split_warnings({"us-101/one": {"train": 4}}, {"us-101/one": VehicleIds(3, 0)}, config)
    assert one[0].endswith(  # not "far above the next largest (0)": there is none
        "us-101/one gives it 0 of 4: its only Vehicle_ID is 3, so the cuts lie at 2 and 2"
    )
    only_val = BuildConfig(split_fractions=(0.0, 1.0, 0.0))
    assert split_warnings({"us-101/r": {"val": 10}}, {}, only_val) == [
        "the train split is empty: its fraction is 0", "the test split is empty: its fraction is 0",
    ]  # fmt: skip


def test_split_warnings_name_the_recordings_that_give_a_split_too_little_in_their_order() -> None:
    # a: 100 samples, 1 in test (1 % < 2 %); b: none at all (skipped); c: 50, none in test.
    samples = {
        "us-101/a": {"train": 80, "val": 19, "test": 1},
        "us-101/b": {"train": 0, "val": 0, "test": 0},
        "i-80/c": {"train": 40, "val": 10},
    }
    top = {
        "us-101/a": VehicleIds(1_000, 990),
        "us-101/b": VehicleIds(5, 4),
        "i-80/c": VehicleIds(3_000, 1_000),
    }
    config = BuildConfig(split_fractions=(0.5, 0.25, 0.25))
    warnings = split_warnings(samples, top, config)
    assert len(warnings) == 1
    assert warnings[0].startswith("the test split holds 1 of 150 samples (0.7%): the vehicle split")
    assert warnings[0].endswith(
        "us-101/a gives it 1 of 100: its largest Vehicle_ID is 1,000, so the cuts lie at 500 and "
        "750; i-80/c gives it 0 of 50: its largest Vehicle_ID is 3,000, far above the next "
        "largest (1,000), so the cuts lie at 1,500 and 2,250"
    )


def test_stray_vehicle_ids_by_hand() -> None:
    # Ids 1..10: median 5.5, so an id above 3 * 5.5 + 100 = 116.5 is a stray.
    assert VehicleIds.of(np.array([3, 1, 2, 10, 4, 5, 6, 7, 8, 9, 10])) == VehicleIds(10, 9)
    assert VehicleIds.of(np.arange(1, 11).tolist() + [116]) == VehicleIds(116, 10)
    # Twelve ids: median 6.5, limit 119.5.
    assert VehicleIds.of(np.arange(1, 11).tolist() + [120, 99_999]) == VehicleIds(
        10, 9, (120, 99_999)
    )
    assert VehicleIds.of(np.array([99_999]), strays_allowed=True) == VehicleIds(99_999, 0)
    # CS-LSTM's script takes the largest id, whatever it is.
    assert VehicleIds.of(np.array([1, 2, 99_999]), strays_allowed=False) == VehicleIds(99_999, 2)
    assert VehicleIds.of(np.array([], dtype=np.int64)) == VehicleIds(0, 0)


def test_a_recording_that_gives_a_split_nothing_is_named() -> None:
    samples = {"us-101/a": {"train": 70, "val": 10, "test": 20}, "i-80/b": {"train": 2, "test": 1}}
    ids = {"us-101/a": VehicleIds(100, 99), "i-80/b": VehicleIds(3, 2)}
    assert split_warnings(samples, ids, BuildConfig()) == [
        "the val split has no sample of i-80/b: the vehicle split (CS-LSTM's rule) trains egos "
        "with Vehicle_ID <= round(0.7 * the recording's largest ID) and validates those <= "
        "round(0.8 * it); i-80/b gives it 0 of 3: its largest Vehicle_ID is 3, so the cuts lie "
        "at 2 and 2"
    ]
    strays = {**ids, "i-80/b": VehicleIds(3, 2, (99_999,))}
    assert split_warnings(samples, strays, BuildConfig())[0] == (
        "i-80/b: Vehicle_ID 99,999 lies far above the others (the largest of which is 3): the "
        "vehicle split ignores it and cuts at 2 and 2"
    )
