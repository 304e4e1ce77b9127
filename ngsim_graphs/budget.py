"""The sizes that bound a build task's memory, every one in one place (docs/design.md), and the
cores a build may use.

No task holds a whole input file or recording; it holds a piece of one, of these sizes, so that
its peak does not grow with the size of the recording and `--jobs` multiplies a bounded figure.
The outputs do not depend on them: tests build with tiny sizes and compare every file. Code
reads `BUDGET` from this module at call time, so that a test may replace it
(`dataclasses.replace`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Budget:
    """Rows, bytes and values held at once, by the stage that holds them."""

    # Reading: a file's text is parsed this many bytes at a time, cut at line ends (Polars' CSV
    # reader then holds about 0.2 GB whatever the file's size, 0.3 GB and more for a whole
    # 300 MB file; a chunk per piece held at once, `pieces_at_once`), and its rows staged this
    # many at a time for each recording it holds, by part.
    text_chunk_bytes: int = 16 * 1024 * 1024
    batch_rows: int = 65_536
    # A recording's vehicles are staged and cleaned in parts: those whose Vehicle_ID // this is
    # the same (NGSIM: 50,000 to 120,000 rows a part).
    vehicles_per_part: int = 128
    # Cleaning: whole vehicles of a part, about this many raw rows at a time; a median of the
    # speed check among at most this many values held at once, narrowed down a histogram of
    # this many bins at a time (`sources.speeds.streamed_median`).
    clean_rows: int = 262_144
    median_held_values: int = 4_194_304  # 32 MB: the evidence of 15 minutes of NGSIM, whole
    median_bins: int = 1_024
    # Building: the grid rows are made this many at a time (each range reads the tracks table's
    # row groups of its times), and the proximity pairs found, written and used a range of steps
    # of about this many grid rows at a time (ten pairs a row in dense traffic; `pieces_at_once`
    # ranges at once).
    grid_rows: int = 262_144
    piece_rows: int = 32_768
    # The neighbourhoods: ego rows looked at together (their pair candidates stay ~25 MB), and
    # samples summed up together (cs-lstm: a million in a recording).
    ego_rows_per_chunk: int = 1_024
    samples_per_chunk: int = 65_536
    # A task's pieces (text chunks, groups of vehicles, ranges of steps, or a range's chunks of
    # ego rows) held at once, one a thread (`threads.in_order`; a piece's own pieces then run
    # on its thread): at most this many, however many cores a process may use.
    pieces_at_once: int = 4
    # CS-LSTM's grid: rows whose neighbours are found at once (about 200 MB of pairs).
    cslstm_grid_rows: int = 200_000


BUDGET = Budget()


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
