"""Ego windows: K_H + K_F consecutive grid steps of one track, cut at a fixed stride."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig


def ego_windows(nodes: pl.DataFrame, config: BuildConfig) -> pl.DataFrame:
    """Every window of every track of one recording's grid nodes (GRID_NODE_SCHEMA).

    A track of n steps starting at step f yields windows starting at f, f + stride, ... while the
    whole window (window_steps steps) lies inside the track. Tracks are contiguous on the grid, so
    the ego is present at every step of each window. Returns one row per window: ego track,
    ego vehicle, start step, present step and the ego's present position (the sample's origin),
    sorted by (ego track, start step).
    """
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
    )
    origin = nodes.select(
        pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
        pl.col(s.STEP).alias(s.PRESENT_STEP),
        pl.col(s.X_M).alias(s.ORIGIN_X_M),
        pl.col(s.Y_M).alias(s.ORIGIN_Y_M),
    )
    return windows.join(origin, on=[s.EGO_TRACK_ID, s.PRESENT_STEP], how="left").sort(
        s.EGO_TRACK_ID, s.START_STEP
    )
