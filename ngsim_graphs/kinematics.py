"""Heading from lightly smoothed positions, with a hold at low speed (docs/conventions.md)."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s


def _centred_mean(column: str, window_steps: int) -> pl.Expr:
    """Centred moving average per track whose window shrinks symmetrically near the ends.

    At step i of an n-step track the radius is min(h, i, n-1-i), h = window_steps // 2, so the
    window stays centred on i: steady motion is kept exactly, and the first and last positions
    are the recorded ones (a one-sided shrink would pull the ends together and flatten them).
    """
    half = window_steps // 2
    position = pl.int_range(pl.len()).over(s.TRACK_ID)
    radius = pl.min_horizontal(pl.lit(half), position, pl.len().over(s.TRACK_ID) - 1 - position)
    smoothed = pl.col(column)
    for r in range(1, half + 1):
        mean = pl.col(column).rolling_mean(2 * r + 1, center=True).over(s.TRACK_ID)
        smoothed = pl.when(radius == r).then(mean).otherwise(smoothed)
    return smoothed


def add_heading(frame: pl.DataFrame, window_steps: int, min_speed_mps: float) -> pl.DataFrame:
    """Add HEADING_RAD: direction of travel from +y towards +x, `atan2(dx, dy)`.

    `frame` holds grid rows sorted by track and frame, with TRACK_ID, X_M, Y_M and SPEED_MPS.
    Positions are smoothed by a centred moving average of `window_steps` steps before
    differencing; the heading at step k is that of the move from k-1 to k. Where the speed is
    below `min_speed_mps` the last heading is held; a track's first step takes the heading of
    its next one; a track that never moves fast enough heads along +y (0). The recorded
    positions themselves are left as they are.
    """
    track = s.TRACK_ID
    smoothed = frame.with_columns(
        _centred_mean(s.X_M, window_steps).alias("__sx"),
        _centred_mean(s.Y_M, window_steps).alias("__sy"),
    )
    dx = pl.col("__sx") - pl.col("__sx").shift(1).over(track)
    dy = pl.col("__sy") - pl.col("__sy").shift(1).over(track)
    moving = pl.col(s.SPEED_MPS) >= min_speed_mps
    raw = pl.when(moving).then(pl.arctan2(dx, dy))
    heading = raw.forward_fill().over(track).backward_fill().over(track).fill_null(0.0)
    return smoothed.with_columns(heading.alias(s.HEADING_RAD)).drop("__sx", "__sy")
