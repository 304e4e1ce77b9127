"""The rule that tells a file cut at a line end from a subset, on vehicle records made by hand."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim.truncation import cut_record_note

NAMES = [("us-101", "0750am-0805am")]


def records(spans: list[tuple[int, int, int | None]], named: int = 0) -> pl.DataFrame:
    """Vehicles 1, 2, ... in file order, each (first frame, last frame, Total_Frames), 100 rows
    each (vehicle v's last at ROW 100 v - 1); every one names vehicle `named`."""
    n = len(spans)
    return pl.DataFrame(
        {
            s.RECORDING_INDEX: [0] * n,
            s.VEHICLE_ID: list(range(1, n + 1)),
            "first": [span[0] for span in spans],
            "last": [span[1] for span in spans],
            "total": [span[2] for span in spans],
            "last_row": [100 * v - 1 for v in range(1, n + 1)],
            "named": [named] * n,
        },
        schema_overrides={s.RECORDING_INDEX: pl.UInt16, "total": pl.Int32},
    )


def test_the_last_vehicle_short_of_its_total_frames_with_a_few_others() -> None:
    # 200 whole vehicles of frames 0..99, then one with frames 0..9 of 100: a cut.
    cut = (0, 9, 100)
    note = cut_record_note(records([(0, 99, 100)] * 200 + [cut]), NAMES, first_line=1)
    assert note is not None and note.startswith(
        "its last vehicle, 201 of us-101/0750am-0805am (line 20100), spans frames 0 to 9: 10 "
        "frames where its Total_Frames says 100, while the other 200 vehicles span all of theirs"
    )
    # 2 of the 200 short too (1 %, the odd vehicle of a real file): still a cut; 3: a subset.
    two = [(0, 50, 100)] * 2 + [(0, 99, 100)] * 198 + [cut]
    assert "while 198 of the other 200 vehicles span" in cut_record_note(records(two), NAMES, 1)
    three = [(0, 50, 100)] * 3 + [(0, 99, 100)] * 197 + [cut]
    assert cut_record_note(records(three), NAMES, 1) is None


def test_what_is_no_cut() -> None:
    whole = [(0, 99, 100)] * 5
    assert cut_record_note(records(whole), NAMES, 1) is None
    assert cut_record_note(records(whole, named=5), NAMES, 1) is None  # names the last: whole
    assert (
        cut_record_note(records([(0, 9, 100)]), NAMES, 1) is None
    )  # one vehicle: nothing to judge
    assert cut_record_note(records([*whole, (0, 9, None)]), NAMES, 1) is None  # no Total_Frames
    # A gap inside: NGSIM's Total_Frames counts its frames too; the span is whole.
    assert cut_record_note(records([*whole, (10, 109, 100)]), NAMES, 1) is None
