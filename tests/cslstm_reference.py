"""CS-LSTM's `preprocess_data.m` rules (docs/cslstm.md) as plain loops over rows, one row at a
time as the script goes: slow on purpose, the reference the fast ngsim_graphs.cslstm is held to.
Written from the script's text and the docs, sharing no code with the fast path."""

from __future__ import annotations

import math

import numpy as np

F = np.float32


def _round(value: np.float32) -> int:
    """MATLAB's round of a non-negative value: halves away from zero (exact in double)."""
    return math.floor(float(value) + 0.5)


def reference_traj(dataset_id: int, table: np.ndarray) -> np.ndarray:
    """(n, 47) float32 from (n, 5) float32 rows [vehicle, frame, x, y, lane] in row order."""
    rows = [[F(dataset_id), *map(F, row)] for row in table]
    if dataset_id <= 3:
        for row in rows:
            row[5] = min(row[5], F(6))
    out = []
    for row in rows:
        ds, vehicle, time, _, y, lane = row
        own = [r for r in rows if r[1] == vehicle]  # the vehicle's rows, in row order
        ind = next(k for k, r in enumerate(own) if r[2] == time)  # first occurrence
        n = len(own)
        ub, lb = min(n - 1, ind + 40), max(0, ind - 40)
        if own[ub][5] > own[ind][5] or own[ind][5] > own[lb][5]:
            lateral = 3
        elif own[ub][5] < own[ind][5] or own[ind][5] < own[lb][5]:
            lateral = 2
        else:
            lateral = 1
        ub, lb = min(n - 1, ind + 50), max(0, ind - 30)
        longitudinal = 1
        if ub != ind and lb != ind:
            with np.errstate(divide="ignore", invalid="ignore"):
                v_hist = F(own[ind][4] - own[lb][4]) / F(ind - lb)
                v_fut = F(own[ub][4] - own[ind][4]) / F(ub - ind)
                if float(F(v_fut / v_hist)) < 0.8:
                    longitudinal = 2
        grid = [F(0)] * 39
        for base, wanted in ((1, lane - 1), (14, lane), (27, lane + 1)):
            for other in rows:
                if other[2] != time or other[5] != wanted:
                    continue
                dy = F(other[4] - y)
                if abs(dy) < 90 and (base != 14 or dy != 0):
                    cell = base + _round(F(F(dy + F(90)) / F(15)))
                    grid[cell - 1] = other[1]  # later rows overwrite
        out.append([*row, F(lateral), F(longitudinal), *grid])
    return np.array(out, dtype=np.float32).reshape(len(out), 47)


def reference_kept(table: np.ndarray) -> list[bool]:
    """The edge filter, row by row; rows of vehicles under 31 rows are not kept."""
    kept = []
    for vehicle, time, *_ in table:
        frames = [r[1] for r in table if r[0] == vehicle]
        kept.append(len(frames) >= 31 and frames[30] <= time and frames[-1] > F(time) + 1)
    return kept


def reference_split(vehicle: float, largest: float) -> str:
    """The script's split of a vehicle id, by its recording's largest id: float32 products,
    MATLAB's round."""
    ul1, ul2 = _round(F(F(0.7) * F(largest))), _round(F(F(0.8) * F(largest)))
    return "train" if vehicle <= ul1 else "val" if vehicle <= ul2 else "test"


def reference_files(tables: dict[int, np.ndarray]) -> dict[str, tuple[np.ndarray, dict]]:
    """The script's split, tracks and edge filter over the datasets' (n, 5) tables in row order:
    per split (train, val, test), `traj` (N, 47) float32 and `tracks` as {(dataset, vehicle):
    (3, n) float32}. A vehicle under 31 rows (where the script stops) has no row in `traj`."""
    all_rows = np.concatenate([reference_traj(k, tables[k]) for k in sorted(tables)])
    parts: dict[str, list[np.ndarray]] = {"train": [], "val": [], "test": []}
    for k in sorted(tables):
        mine = all_rows[all_rows[:, 0] == k]
        largest = F(mine[:, 1].max())
        split = np.array([reference_split(v, largest) for v in mine[:, 1]])
        for name in parts:
            parts[name].append(mine[split == name])
    out = {}
    for name, pieces in parts.items():
        traj = np.concatenate(pieces)
        tracks = {}
        for k, vehicle in sorted({(int(r[0]), int(r[1])) for r in traj}):
            own = traj[(traj[:, 0] == k) & (traj[:, 1] == vehicle)]
            tracks[(k, vehicle)] = own[:, 2:5].T.copy()
        keep = []
        for row in traj:
            track = tracks[(int(row[0]), int(row[1]))]
            t = row[2]
            keep.append(track.shape[1] >= 31 and track[0, 30] <= t and track[0, -1] > t + 1)
        out[name] = (traj[np.array(keep, dtype=bool)], tracks)
    return out
