"""The six official NGSIM recordings and how a recording is recognised from its timestamps.

A recording's key is (location, period). Inside one recording `Global_Time - 100 * Frame_ID` is
constant: it is the epoch time of frame 0. That time names the period: the official period whose
nominal start is nearest, within a tolerance; otherwise a label made of the local clock times.
NGSIM's US-101 and I-80 data were both recorded under Pacific Daylight Time (UTC-7).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError

PACIFIC_DAYLIGHT = timezone(timedelta(hours=-7), "PDT")
MATCH_TOLERANCE_MS = 10 * 60 * 1000
KNOWN_LOCATION_NAMES: tuple[str, ...] = ("us-101", "i-80", "lankershim", "peachtree")
FRAME0_MS = "frame0_epoch_ms"  # Global_Time - 100 * Frame_ID: constant within a recording
RECORDING_INDEX = "recording_index"


@dataclass(frozen=True)
class Recording:
    """One official recording: location, period label as in the file names, nominal start."""

    location: str
    period: str
    start_epoch_ms: int


def _pdt_ms(year: int, month: int, day: int, hour: int, minute: int) -> int:
    moment = datetime(year, month, day, hour, minute, tzinfo=PACIFIC_DAYLIGHT)
    return int(moment.timestamp() * 1000)


# In the order synth takes them: alternating locations so that two recordings cover both.
OFFICIAL_RECORDINGS: tuple[Recording, ...] = (
    Recording("us-101", "0750am-0805am", _pdt_ms(2005, 6, 15, 7, 50)),
    Recording("i-80", "0400-0415", _pdt_ms(2005, 4, 13, 16, 0)),
    Recording("us-101", "0805am-0820am", _pdt_ms(2005, 6, 15, 8, 5)),
    Recording("i-80", "0500-0515", _pdt_ms(2005, 4, 13, 17, 0)),
    Recording("us-101", "0820am-0835am", _pdt_ms(2005, 6, 15, 8, 20)),
    Recording("i-80", "0515-0530", _pdt_ms(2005, 4, 13, 17, 15)),
)


def find_official_recording(frame0_epoch_ms: int, location: str | None = None) -> Recording | None:
    """The official recording whose nominal start is nearest to frame 0's time, if within 10 min.

    With `location`, only that location's recordings are candidates.
    """
    candidates = [r for r in OFFICIAL_RECORDINGS if location is None or r.location == location]
    best = min(candidates, key=lambda r: abs(r.start_epoch_ms - frame0_epoch_ms), default=None)
    if best is None or abs(best.start_epoch_ms - frame0_epoch_ms) > MATCH_TOLERANCE_MS:
        return None
    return best


def period_label(frame0_epoch_ms: int, last_frame_id: int) -> str:
    """A period label for an unofficial recording: local start and end clock times, 'HHMM-HHMM'."""
    start = datetime.fromtimestamp(frame0_epoch_ms / 1000, PACIFIC_DAYLIGHT)
    end = start + timedelta(milliseconds=100 * last_frame_id)
    return f"{start:%H%M}-{end:%H%M}"


def location_from_path(path: Path) -> str | None:
    """A known location named by a folder or the file name (`US-101/...`, `i80_...`), if any."""
    squeezed = {name.replace("-", ""): name for name in KNOWN_LOCATION_NAMES}
    for part in reversed(path.parts):
        token = part.lower().replace("-", "").replace("_", "")
        for key, name in squeezed.items():
            if key in token:
                return name
    return None


def _name_recording(frame0_ms: int, last_frame: int, location: str | None, path: Path) -> tuple[str, str]:
    official = find_official_recording(frame0_ms, location)
    if official is not None:
        return official.location, official.period
    named = location or location_from_path(path)
    if named is None:
        start = datetime.fromtimestamp(frame0_ms / 1000, PACIFIC_DAYLIGHT)
        raise NgsimInputError(
            path,
            f"cannot tell the location: frame 0 at {start:%Y-%m-%d %H:%M} PDT is none of the "
            "official NGSIM periods; put the file in a folder named after its location "
            f"({', '.join(KNOWN_LOCATION_NAMES)})",
        )
    return named, period_label(frame0_ms, last_frame)


def identify_recordings(frame: pl.DataFrame, path: Path) -> tuple[pl.Series, list[tuple[str, str]]]:
    """Which recording each raw row belongs to: (index per row, (location, period) per index).

    `frame` needs global_time, frame_id and location (null where the file does not say, as in
    per-period files). Rows of one file that differ in `Global_Time - 100 * Frame_ID` belong to
    different recordings (the combined CSV holds three periods per location). Rows without a
    time or frame belong to none: their index is null.
    """
    frame0 = pl.col(s.GLOBAL_TIME) - 100 * pl.col(s.FRAME_ID).cast(pl.Int64)
    keyed = frame.select(s.LOCATION, frame0.alias(FRAME0_MS), s.FRAME_ID)
    groups = (
        keyed.drop_nulls(FRAME0_MS)
        .group_by(s.LOCATION, FRAME0_MS)
        .agg(pl.col(s.FRAME_ID).max().alias("last_frame"))
        .sort(s.LOCATION, FRAME0_MS, nulls_last=True)
        .with_row_index(RECORDING_INDEX)
    )
    names = [
        _name_recording(frame0_ms, last_frame, location, path)
        for _, location, frame0_ms, last_frame in groups.iter_rows()
    ]
    index = keyed.join(groups, on=[s.LOCATION, FRAME0_MS], how="left", nulls_equal=True, maintain_order="left")
    return index[RECORDING_INDEX].cast(pl.UInt16), names
