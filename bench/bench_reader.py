"""Benchmark: NGSIM's whitespace text parsed a core at a time, beside Polars' own CSV reader.

Times, on one core (Polars' threads set to 1 before it is imported), the parsing of one text
file, 16 MB of whole lines at a time as a build reads it:
- Polars' CSV reader on the same bytes, reading each line whole into one text column: what
  Polars' own reader does on this text, the ceiling of any reader built on it;
- the fast path (`sources/ngsim/whitespace.py`): numpy makes the fields single-spaced, Polars'
  CSV reader parses them into the raw dtypes;
- the general reader (each line split on runs of whitespace by a regex, each field tidied and
  cast), which every chunk took before and which any chunk that is not plain text still takes.
Prints MB of text per second per core for each (the median of `--repeats`). Synthetic data.

    python bench/bench_reader.py bench/out/raw-txt-r6-m15/us-101/trajectories-0820am-0835am.txt
"""

from __future__ import annotations

import os

os.environ["POLARS_MAX_THREADS"] = "1"  # before Polars is imported: one core

import argparse  # noqa: E402
import io  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import polars as pl  # noqa: E402

from ngsim_graphs import budget  # noqa: E402
from ngsim_graphs import schema as s  # noqa: E402
from ngsim_graphs.sources.ngsim import files, whitespace  # noqa: E402
from ngsim_graphs.sources.ngsim import schema as ns  # noqa: E402


def general(chunk: files.TextChunk) -> pl.DataFrame:
    """The general reader's rows of one chunk (`files.read_raw_file`'s parse of a .txt)."""
    tidied, parsed, present, pointed = files._number_exprs(ns.TXT_COLUMNS)
    text = files._scan_txt_text(Path("x"), chunk).with_columns(
        pl.lit(None, dtype=pl.String).alias(s.LOCATION)
    )
    rows = text.with_columns(tidied).select(files.ROW, *parsed, s.LOCATION, present, pointed)
    return rows.collect()


def lines_whole(chunk: files.TextChunk) -> pl.DataFrame:
    """Polars' CSV reader on the chunk, each line one text field."""
    return pl.read_csv(
        chunk.text.getvalue(),
        has_header=False,
        separator="\x1f",
        quote_char=None,
        schema={"line": pl.String},
    )


def fast(chunk: files.TextChunk) -> pl.DataFrame | None:
    return whitespace.parse_plain(chunk.text.getvalue(), chunk.first_line, chunk.line_ends)


def seconds(parse: Callable[[files.TextChunk], object], chunks: list[files.TextChunk]) -> float:
    start = time.perf_counter()
    for chunk in chunks:
        chunk.text.seek(0)
        parse(files.TextChunk(io.BytesIO(chunk.text.getvalue()), chunk.first_line, chunk.line_ends))
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("path", type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    chunks = list(files.text_chunks(args.path, budget.BUDGET.text_chunk_bytes))
    assert all(fast(chunk) is not None for chunk in chunks), "not plain text: no fast path"
    size_mb = args.path.stat().st_size / 1e6
    print(
        f"{args.path}: {size_mb:.0f} MB, {len(chunks)} chunks, one core (load {os.getloadavg()[0]:.1f})"
    )
    for name, parse in (
        ("Polars' CSV reader, lines whole", lines_whole),
        ("fast path (single-spaced, CSV reader)", fast),
        ("general reader (regex split, tidy, cast)", general),
    ):
        times = [seconds(parse, chunks) for _ in range(args.repeats)]
        median = statistics.median(times)
        print(f"  {name:<42} {median:6.2f} s  {size_mb / median:6.0f} MB/s per core")


if __name__ == "__main__":
    main()
