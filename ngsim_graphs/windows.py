"""Ego windows: the samples of a build, as (ego track, start step) with the ego's present position.

The aigem protocol cuts K_H + K_F consecutive grid steps of each track at a fixed stride
(`ego_windows`); the cs-lstm protocol takes CS-LSTM's kept rows on the grid (`script_windows`).
"""

from __future__ import annotations

from dataclasses import astuple, dataclass

import numpy as np
import polars as pl

from ngsim_graphs import cslstm
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig

# The raw columns CS-LSTM's script reads (script_rows).
SCRIPT_COLUMNS = (s.VEHICLE_ID, s.FRAME_ID, s.LOCAL_X, s.LOCAL_Y, s.LANE_ID)


def ego_windows(nodes: pl.DataFrame | pl.LazyFrame, config: BuildConfig) -> pl.DataFrame:
    """Every window of every track of one recording's grid nodes (GRID_NODE_SCHEMA, in any
    order; a lazy table is streamed, never held whole).

    A track of n steps starting at step f yields windows starting at f, f + stride, ... while the
    whole window (window_steps steps) lies inside the track. Tracks are contiguous on the grid, so
    the ego is present at every step of each window. Returns one row per window: ego track,
    ego vehicle, start step, present step and the ego's present position (the sample's origin),
    sorted by (ego track, start step).
    """
    nodes = nodes.lazy()
    per_track = nodes.group_by(s.TRACK_ID).agg(
        pl.col(s.VEHICLE_ID).first(),
        pl.col(s.STEP).min().alias("first"),
        pl.len().cast(pl.Int64).alias("n"),  # signed: short tracks give negative counts
    )
    counts = ((pl.col("n") - config.window_steps) // config.stride_steps + 1).clip(lower_bound=0)
    windows = (
        per_track.with_columns(counts.alias("count"))
        .filter(pl.col("count") > 0)
        .with_columns(pl.int_ranges(0, pl.col("count")).alias("index"))
        .explode("index")
        .select(
            pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
            pl.col(s.VEHICLE_ID).alias(s.EGO_VEHICLE_ID),
            (pl.col("first") + pl.col("index") * config.stride_steps)
            .cast(pl.Int32)
            .alias(s.START_STEP),
        )
        .with_columns((pl.col(s.START_STEP) + config.history_steps - 1).alias(s.PRESENT_STEP))
        .collect(engine="streaming")
    )
    origin = nodes.select(
        pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
        pl.col(s.STEP).alias(s.PRESENT_STEP),
        pl.col(s.X_M).alias(s.ORIGIN_X_M),
        pl.col(s.Y_M).alias(s.ORIGIN_Y_M),
    )
    # Each window's present step is one row of its track: the windows, the smaller side, are
    # hashed and every grid node looked up in them (the nodes hashed would take more memory).
    found = origin.join(windows.lazy(), on=[s.EGO_TRACK_ID, s.PRESENT_STEP], how="inner")
    found = found.collect(engine="streaming")
    if found.height != windows.height:
        raise ValueError("a window's ego track has no grid node at its present step")
    return found.select(*windows.columns, s.ORIGIN_X_M, s.ORIGIN_Y_M).sort(
        s.EGO_TRACK_ID, s.START_STEP
    )


@dataclass(frozen=True)
class ScriptRows:
    """What the cs-lstm protocol made of CS-LSTM's rows of one recording (or of a build)."""

    kept: int  # rows the script keeps (its edge filter), every split
    too_short: int  # rows of vehicles under 31 rows: the script stops on them; left out, counted
    on_grid: int  # kept rows on the grid, one per (vehicle, frame): an even Frame_ID
    unmatched: int  # of those, rows whose vehicle has no track at that step: no sample

    @property
    def samples(self) -> int:
        return self.on_grid - self.unmatched

    def plus(self, other: ScriptRows) -> ScriptRows:
        return ScriptRows(*(a + b for a, b in zip(astuple(self), astuple(other), strict=True)))


def script_rows(
    raw: pl.DataFrame, dataset_id: int, config: BuildConfig
) -> tuple[pl.DataFrame, int, int]:
    """The rows of one recording that CS-LSTM's `preprocess_data.m` keeps (docs/cslstm.md), on
    the grid: (table, kept, too_short). The table has one row per (vehicle, step) with its split
    (VEHICLE_ID, STEP, SPLIT), in the script's row order; `kept` counts every kept row, on the
    grid or not; `too_short` the rows of vehicles under 31 rows (the script stops on them).

    `raw`: the recording's rows before cleaning (RAW_SCHEMA columns, any order, duplicates and
    all). A kept row is on the grid when its Frame_ID is a multiple of `frames_per_step`; its
    step is Frame_ID / frames_per_step; the rows of one vehicle and frame make one row.
    """
    ordered = cslstm.ordered_rows(
        dataset_id, *(raw[c].cast(pl.Float64).to_numpy() for c in SCRIPT_COLUMNS)
    )
    kept, too_short = cslstm.kept_by_edge_filter(ordered)
    split = cslstm.split_codes(ordered)[kept]
    frame = ordered.frame[kept].astype(np.int64)
    on_grid = frame % config.frames_per_step == 0
    table = pl.DataFrame(
        {
            s.VEHICLE_ID: ordered.vehicle[kept][on_grid].astype(np.int32),
            s.STEP: (frame[on_grid] // config.frames_per_step).astype(np.int32),
            s.SPLIT: np.array(cslstm.SPLIT_NAMES)[split[on_grid]],
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
