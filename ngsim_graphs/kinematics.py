"""Heading from lightly smoothed positions, with a hold at low speed (SPEC section 2)."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s


def add_heading(frame: pl.DataFrame, window_steps: int, min_speed_mps: float) -> pl.DataFrame:
    """Add HEADING_RAD: direction of travel from +y towards +x, `atan2(dx, dy)`.

    `frame` holds grid rows sorted by track and frame, with TRACK_ID, X_M, Y_M and SPEED_MPS.
    Positions are smoothed by a centred moving average of `window_steps` steps (shorter at the
    track's ends) before differencing; the heading at step k is that of the move from k-1 to k.
    Where the speed is below `min_speed_mps` the last heading is held; a track's first step
    takes the heading of its next one; a track that never moves fast enough heads along +y (0).
    The recorded positions themselves are left as they are.
    """
    track = s.TRACK_ID
    smooth = lambda column: pl.col(column).rolling_mean(  # noqa: E731
        window_steps, center=True, min_samples=1
    )
    smoothed = frame.with_columns(smooth(s.X_M).over(track).alias("__sx"),
                                  smooth(s.Y_M).over(track).alias("__sy"))
    dx = pl.col("__sx") - pl.col("__sx").shift(1).over(track)
    dy = pl.col("__sy") - pl.col("__sy").shift(1).over(track)
    moving = pl.col(s.SPEED_MPS) >= min_speed_mps
    raw = pl.when(moving).then(pl.arctan2(dx, dy))
    heading = raw.forward_fill().over(track).backward_fill().over(track).fill_null(0.0)
    return smoothed.with_columns(heading.alias(s.HEADING_RAD)).drop("__sx", "__sy")
