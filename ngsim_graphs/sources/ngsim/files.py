"""Reading raw NGSIM files of all three formats into one parsed raw table per file.

The format is told from the content (`formats.sniff_format`: the first lines), never from the
file name. Every value is read as text first and parsed here, so that thousands separators
(`"1,156"`, and no other comma) parse and a malformed number is reported with its file, line
and column (`faults`). Units stay NGSIM's (feet, ms).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ngsim_graphs import budget
from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.faults import (
    N_FIELDS,
    ODD,
    POINTED,
    PRESENT,
    raise_bad_number,
    raise_odd_shape,
)
from ngsim_graphs.sources.ngsim.formats import (
    check_csv_columns,
    check_not_cut,
    first_line,
    header_names,
    sniff_format,
)
from ngsim_graphs.sources.ngsim.whitespace import parse_plain
from ngsim_graphs.sources.text import (
    CONTROL,
    EXTRA,
    LINE,
    ROW,
    check_line_length,
    check_line_lengths,
    raise_bad_quoting,
    scan_csv_fields,
    scan_lines,
    without_thousands,
)
from ngsim_graphs.threads import in_order

# Where a build gives it a scratch folder, the parsed rows of a file are written there, a chunk
# of its text a file, and read back as they are needed, never held whole.
PARSED_STEM = "parsed"
# Arrow IPC, uncompressed: written at memory speed, read by each pass at memory speed; it lives
# only while its file is read (the disk holds about its text's size, the page cache the rest).
PARSED_SUFFIX = "arrow"


@dataclass(frozen=True)
class RawFile:
    """A parsed raw file: its rows (RAW_SCHEMA + location, + ROW; lazily, from memory or from
    a scratch file) and what reading it counted."""

    path: Path
    raw_format: RawFormat
    size_bytes: int
    rows_read: int  # data rows in the file, blank lines excluded
    first_line: int  # the line number of data row 0: ROW + first_line is a row's line
    rows_other_locations: int  # rows of locations the build did not choose (portal CSV only)
    locations_found: tuple[str, ...]  # every location the file holds
    frame: pl.LazyFrame


def _scan_csv_text(path: Path, chunk: TextChunk | None = None) -> tuple[pl.LazyFrame, list[str]]:
    """CSV as text columns named by the lower-cased header, plus EXTRA for surplus fields (of
    the whole file, or of one chunk of it).

    Returns (frame with ROW and ODD, header as spelled). Polars drops a row's surplus fields
    silently; the one spare column keeps the first of them, so that such rows can be found.
    """
    header = header_names(first_line(path))
    names = [name.lower() for name in header]
    # A short row reads as empty trailing fields, which cannot be told apart here from fields
    # left empty; an empty last field marks the row as odd, and the exact check decides.
    odd = pl.col(EXTRA).is_not_null() | pl.col(names[-1]).is_null()
    if chunk is None:
        fields = scan_csv_fields(path, names)
    else:  # the header is in the first chunk only; ROW counts data rows, not the header
        skip = int(chunk.first_line == 0)
        fields = scan_csv_fields(chunk.text, names, skip, chunk.first_line - 1 + skip)
    return fields.with_columns(odd.alias(ODD)), header


def _scan_txt_text(path: Path, chunk: TextChunk | None = None) -> pl.LazyFrame:
    """Whitespace text: each line read whole and split on runs of whitespace; blank lines skipped
    (of the whole file, or of one chunk of it).

    Returns ROW, the 18 columns as text (null where a line is short) and N_FIELDS.
    """
    source, first_row = (path, 0) if chunk is None else (chunk.text, chunk.first_line)
    lines = scan_lines(source, skip_rows=0).with_row_index(ROW, offset=first_row)
    fields = pl.col(LINE).str.extract_all(r"\S+")
    split = lines.select(ROW, fields.alias(LINE), CONTROL).filter(
        (pl.col(LINE).list.len() > 0) | pl.col(CONTROL).is_not_null()
    )
    columns = [
        pl.col(LINE).list.get(i, null_on_oob=True).alias(c) for i, c in enumerate(ns.TXT_COLUMNS)
    ]
    n_fields = pl.col(LINE).list.len().alias(N_FIELDS)
    odd = (pl.col(N_FIELDS) != len(ns.TXT_COLUMNS)) | pl.col(CONTROL).is_not_null()
    return split.select(ROW, *columns, n_fields, CONTROL).with_columns(odd.alias(ODD))


def _number_exprs(
    columns: tuple[str, ...],
) -> tuple[list[pl.Expr], list[pl.Expr], pl.Expr, pl.Expr]:
    """Parse text columns to RAW_SCHEMA dtypes; also the count of non-empty fields per row, and
    whether an integer field of the row is written with a point or an exponent.

    Returns (tidied, parsed, present, pointed): `tidied` strips each column's blanks and thousands
    separators in place, once (`text.without_thousands`: any other comma stays, and the value
    fails to parse); the others read the tidied columns, in a later select.
    A row whose parsed non-null values are fewer than its non-empty fields holds a malformed
    number. Comparing two counts costs far less than testing every field for it. An integer
    column's value must be whole (`10.5` as a Frame_ID truncates to 10 when cast): the few rows
    written with a point ("2.0" is fine) are checked one by one afterwards (_first_fraction).
    """
    tidied: list[pl.Expr] = []
    parsed: list[pl.Expr] = []
    present: list[pl.Expr] = []
    pointed: list[pl.Expr] = []
    for column in columns:
        text = pl.col(column)
        tidied.append(without_thousands(text))
        dtype = ns.RAW_SCHEMA[column]
        parsed.append(text.cast(pl.Float64, strict=False).cast(dtype, strict=False))
        present.append((text != "").fill_null(False).cast(pl.Int8))
        if dtype != pl.Float64:
            pointed.append(text.str.contains(r"[.eE]").fill_null(False))
    counts = pl.sum_horizontal(present).cast(pl.Int8).alias(PRESENT)
    return tidied, parsed, counts, pl.any_horizontal(pointed).alias(POINTED)


def _first_fraction(text: pl.LazyFrame, rows: pl.Series) -> int | None:
    """The first of `rows` (ROW numbers, rows with a pointed integer field) whose integer field
    is not whole; re-reads those rows only."""
    integers = [c for c in ns.TXT_COLUMNS if ns.RAW_SCHEMA[c] != pl.Float64]
    fields = text.filter(pl.col(ROW).is_in(rows.implode())).select(ROW, *integers)
    real = [without_thousands(pl.col(c)).cast(pl.Float64, strict=False) for c in integers]
    fraction = pl.any_horizontal([(r != r.floor()).fill_null(False) for r in real])
    found = fields.filter(fraction).select(pl.col(ROW).min()).collect().item()
    return None if found is None else int(found)


def _bad_number() -> pl.Expr:
    """Whether a parsed row has a field that did not parse as a finite number."""
    parsed = pl.sum_horizontal(pl.col(ns.TXT_COLUMNS).is_not_null().cast(pl.Int8))
    floats = [c for c in ns.TXT_COLUMNS if ns.RAW_SCHEMA[c] == pl.Float64]
    not_finite = pl.any_horizontal(~pl.col(floats).is_finite()).fill_null(False)
    return (parsed != pl.col(PRESENT)) | not_finite


@dataclass(frozen=True)
class TextChunk:
    """Whole lines of a file's text: its lines from `first_line` (0-based, the header included),
    `line_ends` of them ended (all but a last one without its line end)."""

    text: io.BytesIO
    first_line: int
    line_ends: int


def text_chunks(path: Path, chunk_bytes: int) -> Iterator[TextChunk]:
    """The file's text in chunks of about `chunk_bytes` that end at a line end (LF; CRLF stays
    whole), in order: every line in exactly one chunk. Raises NgsimInputError for a line longer
    than `text.MAX_LINE_BYTES` as it is met: no more than a chunk and that bound is held."""
    first_line, rest = 0, b""
    with path.open("rb") as handle:
        while True:
            data = handle.read(chunk_bytes)
            text = rest + data if rest else data
            check_line_length(path, text, first_line + 1)
            end = text.rfind(b"\n") + 1 if data else len(text)
            if end == 0 and data:  # a line longer than a chunk: read on
                rest = text
                continue
            if end:
                # The next chunk reads the last line's start again: no copy of it carried over.
                handle.seek(end - len(text), io.SEEK_CUR)
                line_ends = text.count(b"\n", 0, end)
                yield TextChunk(io.BytesIO(text[:end]), first_line, line_ends)
                first_line += line_ends
            rest = b""
            if not data:
                return


def _parsed(
    path: Path,
    parse: Callable[[TextChunk | None], pl.LazyFrame],
    scratch: Path | None,
    fast: Callable[[TextChunk], pl.DataFrame | None] | None = None,
) -> pl.LazyFrame:
    """The parsed rows (`parse` of the whole file or of a chunk of it): collected (scratch
    None), or parsed a chunk at a time (`budget.Budget.text_chunk_bytes`) into `scratch` and
    scanned from there: a file's text and rows are then never all in memory at once. `fast`
    parses a chunk as `parse` does where it can (None where it cannot).

    The chunks are parsed on the process's threads (`threads.in_order`), each into its own
    file; an error is the one a single thread would meet first."""
    if scratch is None:
        check_line_lengths(path)  # the reader would hold a line whole, of any length
        return parse(None).collect(engine="streaming").lazy()
    scratch.mkdir(parents=True, exist_ok=True)

    def write(numbered: tuple[int, TextChunk]) -> Path:
        index, chunk = numbered
        part = scratch / f"{PARSED_STEM}-{index:05d}.{PARSED_SUFFIX}"
        rows = None if fast is None else fast(chunk)
        if rows is None:
            parse(chunk).sink_ipc(part, compression="uncompressed")
        else:
            rows.write_ipc(part, compression="uncompressed")
        return part

    chunks = enumerate(text_chunks(path, budget.BUDGET.text_chunk_bytes))
    parts = list(in_order(write, chunks))  # one at least: `sniff_format` let no empty file through
    return pl.scan_ipc(parts)


def _check_fields(
    path: Path,
    raw_format: RawFormat,
    text: pl.LazyFrame,
    frame: pl.LazyFrame,
    summary: pl.DataFrame,
    by_location: pl.DataFrame,
    first_line: int,
) -> None:
    """Raise for a file without data rows, a row with a wrong number of fields, or a field that
    is not a value of its column (a whole number's column with a fraction too), naming the first
    such line of the whole file (`text`); `frame` is its parsed rows, `summary` and `by_location`
    what read_raw_file counted of them."""
    if int(by_location["rows"].sum()) == 0:
        raise NgsimInputError(path, "no data rows")
    if by_location["odd"].sum():
        raise_odd_shape(path, raw_format, text)
    bad = summary["bad"][0]
    if bad is not None:
        raise_bad_number(path, text, int(bad), first_line)
    if summary["pointed"][0]:
        pointed_rows = frame.filter(POINTED).select(ROW).collect(engine="streaming")[ROW]
        fraction = _first_fraction(text, pointed_rows)
        if fraction is not None:
            raise_bad_number(path, text, fraction, first_line)


def read_raw_file(path: Path, locations: tuple[str, ...], scratch: Path | None = None) -> RawFile:
    """Read one NGSIM file of any format; keep rows of `locations` (portal CSV only).

    Returns a frame with RAW_SCHEMA's columns (NGSIM units), `location` (null where the file does
    not say) and ROW. Empty fields become null. Raises NgsimInputError for unusable input.
    With `scratch` (a folder of the build's staging area), the rows are written there and the
    frame scans them, so that reading holds a part of them at a time.
    """
    raw_format = sniff_format(path)
    check_not_cut(path, raw_format)
    fast = None
    if raw_format is RawFormat.TXT:
        scan, first_line = (lambda chunk: _scan_txt_text(path, chunk)), 1
        fast = lambda c: parse_plain(c.text.getvalue(), c.first_line, c.line_ends)  # noqa: E731
    else:
        header = _scan_csv_text(path)[1]
        check_csv_columns(path, header, raw_format)
        scan, first_line = (lambda chunk: _scan_csv_text(path, chunk)[0]), 2
    is_portal = raw_format is RawFormat.PORTAL
    location = (
        pl.col(s.LOCATION).str.strip_chars().str.to_lowercase()
        if is_portal
        else pl.lit(None, dtype=pl.String)
    )
    tidied, parsed, present, pointed = _number_exprs(ns.TXT_COLUMNS)

    def parse(chunk: TextChunk | None) -> pl.LazyFrame:
        text = scan(chunk).with_columns(location.alias(s.LOCATION))
        kept = text.filter(pl.col(s.LOCATION).is_in(locations)) if is_portal else text
        return kept.with_columns(tidied).select(ROW, *parsed, s.LOCATION, present, pointed, ODD)

    text = scan(None).with_columns(location.alias(s.LOCATION))  # the whole file: for faults
    try:
        frame = _parsed(path, parse, scratch, fast)
        summary = frame.select(
            pl.len().alias("rows"),
            pl.col(ODD).sum().alias("odd"),
            pl.col(ROW).filter(_bad_number()).min().alias("bad"),
            pl.col(POINTED).any().alias("pointed"),
        ).collect(engine="streaming")
        # Rows of other locations are counted on their own; one collect_all sharing the scan
        # would hold all of its text in memory.
        by_location = (
            text.group_by(s.LOCATION)
            .agg(pl.len().alias("rows"), pl.col(ODD).sum().alias("odd"))
            .collect(engine="streaming")
            if is_portal
            else summary.select("rows", "odd")
        )
    except pl.exceptions.ComputeError as err:
        if raw_format is not RawFormat.TXT:
            raise_bad_quoting(path)
        message = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise NgsimInputError(path, f"cannot parse as CSV: {message}") from None
    _check_fields(path, raw_format, text, frame, summary, by_location, first_line)
    rows_read, height = int(by_location["rows"].sum()), int(summary["rows"][0])
    found = tuple(sorted(str(x) for x in by_location[s.LOCATION].drop_nulls())) if is_portal else ()
    if height == 0:
        unnamed = (
            int(by_location.filter(pl.col(s.LOCATION).is_null())["rows"].sum()) if is_portal else 0
        )
        held = [*found, *([f"{unnamed:,} rows with an empty Location"] if unnamed else [])]
        raise NgsimInputError(
            path,
            f"holds none of the chosen locations ({', '.join(locations)}); "
            f"it holds: {', '.join(held) or 'no rows'}",
        )
    return RawFile(
        path=path,
        raw_format=raw_format,
        size_bytes=path.stat().st_size,
        rows_read=rows_read,
        first_line=first_line,
        rows_other_locations=rows_read - height,
        locations_found=found,
        frame=frame.drop(PRESENT, ODD, POINTED),
    )
