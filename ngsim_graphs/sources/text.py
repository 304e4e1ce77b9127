"""Reading delimited text files a line or a field at a time, and naming the line at fault.

The sources parse a whole file in one streaming pass and only count what is odd; when something
is, these functions look again, line by line, for the first line at fault and say what is wrong
there in one line: a wrong number of fields, a quote left open or misplaced, a control
character, a field that is not a number (or not finite, or not whole, or out of range). A line
longer than any row (MAX_LINE_BYTES) is refused as soon as it is met, never read whole.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import IO

import numpy as np
import polars as pl

from ngsim_graphs.errors import NgsimInputError

# The longest line a source reads, in bytes, its line end not counted: NGSIM's and highD's rows
# and headers are under 300 bytes. A longer line is no row of theirs (zeros, binary data, text
# without line ends) and is refused as soon as it is met, never read whole.
MAX_LINE_BYTES = 4_096
_SCAN_BYTES = 16 * 1024 * 1024  # check_line_lengths reads this much of a file at a time

ROW = "__row"  # 0-based data row in the file, kept to name lines in errors
EXTRA = "__extra"  # the first surplus field of a CSV row
LINE = "__line"
CONTROL = "__control"  # what follows a 0x1F byte in a line (see scan_lines)
_CUT = "\x1f"


def long_line_at(
    text: bytes | bytearray, end: int | None = None, max_line_bytes: int = MAX_LINE_BYTES
) -> int | None:
    """The offset of the first line of `text` (up to `end`) longer than `max_line_bytes` (a
    last line without its line end counts once it is longer); None where there is none. Looks
    at one line end in every `max_line_bytes` or so, not at every line."""
    end = len(text) if end is None else end
    start = 0  # a line's first byte
    while end - start > max_line_bytes:
        found = text.rfind(b"\n", start, start + max_line_bytes + 1)  # the last within reach
        if found < 0:
            return start
        start = found + 1
    return None


def raise_long_line(path: Path, line: int) -> None:
    raise NgsimInputError(
        path,
        f"a line longer than {MAX_LINE_BYTES:,} bytes, which no trajectory row is "
        "(binary data? no line ends?)",
        line=line,
    )


def check_line_length(path: Path, text: bytes, first_line: int) -> None:
    """Raise NgsimInputError for the first line of `text` (a part of `path` whose first line is
    line `first_line`, from 1) longer than MAX_LINE_BYTES, naming its line."""
    start = long_line_at(text)
    if start is not None:
        raise_long_line(path, first_line + text.count(b"\n", 0, start))


def check_line_lengths(path: Path) -> None:
    """Raise NgsimInputError naming the first line of `path` longer than MAX_LINE_BYTES. Reads
    16 MB at a time into one buffer, holding no more of a line than that bound, however long
    it is (`long_line_at` looks at 16 MB in a few ms; the lines are counted only for the
    error)."""
    buffer = bytearray(MAX_LINE_BYTES + _SCAN_BYTES)
    kept, offset = 0, 0  # the bytes of a line carried at the buffer's start; its file offset
    with path.open("rb") as handle:
        while n_read := handle.readinto(memoryview(buffer)[kept : kept + _SCAN_BYTES]):
            end = kept + n_read
            start = long_line_at(buffer, end)
            if start is not None:
                raise_long_line(path, _line_at(path, offset + start))
            cut = buffer.rfind(b"\n", 0, end) + 1
            buffer[: end - cut] = buffer[cut:end]  # the part of a line, under the bound
            kept, offset = end - cut, offset + cut


def _line_at(path: Path, offset: int) -> int:
    """The line (from 1) of `path` that byte `offset` is in."""
    line = 1
    with path.open("rb") as handle:
        while offset > 0 and (data := handle.read(min(offset, _SCAN_BYTES))):
            line, offset = line + data.count(b"\n"), offset - len(data)
    return line


def scan_lines(path: Path | IO[bytes], skip_rows: int = 1) -> pl.LazyFrame:
    """Every line after the first `skip_rows` as one text column (LINE), quotes untouched (of a
    file, or of a range of its bytes).

    Lines are cut at a byte no NGSIM file holds (0x1F, the unit separator); a line that holds it
    anyway has the rest in CONTROL, so that it is reported rather than read as more columns.
    """
    return pl.scan_csv(
        path,
        has_header=False,
        skip_rows=skip_rows,
        separator=_CUT,
        quote_char=None,
        schema={LINE: pl.String, CONTROL: pl.String},
        missing_columns="insert",
        truncate_ragged_lines=True,
        encoding="utf8-lossy",
    )


def scan_csv_fields(
    path: Path | IO[bytes], names: list[str], skip_rows: int = 1, first_row: int = 0
) -> pl.LazyFrame:
    """A CSV's data rows as text columns `names` (the header, lower-cased), with ROW from
    `first_row` (of a file, or of a range of its bytes: `skip_rows` 0 but in the first); blank
    lines dropped. Polars drops a row's surplus fields silently: the one spare column EXTRA
    keeps the first of them, so that ragged rows can be found."""
    frame = pl.scan_csv(
        path,
        has_header=False,
        skip_rows=skip_rows,
        schema=dict.fromkeys([*names, EXTRA], pl.String),
        missing_columns="insert",
        truncate_ragged_lines=True,
        quote_char='"',
        encoding="utf8-lossy",
    )
    # Blank lines read as all-null rows: neither data nor another location.
    not_blank = pl.any_horizontal(pl.col(names).is_not_null())
    return frame.with_row_index(ROW, offset=first_row).filter(not_blank)


def raise_control_character(path: Path, row: int, first_line: int) -> None:
    raise NgsimInputError(
        path, "holds a control character (0x1F): not NGSIM text", line=row + first_line
    )


# A CSV line whose quoting is well formed: fields unquoted (no quote in them) or quoted whole.
_FIELD = r'(?:[^",]*|"(?:[^"]|"")*")'
_QUOTED_CSV_LINE = rf"^{_FIELD}(?:,{_FIELD})*\r?$"


def raise_bad_quoting(path: Path) -> None:
    """Raise for the first line with an odd number of double quotes (a truncated quoted field),
    or a control character, or quoting that is not well formed (the CSV parser's own error
    names no line).

    The sources' fields never hold a line break, so a quote left open on one line is an error there,
    not a field that goes on: the CSV parser would read on into the next lines.
    """
    odd = pl.col(LINE).str.count_matches('"', literal=True) % 2 == 1
    scan = scan_lines(path).with_row_index(ROW).filter(odd | pl.col(CONTROL).is_not_null())
    found = scan.select(ROW, CONTROL).head(1).collect(engine="streaming")
    if found.height:
        row, control = found.row(0)
        if control is not None:
            raise_control_character(path, row, 2)
        raise NgsimInputError(path, "a quoted field is not closed (truncated line?)", line=row + 2)
    well_formed = pl.col(LINE).str.contains(_QUOTED_CSV_LINE)
    bad = scan_lines(path).with_row_index(ROW).filter(~well_formed).select(ROW).head(1)
    found = bad.collect(engine="streaming")
    if found.height:
        raise NgsimInputError(
            path,
            'malformed quoting: a quote inside a field, or text after a closing "',
            line=int(found.item()) + 2,
        )


def check_csv_field_counts(path: Path, n_columns: int) -> None:
    """Raise for the first non-blank line whose field count differs from the header's.

    The exact check behind _odd_csv_shape: counts the commas outside quotes of every line in
    one streaming pass. It runs only for files where a row looked odd.
    """
    lines = scan_lines(path)
    unquoted = pl.col(LINE).str.replace_all(r'"[^"]*"', "")
    n_fields = unquoted.str.count_matches(",", literal=True) + 1
    wrong = (
        lines.with_row_index(ROW)
        .filter(pl.col(LINE).str.strip_chars() != "")
        .select(ROW, n_fields.alias("n"), CONTROL)
        .filter((pl.col("n") != n_columns) | pl.col(CONTROL).is_not_null())
        .head(1)
        .collect(engine="streaming")
    )
    if wrong.height:
        row, n, control = wrong.row(0)
        if control is not None:
            raise_control_character(path, row, 2)
        cause = "truncated line?" if n < n_columns else "an unquoted comma?"
        raise NgsimInputError(
            path, f"{n} fields where the header has {n_columns} ({cause})", line=row + 2
        )


# A decimal number as the reader parses it. Python's float() accepts more ("1_000", "\x1f1"),
# so it is not the judge of what the reader could not parse.
_DECIMAL = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_NOT_FINITE = ("inf", "infinity", "nan")
_RUST_WHITESPACE = (
    " \t\n\v\f\r\x85\xa0\u1680\u2000\u2001\u2002\u2003\u2004\u2005\u2006\u2007\u2008\u2009"
    "\u200a\u2028\u2029\u202f\u205f\u3000"
)


# A number written with thousands separators as the portal writes them (`1,156`, `-1,234.5`,
# `12,345,678`): 1-3 digits, then groups of exactly 3, then a fraction. Only such commas are
# stripped; any other (`-1,2` or `0,5`, a decimal comma; `1,,5`; `,25`) leaves the field as it is,
# which then does not parse: "not a number", with its line.
_GROUPED = r"[+-]?[0-9]{1,3}(?:,[0-9]{3})+(?:\.[0-9]*)?"
_GROUPED_FULL = re.compile(_GROUPED)


def without_thousands(text: pl.Expr) -> pl.Expr:
    """A text column, stripped, without its thousands separators where it is a number written
    with them (`_GROUPED`), as it is otherwise."""
    stripped = text.str.strip_chars()
    grouped = stripped.str.contains(f"^{_GROUPED}$")
    return (
        pl.when(grouped).then(stripped.str.replace_all(",", "", literal=True)).otherwise(stripped)
    )


def field_without_thousands(text: str) -> str:
    """One field as `without_thousands` reads it: stripped, its thousands separators dropped
    where it is a number written with them."""
    stripped = text.strip(_RUST_WHITESPACE)
    return stripped.replace(",", "") if _GROUPED_FULL.fullmatch(stripped) else stripped


def number_problem(text: str, dtype: pl.DataType) -> str | None:
    """What is wrong with one field's text as a value of `dtype`; None when it is fine or empty.

    `text` is stripped as polars' `strip_chars()` strips (Unicode white space, no control codes).
    """
    text = text.strip(_RUST_WHITESPACE)
    if text == "":
        return None
    if not _DECIMAL.fullmatch(text):
        return (
            "is not a finite number"
            if text.lower().lstrip("+-") in _NOT_FINITE
            else "is not a number"
        )
    value = float(text)
    if not math.isfinite(value):
        return "is not a finite number"
    if dtype != pl.Float64:
        if value != math.floor(value):
            return "is not a whole number"
        info = np.iinfo(str(dtype).lower())  # polars Int32 -> "int32"
        if not info.min <= value <= info.max:
            return f"is out of range ({info.min:,} to {info.max:,})"
    return None
