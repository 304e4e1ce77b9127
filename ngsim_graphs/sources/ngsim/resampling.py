"""Downsampling 10 Hz rows to the 0.2 s grid, by frame number and never by row position."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s


def downsample_to_grid(frame: pl.DataFrame, frames_per_step: int) -> pl.DataFrame:
    """Keep the rows on the recording's frame grid: frame_id divisible by `frames_per_step`.

    The grid is the recording's, not the track's: every vehicle is sampled at the same instants,
    so neighbours at one grid step are seen at the same time.
    """
    return frame.filter(pl.col(s.FRAME_ID) % frames_per_step == 0)
