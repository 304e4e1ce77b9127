"""CS-LSTM's dataset (`preprocess_data.m`): the rules of docs/cslstm.md on one recording's rows,
and the cs-lstm protocol of a build (`CS_LSTM`), whose samples are the script's kept rows.

The rules are pure numpy over one recording's raw rows in the script's row order (by
Vehicle_ID, then Frame_ID, stable), every value float32 as the script computes it, feet. Per
row: the lateral and longitudinal maneuver classes and the 39-cell neighbour grid; per
recording: the vehicle split and the edge filter. `tests/cslstm_reference.py` holds the same
rules as plain loops, written from the script's text, and the tests hold the two against each
other. `cslstm_export` writes the script's .mat files with them; a build under the cs-lstm
protocol takes its samples from them (`cslstm_windows`): the stages never import this module,
they are handed `CS_LSTM` (`protocols.PROTOCOLS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from ngsim_graphs import budget
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.graphs import concat_ranges
from ngsim_graphs.manifest import ScriptRows
from ngsim_graphs.sources.contract import RecordingKey, frames_per_step
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import FRAME_PERIOD_S
from ngsim_graphs.splits import VehicleIds
from ngsim_graphs.windows import RecordingWindows, SampleProtocol

GRID_CELLS = 39  # 13 cells of 15 ft along each of the left, own and right lanes
TRAJ_COLUMNS = 8 + GRID_CELLS  # dataset, vehicle, frame, x, y, lane, lateral, longitudinal, grid
US101_DATASETS = (1, 2, 3)  # their lanes 6, 7, 8 (auxiliary, on-ramp, off-ramp) fold into 6
GRID_REACH_FT = 90.0
GRID_CELL_FT = 15.0
LATERAL_WINDOW_ROWS = 40
HISTORY_WINDOW_ROWS, FUTURE_WINDOW_ROWS = 30, 50  # of the longitudinal maneuver
BRAKING_RATIO = 0.8
HISTORY_ROWS = 30  # the edge filter: a row needs 30 rows of its vehicle before it
_LANE_BASE = {-1: 1, 0: 14, 1: 27}  # first cell (1-based) of the left, own and right lane
# The script's dataset ids, by our recording key (location, period).
DATASET_IDS: dict[tuple[str, str], int] = {
    ("us-101", "0750am-0805am"): 1,
    ("us-101", "0805am-0820am"): 2,
    ("us-101", "0820am-0835am"): 3,
    ("i-80", "0400-0415"): 4,
    ("i-80", "0500-0515"): 5,
    ("i-80", "0515-0530"): 6,
}
RECORDING_OF_DATASET = {dataset_id: key for key, dataset_id in DATASET_IDS.items()}
SPLIT_NAMES = ("train", "val", "test")  # split codes 0, 1, 2 (split_codes)
# The raw columns the script reads (script_rows).
SCRIPT_COLUMNS = (s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_X, ns.LOCAL_Y, s.LANE_ID)


@dataclass(frozen=True)
class RecordingRows:
    """One recording's raw rows in the script's row order; (n,) float32 each, feet."""

    dataset_id: int  # 1..6, the script's order (docs/cslstm.md)
    vehicle: np.ndarray
    frame: np.ndarray
    x_ft: np.ndarray
    y_ft: np.ndarray
    lane: np.ndarray  # as recorded; fold_lanes gives the script's


def row_order(vehicle: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Indices putting rows in the official text files' order: by vehicle, then frame, stable."""
    return np.lexsort((frame, vehicle))


def ordered_rows(
    dataset_id: int,
    vehicle: np.ndarray,
    frame: np.ndarray,
    x_ft: np.ndarray,
    y_ft: np.ndarray,
    lane: np.ndarray,
) -> RecordingRows:
    """One recording's raw rows (any order, NGSIM units) in the script's order, as float32."""
    order = row_order(np.asarray(vehicle), np.asarray(frame))
    columns = (np.asarray(c)[order].astype(np.float32) for c in (vehicle, frame, x_ft, y_ft, lane))
    return RecordingRows(dataset_id, *columns)


def fold_lanes(lane: np.ndarray, dataset_id: int) -> np.ndarray:
    """US-101's lanes 6 and above become 6; I-80's stay."""
    lane = np.asarray(lane, dtype=np.float32)
    return np.minimum(lane, np.float32(6)) if dataset_id in US101_DATASETS else lane


def matlab_round(values: np.ndarray) -> np.ndarray:
    """MATLAB's round (halves away from zero), exact in float32 for values >= 0."""
    whole = np.floor(values)
    return whole + (values - whole >= 0.5)


def vehicle_bounds(vehicle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) row of each vehicle's run of rows, rows in the script's order."""
    n = len(vehicle)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.flatnonzero(np.r_[True, vehicle[1:] != vehicle[:-1]])
    return starts, np.r_[starts[1:], n]


def _vehicle_runs(vehicle: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per row: the first row of its vehicle, its vehicle's row count, and the index (within the
    vehicle) of the first row of its frame (a repeated frame takes its first occurrence)."""
    n = len(vehicle)
    starts, ends = vehicle_bounds(vehicle)
    new_vehicle = np.zeros(n, bool)
    new_vehicle[starts] = True
    lengths = ends - starts
    owner = np.repeat(np.arange(len(starts)), lengths)
    first = starts[owner]
    new_frame = new_vehicle | np.r_[True, frame[1:] != frame[:-1]] if n else new_vehicle
    frame_first = np.maximum.accumulate(np.where(new_frame, np.arange(n), 0))
    return first, lengths[owner], frame_first - first


def maneuvers(rows: RecordingRows, lane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) lateral (1 keep, 2 lane number falls, 3 it grows) and longitudinal (1 keep,
    2 braking) classes, float32, by the script's row-index windows."""
    first, count, i = _vehicle_runs(rows.vehicle, rows.frame)
    last = count - 1
    lo = first + np.maximum(0, i - LATERAL_WINDOW_ROWS)
    hi = first + np.minimum(last, i + LATERAL_WINDOW_ROWS)
    now = lane[first + i]
    grows = (lane[hi] > now) | (now > lane[lo])
    falls = (lane[hi] < now) | (now < lane[lo])
    lateral = np.where(grows, 3, np.where(falls, 2, 1)).astype(np.float32)

    lo = np.maximum(0, i - HISTORY_WINDOW_ROWS)
    hi = np.minimum(last, i + FUTURE_WINDOW_ROWS)
    y = rows.y_ft
    y_now = y[first + i]
    with np.errstate(divide="ignore", invalid="ignore"):
        v_hist = (y_now - y[first + lo]) / (i - lo).astype(np.float32)
        v_fut = (y[first + hi] - y_now) / (hi - i).astype(np.float32)
        braking = (v_fut / v_hist).astype(np.float64) < BRAKING_RATIO
    edge = (hi == i) | (lo == i)
    longitudinal = np.where(~edge & braking, 2, 1).astype(np.float32)
    return lateral, longitudinal


@dataclass(frozen=True)
class _SortedRows:
    """A recording's rows sorted by (frame, lane, y): `order` the row indices, `key` the keys."""

    order: np.ndarray
    key: np.ndarray


def _group(rows: RecordingRows, lane: np.ndarray) -> np.ndarray:
    return rows.frame.astype(np.float64) * 64 + lane.astype(np.float64)  # lanes: small numbers


def _key(group: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(frame, lane) group and y in one float64, y shifted so that |y| < 5e4 ft stays inside."""
    return group * 1e5 + (y.astype(np.float64) + 5e4)


def _sorted_rows(rows: RecordingRows, lane: np.ndarray) -> _SortedRows:
    group = _group(rows, lane)
    order = np.lexsort((rows.y_ft, group))
    return _SortedRows(order, _key(group[order], rows.y_ft[order]))


def _lane_pairs(
    rows: RecordingRows, lane: np.ndarray, ordered: _SortedRows, chunk: slice, offset: int
) -> tuple[np.ndarray, ...]:
    """(row, neighbour row, float32 dy) of every row of `chunk` and each row of the same frame
    in lane `lane + offset` within the grid's reach (|dy| < 90 ft; dy != 0 in the own lane)."""
    y = rows.y_ft
    mine = np.arange(len(y))[chunk]
    wanted = _key(_group(rows, lane)[chunk] + offset, y[chunk])
    low = np.searchsorted(ordered.key, wanted - GRID_REACH_FT - 1, "left")
    high = np.searchsorted(ordered.key, wanted + GRID_REACH_FT + 1, "right")
    owner, position = concat_ranges(low, high)
    row = mine[owner]
    neighbour = ordered.order[position]
    dy = y[neighbour] - y[row]  # float32, as the script subtracts
    same_frame = rows.frame[neighbour] == rows.frame[row]
    near = same_frame & (lane[neighbour] == lane[row] + np.float32(offset))
    near &= np.abs(dy) < np.float32(GRID_REACH_FT)
    if offset == 0:
        near &= dy != 0
    return row[near], neighbour[near], dy[near]


def grid(rows: RecordingRows, lane: np.ndarray, chunk_rows: int | None = None) -> np.ndarray:
    """(n, 39) float32 neighbour Vehicle_IDs by cell, 0 where empty; of several rows in one cell
    the last in row order. Rows are taken `chunk_rows` at a time to bound the memory."""
    chunk_rows = chunk_rows or budget.BUDGET.cslstm_grid_rows
    n = len(rows.vehicle)
    cells = np.zeros((n, GRID_CELLS), dtype=np.float32)
    ordered = _sorted_rows(rows, lane)
    for start in range(0, n, chunk_rows):
        chunk = slice(start, min(n, start + chunk_rows))
        parts = [_lane_pairs(rows, lane, ordered, chunk, offset) for offset in (-1, 0, 1)]
        row = np.concatenate([p[0] for p in parts])
        neighbour = np.concatenate([p[1] for p in parts])
        quotient = [(p[2] + np.float32(GRID_REACH_FT)) / np.float32(GRID_CELL_FT) for p in parts]
        base = np.concatenate(
            [np.full(len(p[0]), _LANE_BASE[o]) for p, o in zip(parts, (-1, 0, 1), strict=True)]
        )
        cell = base + matlab_round(np.concatenate(quotient)).astype(np.int64) - 1  # 0-based
        order = np.lexsort((neighbour, cell, row))  # the last neighbour (row order) of each cell
        row, cell, neighbour = row[order], cell[order], neighbour[order]
        last = np.r_[(row[1:] != row[:-1]) | (cell[1:] != cell[:-1]), True] if len(row) else []
        cells[row[last], cell[last]] = rows.vehicle[neighbour[last]]
    return cells


def traj_rows(rows: RecordingRows) -> np.ndarray:
    """(n, 47) float32: the script's columns of every row, before the split and edge filter."""
    lane = fold_lanes(rows.lane, rows.dataset_id)
    lateral, longitudinal = maneuvers(rows, lane)
    head = np.stack(
        [
            np.full(len(rows.vehicle), rows.dataset_id, dtype=np.float32),
            rows.vehicle,
            rows.frame,
            rows.x_ft,
            rows.y_ft,
            lane,
            lateral,
            longitudinal,
        ],
        axis=1,
    ).astype(np.float32)
    return np.concatenate([head, grid(rows, lane)], axis=1)


def split_limits(max_vehicle_id: float) -> tuple[float, float]:
    """(ul1, ul2): train `id <= ul1`, validation `ul1 < id <= ul2`, test above (float32)."""
    largest = np.float32(max_vehicle_id)
    return (
        float(matlab_round(np.float32(0.7) * largest)),
        float(matlab_round(np.float32(0.8) * largest)),
    )


def split_codes(rows: RecordingRows) -> np.ndarray:
    """(n,) int8 per row: 0 train, 1 validation, 2 test, by the vehicle id and the recording's
    largest one (split_limits)."""
    if len(rows.vehicle) == 0:
        return np.zeros(0, dtype=np.int8)
    ul1, ul2 = split_limits(float(rows.vehicle.max()))
    return ((rows.vehicle > ul1).astype(np.int8) + (rows.vehicle > ul2)).astype(np.int8)


def kept_by_edge_filter(rows: RecordingRows) -> tuple[np.ndarray, np.ndarray]:
    """(kept, too_short), (n,) bool each: a row is kept when its vehicle's 31st row comes at or
    before it and its vehicle's last frame more than one frame after it. `too_short`: rows of
    vehicles with under 31 rows, which make the script stop; dropped here and counted."""
    first, count, _ = _vehicle_runs(rows.vehicle, rows.frame)
    too_short = count <= HISTORY_ROWS
    history_frame = rows.frame[np.minimum(first + HISTORY_ROWS, len(rows.frame) - 1)]
    last_frame = rows.frame[first + count - 1]
    kept = ~too_short & (history_frame <= rows.frame) & (last_frame > rows.frame + 1)
    return kept, too_short


def script_rows(
    raw: pl.DataFrame, dataset_id: int, config: BuildConfig
) -> tuple[pl.DataFrame, int, int]:
    """The rows of one recording that CS-LSTM's `preprocess_data.m` keeps (docs/cslstm.md), on
    the grid: (table, kept, too_short). The table has one row per (vehicle, step) with its split
    (VEHICLE_ID, STEP, SPLIT), in the script's row order; `kept` counts every kept row, on the
    grid or not; `too_short` the rows of vehicles under 31 rows (the script stops on them).

    `raw`: the recording's rows before cleaning (RAW_SCHEMA columns, any order, duplicates and
    all). A kept row is on the grid when its Frame_ID is a multiple of NGSIM's frames per step;
    its step is Frame_ID / frames per step; the rows of one vehicle and frame make one row.
    """
    frames = frames_per_step(config.time_step_s, FRAME_PERIOD_S)
    ordered = ordered_rows(
        dataset_id, *(raw[c].cast(pl.Float64).to_numpy() for c in SCRIPT_COLUMNS)
    )
    kept, too_short = kept_by_edge_filter(ordered)
    split = split_codes(ordered)[kept]
    frame = ordered.frame[kept].astype(np.int64)
    on_grid = frame % frames == 0
    table = pl.DataFrame(
        {
            s.VEHICLE_ID: ordered.vehicle[kept][on_grid].astype(np.int32),
            s.STEP: (frame[on_grid] // frames).astype(np.int32),
            s.SPLIT: pl.Series(split[on_grid]).replace_strict(
                dict(enumerate(SPLIT_NAMES)), return_dtype=pl.String
            ),
        },
        schema={s.VEHICLE_ID: pl.Int32, s.STEP: pl.Int32, s.SPLIT: pl.String},
    ).unique(subset=[s.VEHICLE_ID, s.STEP], keep="first", maintain_order=True)
    return table, int(kept.sum()), int(too_short.sum())


def script_windows(
    raw: pl.DataFrame, nodes: pl.DataFrame | pl.LazyFrame, dataset_id: int, config: BuildConfig
) -> tuple[pl.DataFrame, ScriptRows]:
    """The samples of the cs-lstm protocol of one recording, as ego windows with s.SPLIT.

    One sample per script row on the grid (`script_rows`) whose vehicle has a track at that step
    in `nodes` (the recording's grid nodes, GRID_NODE_SCHEMA): the ego is that track, the present
    that step, and the window starts history_steps - 1 steps before it (the ego may be absent at
    earlier steps: its track may start later, at a gap or where cleaning removed rows). The rows
    without such a track are counted (`ScriptRows.unmatched`). Columns and order as
    `ego_windows`, plus s.SPLIT.
    """
    rows, kept, too_short = script_rows(raw, dataset_id, config)
    ego = nodes.lazy().select(
        s.VEHICLE_ID,
        s.STEP,
        pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
        pl.col(s.X_M).alias(s.ORIGIN_X_M),
        pl.col(s.Y_M).alias(s.ORIGIN_Y_M),
    )
    windows = (
        rows.lazy()
        .join(ego, on=[s.VEHICLE_ID, s.STEP], how="inner")
        .select(
            s.EGO_TRACK_ID,
            pl.col(s.VEHICLE_ID).alias(s.EGO_VEHICLE_ID),
            (pl.col(s.STEP) - (config.history_steps - 1)).cast(pl.Int32).alias(s.START_STEP),
            pl.col(s.STEP).alias(s.PRESENT_STEP),
            s.ORIGIN_X_M,
            s.ORIGIN_Y_M,
            s.SPLIT,
        )
        .collect(engine="streaming")
        .sort(s.EGO_TRACK_ID, s.START_STEP)
    )
    counts = ScriptRows(kept, too_short, rows.height, rows.height - windows.height)
    return windows, counts


def cslstm_windows(
    nodes: pl.DataFrame | pl.LazyFrame,
    raw: pl.LazyFrame,
    key: RecordingKey,
    recording_index: int,
    config: BuildConfig,
) -> RecordingWindows:
    """The cs-lstm protocol's samples of one recording (`script_windows`) from its staged rows
    before cleaning (`raw`: their SCRIPT_COLUMNS are read); the vehicle split's ids are those
    rows' own, and its largest the largest, stray or not.

    `raw` may come in any order but that of a vehicle's rows of one frame (`ordered_rows` sorts
    stably): those are in one part, read from its files in the order they were read."""
    rows = raw.select(SCRIPT_COLUMNS).collect()
    vehicle_ids = VehicleIds.of(rows[s.VEHICLE_ID].unique().to_numpy(), strays_allowed=False)
    windows, counts = script_windows(rows, nodes, DATASET_IDS.get(key, 0), config)
    return RecordingWindows(windows, vehicle_ids, counts)


def refused_recording(key: RecordingKey) -> str | None:
    """Why the cs-lstm protocol cannot take recording `key`: it is none of the script's six."""
    if key in DATASET_IDS:
        return None
    official = ", ".join(f"{loc} {period}" for loc, period in DATASET_IDS)
    return (
        f"recording {key[0]}/{key[1]} is not one of the six that CS-LSTM's script reads "
        f"({official}); the cs-lstm protocol takes those only"
    )


def why_no_samples(script: ScriptRows | None, rows: int, config: BuildConfig) -> str | None:
    """Why the script's rows (of `rows` raw rows in all) gave no sample."""
    if script is None:
        return None
    return (
        f"CS-LSTM's script keeps {script.kept:,} of the {rows:,} rows (and would stop on "
        f"the {script.too_short:,} rows of vehicles under 31 rows), {script.on_grid:,} of "
        f"them on the {config.time_step_s} s grid, {script.unmatched:,} of those with no "
        "track at their step"
    )


CS_LSTM = SampleProtocol(
    cslstm_windows,
    refused_recording,
    why_no_samples,
    (("us-101", "i-80"), "CS-LSTM's six recordings"),
)
