"""The 0.2 s grid is chosen by frame number on the recording's grid, never by row position."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim.resampling import downsample_to_grid


def test_grid_keeps_even_frames_whatever_the_row_order() -> None:
    # Vehicle 1 starts on an odd frame; vehicle 2's rows are shuffled and it has a gap.
    frame = pl.DataFrame(
        {s.VEHICLE_ID: [1, 1, 1, 1, 2, 2, 2, 2], s.FRAME_ID: [3, 4, 5, 6, 12, 8, 9, 13]}
    )
    kept = downsample_to_grid(frame, frames_per_step=2)
    assert kept.rows() == [(1, 4), (1, 6), (2, 12), (2, 8)]


def test_coarser_grid() -> None:
    frame = pl.DataFrame({s.VEHICLE_ID: [1] * 7, s.FRAME_ID: list(range(7))})
    assert downsample_to_grid(frame, frames_per_step=3)[s.FRAME_ID].to_list() == [0, 3, 6]
