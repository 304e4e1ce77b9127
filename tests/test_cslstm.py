"""ngsim_graphs.cslstm against the plain-loop reference of CS-LSTM's rules (cslstm_reference),
on random small recordings built to hit the rules' edges, and on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
from cslstm_reference import reference_kept, reference_traj

from ngsim_graphs.cslstm import (
    DATASET_IDS,
    RecordingRows,
    fold_lanes,
    grid,
    kept_by_edge_filter,
    matlab_round,
    ordered_rows,
    row_order,
    split_codes,
    split_limits,
    traj_rows,
)
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS

F = np.float32


def _recording(seed: int, vehicles: int = 14, frames: int = 90) -> np.ndarray:
    """(n, 5) float32 rows [vehicle, frame, x, y, lane] in row order, with lane changes both
    ways, braking, vehicles at exactly 7.5 + 15k ft from others, US-101 lanes 7 and 8, frame
    gaps, repeated frames (one at another y) and short vehicles."""
    rng = np.random.default_rng(seed)
    rows = []
    for vehicle in range(1, vehicles + 1):
        start = int(rng.integers(0, 30))
        length = int(rng.integers(20, frames))  # some under 31 rows
        lane = float(rng.integers(1, 9))
        y = float(rng.choice([0.0, 7.5, 22.5, 82.5, 89.9, 90.0])) + 15.0 * int(rng.integers(0, 6))
        speed = float(rng.uniform(2, 6))
        for frame in range(start, start + length):
            if rng.random() < 0.03:
                continue  # a frame gap: the vehicle is not split
            if rng.random() < 0.04:
                lane = float(np.clip(lane + rng.choice([-1, 1]), 1, 8))
            if frame > start + length // 2 and vehicle % 3 == 0:
                speed *= 0.9  # braking
            y += speed
            rows.append([vehicle, frame, rng.uniform(0, 60), round(y, 3), lane])
            if rng.random() < 0.02:
                rows.append([vehicle, frame, rows[-1][2], round(y + 2.5, 3), lane])  # repeated
    table = np.array(rows, dtype=np.float32)
    return table[row_order(table[:, 0], table[:, 1])]


def _rows(dataset_id: int, table: np.ndarray) -> RecordingRows:
    return RecordingRows(dataset_id, *(np.ascontiguousarray(table[:, k]) for k in range(5)))


@pytest.mark.parametrize(("seed", "dataset_id"), [(1, 1), (2, 4), (3, 3), (4, 6)])
def test_traj_rows_equal_the_reference(seed: int, dataset_id: int) -> None:
    table = _recording(seed)
    fast = traj_rows(_rows(dataset_id, table))
    slow = reference_traj(dataset_id, table)
    assert fast.dtype == np.float32 and fast.shape == slow.shape == (len(table), 47)
    np.testing.assert_array_equal(fast, slow)
    assert set(np.unique(fast[:, 6])) == {1, 2, 3}  # every lateral class occurs
    assert set(np.unique(fast[:, 7])) == {1, 2}
    assert (fast[:, 8:] > 0).any()


@pytest.mark.parametrize("seed", [1, 5])
def test_edge_filter_equals_the_reference(seed: int) -> None:
    table = _recording(seed)
    kept, too_short = kept_by_edge_filter(_rows(1, table))
    assert kept.tolist() == reference_kept(table)
    assert too_short.any() and kept.any() and not (kept & too_short).any()


def test_grid_cells_by_hand() -> None:
    """Row 0 (vehicle 1, lane 2, y 100) at frame 5 and its neighbours:
    - vehicle 2 level in the left lane: cell 1 + round(90/15) = 7;
    - vehicle 3 67.5 ft ahead in its own lane: 14 + round(157.5/15 = 10.5) = 25, a half rounded
      away from zero (numpy's round would give 10);
    - vehicle 4 90 ft behind in the right lane: outside (|dy| < 90 is strict);
    - vehicles 5 and 6, 30 and 29 ft behind: both cell 14 + round(4 or 4.07) = 18, and the later
      row wins."""
    table = np.array(
        [
            [1, 5, 0, 100.0, 2],
            [2, 5, 0, 100.0, 1],
            [3, 5, 0, 167.5, 2],
            [4, 5, 0, 10.0, 3],
            [5, 5, 0, 70.0, 2],
            [6, 5, 0, 71.0, 2],
        ],
        dtype=np.float32,
    )
    grid = traj_rows(_rows(4, table))[0, 8:]
    assert {cell + 1: int(v) for cell, v in enumerate(grid) if v} == {7: 2, 25: 3, 18: 6}


def test_maneuvers_by_hand() -> None:
    """A vehicle that moves up one lane at its 10th row, and brakes to half speed."""
    frames = np.arange(60, dtype=np.float32)
    lane = np.where(frames < 10, 2, 3).astype(np.float32)
    y = np.cumsum(np.where(frames < 30, 4.0, 2.0)).astype(np.float32)
    table = np.stack([np.ones(60), frames, np.zeros(60), y, lane], axis=1).astype(np.float32)
    traj = traj_rows(_rows(5, table))
    assert traj[0, 6] == 3 and traj[9, 6] == 3 and traj[50, 6] == 1  # within 40 rows: 3
    assert traj[0, 7] == 1 and traj[59, 7] == 1  # at either end of the track: keep
    assert traj[20, 7] == 2  # rows 0..20 at 4 ft a frame, rows 20..59 at 96/39: ratio 0.62
    assert traj[55, 7] == 1  # rows 25..55 at 68/30 ft a frame, rows 55..59 at 2: ratio 0.88


def test_matlab_round_and_split_limits() -> None:
    np.testing.assert_array_equal(
        matlab_round(np.array([0.5, 1.5, 2.5, 11.5, 2.49], dtype=np.float32)), [1, 2, 3, 12, 2]
    )
    assert split_limits(15) == (11.0, 12.0)  # 10.5 -> 11 (numpy's round would give 10)
    assert split_limits(2169) == (1518.0, 1735.0)


def test_dataset_ids_name_the_official_recordings_in_the_scripts_order() -> None:
    official = {(r.location, r.period): r.start_epoch_ms for r in OFFICIAL_RECORDINGS}
    assert set(DATASET_IDS) == set(official)
    by_id = sorted(DATASET_IDS, key=DATASET_IDS.__getitem__)
    assert [key[0] for key in by_id] == ["us-101"] * 3 + ["i-80"] * 3
    for first, second in zip(by_id[:2], by_id[1:3], strict=True):  # each location by start
        assert official[first] < official[second]
    assert official[by_id[3]] < official[by_id[4]] < official[by_id[5]]


def test_ordered_rows_and_split_codes() -> None:
    """Rows come out by vehicle then frame, stable for a repeated frame; with 15 the largest id,
    ul1 = round(10.5) = 11 and ul2 = 12: ids 11 train, 12 validation, 13 and 15 test."""
    vehicle = np.array([15, 11, 12, 11, 13, 11])
    frame = np.array([1, 7, 3, 5, 2, 5])
    y = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    rows = ordered_rows(2, vehicle, frame, np.zeros(6), y, np.ones(6))
    assert rows.dataset_id == 2 and rows.y_ft.dtype == np.float32
    assert rows.vehicle.tolist() == [11, 11, 11, 12, 13, 15]
    assert rows.frame.tolist() == [5, 5, 7, 3, 2, 1]
    assert rows.y_ft.tolist() == [3, 5, 1, 2, 4, 0]  # the repeated frame 5 keeps its order
    assert split_codes(rows).tolist() == [0, 0, 0, 1, 2, 2]


def test_grid_in_small_chunks_equals_grid_at_once() -> None:
    rows = _rows(2, _recording(7))
    lane = fold_lanes(rows.lane, rows.dataset_id)
    at_once = grid(rows, lane, chunk_rows=len(rows.vehicle))
    assert (at_once > 0).sum() > 100
    np.testing.assert_array_equal(grid(rows, lane, chunk_rows=7), at_once)


def test_vehicles_at_exact_cell_boundaries_equal_the_reference() -> None:
    """Vehicles in lockstep (4.5 ft a frame) in lanes 1-8, each at a whole multiple of 7.5 ft
    from the others, so that every (dy + 90) / 15 is a whole number or exactly a half at every
    frame, and some |dy| are exactly 90: the reference and the fast path agree cell by cell."""
    rows = []
    for vehicle in range(1, 25):
        lane, offset = 1 + vehicle % 8, 7.5 * (vehicle * 5 % 25)
        rows += [[vehicle, f, 6.0 * lane, offset + 4.5 * f, lane] for f in range(40)]
    table = np.array(rows, dtype=np.float32)
    table = table[row_order(table[:, 0], table[:, 1])]
    for dataset_id in (2, 5):  # US-101 folds lanes 7 and 8 into 6; I-80 keeps them
        fast = traj_rows(_rows(dataset_id, table))
        np.testing.assert_array_equal(fast, reference_traj(dataset_id, table))
        dy = np.abs(table[:, 3][:, None] - table[:, 3][None, :])
        assert (dy == 90).any() and (dy == 82.5).any()  # the edge, and a half: 11.5 -> 12
        assert (fast[:, 8:] > 0).sum() > 500
