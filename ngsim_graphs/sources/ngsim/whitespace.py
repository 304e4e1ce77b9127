"""NGSIM's whitespace text parsed by Polars' own CSV reader: the fast path of `files`.

The original per-period text separates its 18 fields by runs of spaces, with spaces before and
after each line. Polars' CSV reader takes one separator byte, so a chunk of whole lines is first
made plain with numpy (every run of spaces between two fields one space, none at a line's ends)
and then parsed straight into the raw dtypes, some 400 MB of text a second and a core each.

Only plain text takes this path: digits, points, minus signs, spaces, tabs and line ends (CRLF
too), every line of 18 fields, every value a number of its column (an integer column's written
without a point, within the range where its value is exactly a float64, as the general reader
reads it). Anything else, however rare (a blank line, a thousands separator, an exponent, a
letter, a field too many or too few, a value out of range), returns None, and the chunk goes to
the general reader (`files._scan_txt_text`), which names the line at fault: the rows of the two
paths are the same (tests/test_ngsim_whitespace.py holds them to each other).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.faults import ODD, POINTED, PRESENT
from ngsim_graphs.sources.text import ROW

_PLAIN = b"0123456789.- \t\r\n"  # the bytes of plain text
_SPACE, _NEWLINE = 32, 10
_TO_SPACE = bytes.maketrans(b"\t\r", b"  ")
_INDENT = "__indent"  # the empty field before a line's first
# The general reader reads an integer through float64: beyond 2**53 it rounds, and so must agree.
_EXACT_INT = 2**53
_PARSED = {c: ns.RAW_SCHEMA[c] for c in ns.TXT_COLUMNS}


def is_plain(text: bytes) -> bool:
    """Whether `text` holds only the bytes of plain text, a CR only before a LF."""
    if text.translate(None, _PLAIN):
        return False
    return b"\r" not in text or text.count(b"\r") == text.count(b"\r\n")


def single_spaced(text: bytes, line_ends: int) -> tuple[bytes, bool]:
    """(lines, indented): `text` (plain, whole lines, `line_ends` LFs) with its fields one space
    apart and no space at a line's end (a blank line stays, empty); with `indented`, every line
    begins with one space (NGSIM pads its lines), which the CSV reader reads as an empty first
    field. One pass to choose the bytes kept and one to keep them: the two cost about what
    Polars' reader does."""
    raw = np.frombuffer(
        text.translate(_TO_SPACE) if b"\t" in text or b"\r" in text else text, np.uint8
    )
    keep = raw != _SPACE
    np.logical_or(keep[:-1], raw[1:] > _SPACE, out=keep[:-1])  # the last space before a field
    kept = raw[keep]
    lines = kept.tobytes()
    # Lines that begin with a space: the first, and those after a line end (bytes.count of a
    # two-byte pattern is three times as slow as finding the line ends).
    ends = np.flatnonzero(kept == _NEWLINE)
    after = ends[ends < len(kept) - 1] + 1
    starts = int(np.count_nonzero(kept[after] == _SPACE)) + lines.startswith(b" ")
    if starts == line_ends + (not lines.endswith(b"\n")):
        return lines, True
    if starts == 0:
        return lines, False
    leading = np.zeros(len(kept), bool)  # some lines begin with a space and some do not
    leading[0] = kept[0] == _SPACE
    np.logical_and(kept[1:] == _SPACE, kept[:-1] == _NEWLINE, out=leading[1:])
    return kept[~leading].tobytes(), False


def parse_plain(text: bytes, first_row: int, line_ends: int) -> pl.DataFrame | None:
    """The rows of a chunk of whole lines (`line_ends` LFs: the last may lack its own) as the
    general reader parses them (ROW from `first_row`, the 18 columns in RAW_SCHEMA's dtypes,
    LOCATION null, PRESENT, POINTED, ODD), or None where the chunk is not plain text of 18
    numbers a line."""
    if not text or not is_plain(text):
        return None
    lines = line_ends + (not text.endswith(b"\n"))
    fields, indented = single_spaced(text, line_ends)
    try:
        parsed = pl.read_csv(
            fields if fields.endswith(b"\n") else fields + b"\n",
            has_header=False,
            separator=" ",
            quote_char=None,
            schema={_INDENT: pl.String, **_PARSED} if indented else _PARSED,
        )
    except (pl.exceptions.PolarsError, ValueError):
        return None  # a field that is no number of its column (or out of its range), one too many
    if indented:
        if parsed[_INDENT].null_count() != parsed.height:
            return None
        parsed = parsed.drop(_INDENT)
    if parsed.height != lines or any(parsed.null_count().row(0)):  # a blank or short line
        return None
    if parsed[ns.GLOBAL_TIME].abs().max() >= _EXACT_INT:
        return None
    return parsed.select(
        pl.int_range(first_row, first_row + parsed.height, dtype=pl.UInt32).alias(ROW),
        *ns.TXT_COLUMNS,
        pl.lit(None, dtype=pl.String).alias(s.LOCATION),
        pl.lit(len(ns.TXT_COLUMNS), dtype=pl.Int8).alias(PRESENT),
        pl.lit(False).alias(POINTED),
        pl.lit(False).alias(ODD),
    )
