"""The cleaning the sources share: the grid by frame number (never by row position), the rule
of dropped rows."""

from __future__ import annotations

import polars as pl
import pytest

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.cleaning import check_dropped, downsample_to_grid
from ngsim_graphs.sources.limits import PhysicalLimits

LIMITS = PhysicalLimits(max_frame_id=72_000)


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


def test_check_dropped_share_and_strict() -> None:
    reason = DropReason.SPEED.value
    check_dropped("f.txt", {reason: 1}, {reason: 7}, 100, LIMITS, strict=False)  # 1 %: allowed
    check_dropped("f.txt", {reason: 0}, {}, 100, LIMITS, strict=True)  # nothing dropped
    with pytest.raises(
        NgsimInputError, match=r"^f\.txt: 2 of 100 rows \(2\.0%\) are implausible.*line 7"
    ):
        check_dropped("f.txt", {reason: 2}, {reason: 7}, 100, LIMITS, strict=False)
    with pytest.raises(NgsimInputError, match=r"^f\.txt, line 7: v_Vel negative .*--strict"):
        check_dropped("f.txt", {reason: 1}, {reason: 7}, 100, LIMITS, strict=True)
