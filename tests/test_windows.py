"""Ego windows per track, counted and placed by hand: 41 steps make one window."""

from __future__ import annotations

import polars as pl
import pytest
from polars.testing import assert_frame_equal

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.windows import AIGEM, ego_windows


def nodes_of(tracks: dict[int, tuple[int, int]]) -> pl.DataFrame:
    """Grid nodes of tracks {track_id: (first step, number of steps)}; vehicle = 100 + track.

    The track drives along +y: at step st it is at (track, 2 * st).
    """
    rows = [
        (step, track, 100 + track, float(track), 2.0 * step, 0.0, 10.0)
        for track, (first, n) in tracks.items()
        for step in range(first, first + n)
    ]
    return pl.DataFrame(rows, schema=s.GRID_NODE_SCHEMA, orient="row").sort(s.STEP, s.TRACK_ID)


@pytest.mark.parametrize(
    ("n_steps", "starts"),
    [
        (1, []),
        (40, []),
        (41, [0]),
        (80, [0]),
        (81, [0, 40]),
        (121, [0, 40, 80]),
        (160, [0, 40, 80]),
    ],
)
def test_windows_per_track_default_stride(n_steps: int, starts: list[int]) -> None:
    config = BuildConfig()
    assert config.window_steps == 41 and config.stride_steps == 40
    windows = ego_windows(nodes_of({3: (7, n_steps)}), config)
    assert windows[s.START_STEP].to_list() == [7 + st for st in starts]


@pytest.mark.parametrize("n_steps", [40, 41, 42, 60, 90])
def test_stride_one_gives_n_minus_40_windows(n_steps: int) -> None:
    config = BuildConfig(stride_s=0.2)
    windows = ego_windows(nodes_of({0: (5, n_steps)}), config)
    assert windows[s.START_STEP].to_list() == list(range(5, 5 + n_steps - 40))


def test_window_rows_present_step_and_origin() -> None:
    config = BuildConfig()
    windows = ego_windows(nodes_of({4: (10, 81), 2: (0, 41), 9: (3, 30)}), config)
    assert windows.columns == [
        s.EGO_TRACK_ID, s.EGO_VEHICLE_ID, s.START_STEP, s.PRESENT_STEP, s.ORIGIN_X_M, s.ORIGIN_Y_M
    ]  # fmt: skip
    # Track 2: start 0, present 15, at (2, 30). Track 4: starts 10 and 50, presents 25 and 65.
    assert windows.rows() == [
        (2, 102, 0, 15, 2.0, 30.0),
        (4, 104, 10, 25, 4.0, 50.0),
        (4, 104, 50, 65, 4.0, 130.0),
    ]


def test_windows_with_other_history_and_future_lengths() -> None:
    config = BuildConfig(history_steps=3, future_steps=2, stride_s=0.4)
    windows = ego_windows(nodes_of({1: (0, 9)}), config)
    # window of 5 steps, stride 2: starts 0, 2, 4 (4 + 5 = 9 steps), presents 2, 4, 6
    assert windows.select(s.START_STEP, s.PRESENT_STEP).rows() == [(0, 2), (2, 4), (4, 6)]
    assert windows[s.ORIGIN_Y_M].to_list() == [4.0, 8.0, 12.0]


def test_no_tracks_no_windows() -> None:
    assert ego_windows(nodes_of({}), BuildConfig()).height == 0


def test_a_lazy_table_of_nodes_in_any_order_gives_the_same_windows() -> None:
    """What a build passes: the grid nodes streamed from the tracks table, in its order."""
    config = BuildConfig(stride_s=0.4)
    nodes = nodes_of({4: (10, 81), 2: (0, 41), 9: (3, 30)})
    shuffled = nodes.sample(fraction=1.0, shuffle=True, seed=1).lazy()
    expected = ego_windows(nodes, config)
    assert expected.height > 20
    assert_frame_equal(ego_windows(shuffled, config), expected)


def test_the_aigem_protocol_splits_the_windows_by_vehicle_and_never_reads_raw_rows() -> None:
    """Tracks 1..10 (vehicles 101..110) of 41 steps: one window each. The vehicle split cuts at
    round(0.7 * 110) = 77 and round(0.8 * 110) = 88: every vehicle id is above both (test)."""
    nodes = nodes_of(dict.fromkeys(range(1, 11), (0, 41)))
    unread = pl.LazyFrame({"never": [1]}).select(pl.col("missing"))  # fails if collected
    made = AIGEM.recording_windows(nodes, unread, ("us-101", "p"), 0, BuildConfig())
    assert made.windows[s.EGO_VEHICLE_ID].to_list() == list(range(101, 111))
    assert made.windows[s.SPLIT].unique().to_list() == ["test"]
    assert (made.vehicle_ids.largest, made.script_rows) == (110, None)
    assert AIGEM.refuses(("anywhere", "any time")) is None
