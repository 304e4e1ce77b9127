"""Whether an NGSIM file was cut at a line end (a partial copy or download), told from the
records of its vehicles.

NGSIM writes its files sorted by vehicle, then frame (the .txt, the per-period CSV; the portal's
CSV one recording after another), and each row carries its vehicle's Total_Frames, the frames of
its whole record, and the vehicles beside it (Preceding, Following). A copy cut at a line end
keeps the vehicles before the cut whole, the first frames of the vehicle at the cut, and none of
the vehicles after it: its last vehicle in file order ends short of its Total_Frames while the
others have all of theirs; or, cut between two vehicles, the last is whole but the others name
vehicles numbered above any in the file. A subset made by a query of the portal (a time window,
a stretch of road) cuts the record of every vehicle at its edges, many of them: it is not taken
for a cut. Nor can a cut be seen in a file whose rows are in another order (by Global_Y, say),
which leaves many vehicles short, as a query does.
"""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.contract import RecordingKey
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.text import ROW

# Of the vehicles before the last, the share whose record may end short of Total_Frames in a
# whole file (the odd vehicle of a real one): more say the file is a subset, not a cut copy.
MAX_SHORT_SHARE = 0.01

_FIRST, _LAST, _TOTAL, _LAST_ROW = "first", "last", "total", "last_row"
_NAMED, _SHORT = "named", "short"  # the largest Preceding or Following; spans under Total_Frames


def vehicle_records(frame: pl.LazyFrame, recording: pl.Expr) -> pl.DataFrame:
    """Each vehicle's record in each chosen recording of a file's parsed rows (RAW_SCHEMA, ROW):
    RECORDING_INDEX, VEHICLE_ID, its first and last Frame_ID, its Total_Frames (the largest
    written; frames), its last ROW and the largest vehicle id it names as Preceding or
    Following. `recording` is each row's recording index (UInt16, null for rows of no chosen
    recording, which are left out). One streaming pass."""
    named = pl.max_horizontal(s.PRECEDING, s.FOLLOWING)
    return (
        frame.select(
            recording.alias(s.RECORDING_INDEX),
            s.VEHICLE_ID,
            s.FRAME_ID,
            ns.TOTAL_FRAMES,
            ROW,
            named.alias(_NAMED),
        )
        .drop_nulls([s.RECORDING_INDEX, s.VEHICLE_ID, s.FRAME_ID])
        .group_by(s.RECORDING_INDEX, s.VEHICLE_ID)
        .agg(
            pl.col(s.FRAME_ID).min().alias(_FIRST),
            pl.col(s.FRAME_ID).max().alias(_LAST),
            pl.col(ns.TOTAL_FRAMES).max().alias(_TOTAL),
            pl.col(ROW).max().alias(_LAST_ROW),
            pl.col(_NAMED).max(),
        )
        .collect(engine="streaming")
    )


def cut_record_note(
    records: pl.DataFrame, names: list[RecordingKey], first_line: int
) -> str | None:
    """A line for a file that looks cut at a line end; None otherwise.

    `records` are `vehicle_records`; the last vehicle is the one with the file's last row. The
    others (at least one with its Total_Frames) must be whole: at most MAX_SHORT_SHARE of them
    span fewer frames, first to last, than their Total_Frames. A span, not a count of rows: a
    record with a gap inside (NGSIM's Total_Frames counts the frames lost) is whole. Then the
    file looks cut when the last vehicle is short of its Total_Frames, or when it is whole, the
    highest-numbered of its recording, and a vehicle of the recording names a higher one as
    Preceding or Following. `names` are the recordings' (location, period) by index; ROW +
    `first_line` is a row's line.
    """
    span = pl.col(_LAST) - pl.col(_FIRST) + 1
    spans = records.sort(_LAST_ROW).with_columns((span < pl.col(_TOTAL)).alias(_SHORT))
    others = spans.head(-1).drop_nulls(_TOTAL)
    short = int(others[_SHORT].sum())
    if others.height == 0 or short > MAX_SHORT_SHARE * others.height:
        return None
    last = spans.row(-1, named=True)
    n = others.height
    whole = f"the other {n:,}" if short == 0 else f"{n - short:,} of the other {n:,}"
    location, period = names[last[s.RECORDING_INDEX]]
    vehicle = f"its last vehicle, {last[s.VEHICLE_ID]} of {location}/{period} (line "
    vehicle += f"{last[_LAST_ROW] + first_line})"
    question = "is the file cut short (a partial copy or download)? Any vehicle after it is "
    question += "missing from the build"
    if last[_SHORT]:
        frames = last[_LAST] - last[_FIRST] + 1
        return (
            f"{vehicle}, spans frames {last[_FIRST]} to {last[_LAST]}: {frames:,} "
            f"frame{'s' if frames > 1 else ''} where its Total_Frames says {last[_TOTAL]:,}, "
            f"while {whole} vehicles span all of theirs: {question}"
        )
    beyond = _named_beyond(spans, last)
    if beyond is None:
        return None
    return (
        f"{vehicle}, is whole, but the rows of its recording name vehicles up to {beyond} as "
        f"Preceding or Following, and none above {last[s.VEHICLE_ID]} is in the file: {question}"
    )


def _named_beyond(spans: pl.DataFrame, last: dict) -> int | None:
    """The largest vehicle id named as Preceding or Following in the last vehicle's recording,
    where that is above the last vehicle's id and the last vehicle is the recording's
    highest-numbered (as in a file sorted by vehicle); None otherwise."""
    recording = spans.filter(pl.col(s.RECORDING_INDEX) == last[s.RECORDING_INDEX])
    named = recording[_NAMED].max()
    top = recording[s.VEHICLE_ID].max()
    if named is None or top != last[s.VEHICLE_ID] or named <= top:
        return None
    return int(named)
