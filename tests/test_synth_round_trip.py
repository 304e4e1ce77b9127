"""`synth` round trip: every format, with and without quirks, reads back to the same tracks.

The reference is the tracks table built straight from the simulated rows (no file in between).
"""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from polars.testing import assert_frame_equal

from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.layout import tracks_path
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS
from ngsim_graphs.sources.ngsim.tracks import build_tracks
from ngsim_graphs.synth.formats import simulated_rows, write_synthetic

MINUTES = 0.5
RECORDINGS = 2  # us-101 0750am and i-80 0400: both locations


def expected_tracks(quirks: bool) -> dict[tuple[str, str], pl.DataFrame]:
    config = SynthConfig(recordings=RECORDINGS, minutes=MINUTES, seed=5, quirks=quirks)
    tracks, first_id = {}, 0
    chosen = enumerate(OFFICIAL_RECORDINGS[:RECORDINGS])
    for index, recording in sorted(chosen, key=lambda p: (p[1].location, p[1].period)):
        key = (recording.location, recording.period)
        table, report = build_tracks(
            simulated_rows(recording, index, config), key, BuildConfig(), first_id
        )
        tracks[key], first_id = table, first_id + report.tracks
    return tracks


@pytest.fixture(scope="module")
def references() -> dict[bool, dict[tuple[str, str], pl.DataFrame]]:
    return {quirks: expected_tracks(quirks) for quirks in (False, True)}


# The portal's CSV with the quirks of real exports by default; every other format and quirk
# setting is slow (each format's reader and each quirk have fast tests of their own).
@pytest.mark.parametrize(
    ("raw_format", "quirks"),
    [
        pytest.param(
            f,
            q,
            id=f"{f.value}-{q}",
            marks=() if (f, q) == (RawFormat.PORTAL, True) else pytest.mark.slow,
        )
        for f in RawFormat
        if f is not RawFormat.HIGHD  # see test_synth_highd
        for q in (False, True)
    ],
)
def test_every_format_reads_back_to_the_simulated_tracks(
    tmp_path: Path, raw_format: RawFormat, quirks: bool, references: dict
) -> None:
    config = SynthConfig(
        raw_format=raw_format, recordings=RECORDINGS, minutes=MINUTES, seed=5, quirks=quirks
    )
    write_synthetic(tmp_path / "raw", config)
    result = run_build([tmp_path / "raw"], tmp_path / "out", BuildConfig())
    expected = references[quirks]
    assert [(r.location, r.period) for r in result.recordings] == sorted(expected)
    for (location, period), table in expected.items():
        assert_frame_equal(pl.read_parquet(tracks_path(tmp_path / "out", location, period)), table)
    counts = result.manifest.to_dict()["counts"]
    if quirks and raw_format is RawFormat.PORTAL:
        assert counts["exact_duplicates"] > 0 and counts["conflicting_duplicates"] > 0
        assert counts["rows_missing_values"] > 0 and counts["rows_other_locations"] > 0
    else:
        assert counts["exact_duplicates"] == counts["conflicting_duplicates"] == 0
    assert (counts["gaps"] > 0) == quirks
