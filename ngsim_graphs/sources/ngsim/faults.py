"""Naming the NGSIM line and field at fault once a raw file failed to read fast.

The reader (`files`) parses a whole file in one streaming pass and only counts what is odd; when
something is, these functions look again for the first line at fault, with the line scans of
`sources.text`: a wrong number of fields, a field that is not a number of its column's dtype.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.text import (
    CONTROL,
    EXTRA,
    ROW,
    check_csv_field_counts,
    field_without_thousands,
    number_problem,
    raise_control_character,
)

PRESENT = "__present"  # non-empty fields of a row
ODD = "__odd"  # the row may have a wrong number of fields
N_FIELDS = "__n_fields"  # fields of a text line
POINTED = "__pointed"  # an integer field of the row has a point or an exponent


def raise_bad_number(path: Path, text: pl.LazyFrame, row: int, first_line: int) -> None:
    """Name the first field of data row `row` that is not a number (re-reading that row only)."""
    fields = text.filter(pl.col(ROW) == row).select(ns.TXT_COLUMNS).collect().row(0, named=True)
    official = {name.lower(): name for name in ns.PORTAL_HEADER}
    for column, value in fields.items():
        problem = number_problem(field_without_thousands(value or ""), ns.RAW_SCHEMA[column])
        if problem:
            message = f"column {official[column]}: {value!r} {problem}"
            raise NgsimInputError(path, message, line=row + first_line)
    raise NgsimInputError(path, "a value is out of range", line=row + first_line)


def raise_odd_shape(path: Path, raw_format: RawFormat, text: pl.LazyFrame) -> None:
    """Raise for the first row with a wrong number of fields (a CSV may turn out fine)."""
    if raw_format is RawFormat.TXT:
        odd = text.filter(pl.col(ODD)).select(ROW, N_FIELDS, CONTROL).head(1).collect().row(0)
        row, n_fields, control = odd
        if control is not None:
            raise_control_character(path, row, 1)
        expected = len(ns.TXT_COLUMNS)
        cause = "truncated line?" if n_fields < expected else "more fields than NGSIM's"
        raise NgsimInputError(
            path, f"{n_fields} fields where {expected} were expected ({cause})", line=row + 1
        )
    columns = text.collect_schema().names()
    check_csv_field_counts(path, columns.index(EXTRA) - 1)  # the fields between ROW and EXTRA
