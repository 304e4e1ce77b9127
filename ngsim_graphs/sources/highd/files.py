"""Reading highD's three CSV files: finding a recording's files, parsing, and one-line errors.

A file's kind is told from its header (its content), its recording from its name's `NN_`
prefix: `01_tracks.csv` needs `01_tracksMeta.csv` and `01_recordingMeta.csv` beside it. A
header with a damaged name is still its kind's (most of the kind's names, or the file's
`NN_kind.csv` name, tell it), so that the reader refuses it naming the column rather than a
search skipping the recording. Every value is read as text and parsed here, so that a malformed
number is reported with its file, line and column; a file whose last line has no line end was
cut short and is refused. Units stay highD's (metres, image coordinates); `geometry` maps them.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.recordings import FRAME_RATE_HZ, parse_file_name, sibling
from ngsim_graphs.sources.highd.schema import HighdFile
from ngsim_graphs.sources.inputs import files_in
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.text import (
    EXTRA,
    LINE,
    ROW,
    check_csv_field_counts,
    check_line_lengths,
    number_problem,
    raise_bad_quoting,
    scan_csv_fields,
    scan_lines,
)

SNIFF_BYTES = 64 * 1024
FIRST_LINE = 2  # the line of data row 0: ROW + FIRST_LINE is a row's line
_BAD = "__bad"
# Header columns that tell each kind of file (lower case); the kinds share no such set.
SIGNATURES: dict[HighdFile, frozenset[str]] = {
    HighdFile.TRACKS: frozenset(
        c.lower() for c in (hs.HIGHD_FRAME, hs.HIGHD_X_VELOCITY, hs.HIGHD_LANE_ID)
    ),
    HighdFile.TRACKS_META: frozenset(
        c.lower() for c in ("initialFrame", hs.HIGHD_DRIVING_DIRECTION)
    ),
    HighdFile.RECORDING_META: frozenset(
        c.lower() for c in (hs.HIGHD_FRAME_RATE, hs.HIGHD_LOCATION_ID)
    ),
}
HEADERS = {
    HighdFile.TRACKS: hs.HIGHD_TRACKS_HEADER,
    HighdFile.TRACKS_META: hs.HIGHD_TRACKS_META_HEADER,
    HighdFile.RECORDING_META: hs.HIGHD_RECORDING_META_HEADER,
}
SCHEMAS = {
    HighdFile.TRACKS: hs.HIGHD_TRACKS_SCHEMA,
    HighdFile.TRACKS_META: hs.HIGHD_TRACKS_META_SCHEMA,
    HighdFile.RECORDING_META: hs.HIGHD_RECORDING_META_SCHEMA,
}


@dataclass(frozen=True)
class RecordingMeta:
    """What a recordingMeta file says about its recording."""

    recording_id: int
    location_id: int
    upper_markings_m: tuple[float, ...]  # image y of the upper lanes' markings, top to bottom
    lower_markings_m: tuple[float, ...]  # image y of the lower lanes' markings, top to bottom


def header_names(path: Path) -> list[str] | None:
    """The fields of the first non-blank line, stripped (a byte-order mark too); None if empty."""
    with path.open("rb") as handle:
        head = handle.read(SNIFF_BYTES)
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    line = next((line for line in text.splitlines() if line.strip()), None)
    return None if line is None else [name.strip().strip('"') for name in line.split(",")]


def sniff_highd(path: Path) -> HighdFile | None:
    """The kind of highD file `path` is; None for any other file.

    Told from its header: the kind's signature columns, or else more than half of the kind's
    names (a header with a damaged name); or else from a name `NN_<kind>.csv`. The reader then
    refuses a damaged header naming its column (`check_header`)."""
    names = header_names(path)
    lowered = {name.lower() for name in names or ()}
    signed = next((kind for kind, needed in SIGNATURES.items() if needed <= lowered), None)
    if signed is not None:
        return signed
    for kind, header in HEADERS.items():
        if 2 * len(lowered & {name.lower() for name in header}) > len(header):
            return kind
    named = parse_file_name(path)
    return None if named is None else named[1]


def is_highd_file(path: Path) -> bool:
    """Whether `path` is a highD file (`sniff_highd`); a highD file whose header is damaged
    raises NgsimInputError naming the column (`check_header`)."""
    kind = sniff_highd(path)
    if kind is not None:
        check_header(path, kind)
    return kind is not None


def recording_files(path: Path) -> list[Path]:
    """The three files of the recording `path` belongs to: tracks, tracksMeta, recordingMeta."""
    kind = sniff_highd(path)
    if kind is None:
        raise NgsimInputError(
            path,
            "not a highD file: the header is none of tracks, tracksMeta, recordingMeta",
            line=1,
        )
    named = parse_file_name(path)
    if named is None:
        raise NgsimInputError(
            path,
            f"a highD {kind.value} file must be named NN_{kind.value}.csv (its recording number "
            "first) so that the recording's other files are found beside it",
        )
    prefix, name_kind = named
    if name_kind is not kind:
        raise NgsimInputError(
            path, f"named like a {name_kind.value} file but holds a {kind.value} header"
        )
    files = [sibling(path, prefix, other) for other in HighdFile]
    for other, file in zip(HighdFile, files, strict=True):
        if not file.is_file():
            raise NgsimInputError(
                path, f"no {file.name} beside it: a highD recording needs all three files"
            )
        if other is not kind and sniff_highd(file) is not other:
            raise NgsimInputError(file, f"does not hold a highD {other.value} header", line=1)
    return files


def find_highd_files(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    """Expand files and directories into highD files; returns (files, skipped other files).

    A named file brings its recording's three files. A directory is searched recursively for
    tracks files (`sniff_highd`: by header, a damaged one too, or by name), each with its two
    meta files; other .csv/.txt files are skipped, meta files without a tracks file too.
    """
    found: list[Path] = []
    skipped: list[Path] = []
    for path in paths:
        candidates = files_in(path, (".csv", ".txt"))
        if candidates is None:  # named: its recording's three files
            found.extend(recording_files(path))
            continue
        tracks = [p for p in candidates if sniff_highd(p) is HighdFile.TRACKS]
        if not tracks:
            raise NgsimInputError(path, "no highD tracks files (NN_tracks.csv) in this directory")
        members = [member for track in tracks for member in recording_files(track)]
        found.extend(members)
        skipped.extend(sorted(set(candidates) - set(members)))
    unique = list(dict.fromkeys(p.resolve() for p in found))
    return unique, skipped


def check_header(path: Path, kind: HighdFile) -> None:
    """Raise NgsimInputError unless the header of `path` holds every column the reader reads of
    a `kind` file, once (naming the column missing and the damaged name that may be it)."""
    header = header_names(path)
    if header is None:
        raise NgsimInputError(path, "empty file: no header and no data")
    _check_header(path, header, kind, list(SCHEMAS[kind]))


def _check_header(path: Path, header: list[str], kind: HighdFile, needed: list[str]) -> None:
    lowered = [name.lower() for name in header]
    twice = next((name for i, name in enumerate(header) if lowered[i] in lowered[:i]), None)
    if twice is not None:
        raise NgsimInputError(path, f"column {twice} appears twice in the header", line=1)
    known = {name.lower() for name in HEADERS[kind]}
    unknown = {name.lower(): name for name in header if name.lower() not in known}
    for column in needed:
        if column.lower() not in lowered:
            close = difflib.get_close_matches(column.lower(), list(unknown), n=1, cutoff=0.75)
            hint = f" (found '{unknown[close[0]]}': misspelled?)" if close else ""
            raise NgsimInputError(path, f"missing column {column}{hint}", line=1)


def _parsed(column: str, dtype: pl.DataType) -> tuple[pl.Expr, pl.Expr]:
    """The column `column` (lower-cased in the text) parsed as `dtype`, and whether its text is
    not empty yet no value of that dtype (not a number, not finite, not whole, out of range)."""
    text = pl.col(column.lower()).str.strip_chars()
    present = text.is_not_null() & (text != "")
    if dtype == pl.String:
        return pl.when(present).then(text).alias(column), pl.lit(False)
    real = text.cast(pl.Float64, strict=False)
    wrong = real.is_null() | ~real.is_finite()
    value = real
    if dtype != pl.Float64:
        value = real.cast(dtype, strict=False)
        wrong = wrong | (real != real.floor()) | value.is_null()
    return value.alias(column), (present & wrong).fill_null(False)


def _raise_bad_number(path: Path, text: pl.LazyFrame, row: int, schema: pl.Schema) -> None:
    """Name the first field of data row `row` that is not a value of its column's dtype."""
    fields = text.filter(pl.col(ROW) == row).select([c.lower() for c in schema]).collect().row(0)
    for (column, dtype), value in zip(schema.items(), fields, strict=True):
        problem = number_problem(value or "", dtype)
        if problem:
            raise NgsimInputError(
                path, f"column {column}: {value!r} {problem}", line=row + FIRST_LINE
            )
    raise NgsimInputError(path, "a value is out of range", line=row + FIRST_LINE)


def read_columns(path: Path, kind: HighdFile, schema: pl.Schema) -> pl.DataFrame:
    """The columns of `schema` of one highD file, parsed, with ROW (0-based data row).

    Empty fields become null. Raises NgsimInputError for an empty or header-only file, a
    missing column, a row with the wrong number of fields, or a value that does not parse.
    """
    header = header_names(path)
    if header is None:
        raise NgsimInputError(path, "empty file: no header and no data")
    _check_header(path, header, kind, list(schema))
    check_line_lengths(path)  # the reader would hold a line whole, of any length
    text = scan_csv_fields(path, [name.lower() for name in header])
    odd = pl.col(EXTRA).is_not_null() | pl.col(header[-1].lower()).is_null()
    parsed = [_parsed(column, dtype) for column, dtype in schema.items()]
    try:
        frame = text.select(
            ROW,
            *(value for value, _ in parsed),
            pl.any_horizontal(bad for _, bad in parsed).alias(_BAD),
            odd.alias(EXTRA),
        ).collect(engine="streaming")
    except pl.exceptions.ComputeError as err:
        raise_bad_quoting(path)
        raise NgsimInputError(
            path, f"cannot parse as CSV: {str(err).strip().splitlines()[0]}"
        ) from None
    if frame.height == 0:
        raise NgsimInputError(path, "no data rows")
    _check_line_end(path, int(frame[ROW].max()) + FIRST_LINE)
    if frame[EXTRA].any():
        check_csv_field_counts(path, len(header))
    bad = frame[_BAD].arg_true()
    if len(bad):
        _raise_bad_number(path, text, int(frame[ROW][int(bad[0])]), schema)
    return frame.drop(_BAD, EXTRA)


def _check_line_end(path: Path, last_line: int) -> None:
    """Raise when the file does not end with a line end: highD's files end every line with one,
    the last too, so a file without was cut short, perhaps inside its last field, which keeps
    the field count (a laneId 12 read as 1, a lane marking lost)."""
    with path.open("rb") as handle:
        handle.seek(-1, os.SEEK_END)
        if handle.read(1) != b"\n":
            raise NgsimInputError(
                path, "the last line has no line end: the file is cut short", line=last_line
            )


def count_data_rows(path: Path) -> int:
    """Non-blank lines after the header: the rows of a file whose values the build skips."""
    check_line_lengths(path)
    lines = scan_lines(path).filter(pl.col(LINE).str.strip_chars() != "")
    return int(lines.select(pl.len()).collect(engine="streaming").item())


def _markings(path: Path, column: str, text: str | None, far_m: float) -> tuple[float, ...]:
    """Lane markings `a;b;c` (image y, m): at least two finite numbers within +-`far_m` (the
    position limit), increasing."""
    fields = [v.strip() for v in (text or "").split(";") if v.strip()]
    for field in fields:
        problem = number_problem(field, pl.Float64)
        if problem is None and abs(float(field)) > far_m:
            problem = f"lies beyond the position limit of {far_m:,g} m"
        if problem:
            raise NgsimInputError(
                path, f"column {column}: {text!r}: {field!r} {problem}", line=FIRST_LINE
            )
    values = tuple(float(v) for v in fields)
    if len(values) < 2 or any(b <= a for a, b in zip(values, values[1:], strict=False)):
        raise NgsimInputError(
            path,
            f"column {column}: {text!r} is not a list of increasing numbers 'a;b;c'",
            line=FIRST_LINE,
        )
    return values


def read_recording_meta(path: Path, limits: PhysicalLimits) -> RecordingMeta:
    """The one row of a recordingMeta file; its frame rate must be highD's 25 Hz, its lane
    markings plausible (finite, within `limits`' position limit, increasing, the upper
    carriageway's above the lower's)."""
    frame = read_columns(path, HighdFile.RECORDING_META, hs.HIGHD_RECORDING_META_SCHEMA)
    if frame.height != 1:
        raise NgsimInputError(path, f"holds {frame.height} rows; a recordingMeta file holds one")
    row = frame.row(0, named=True)
    for column in (hs.HIGHD_ID, hs.HIGHD_FRAME_RATE, hs.HIGHD_LOCATION_ID):
        if row[column] is None or row[column] < 1:
            raise NgsimInputError(
                path, f"column {column}: {row[column]!r} is not a positive number", line=FIRST_LINE
            )
    if row[hs.HIGHD_FRAME_RATE] != FRAME_RATE_HZ:
        raise NgsimInputError(
            path,
            f"frameRate {row[hs.HIGHD_FRAME_RATE]}: highD recordings run at {FRAME_RATE_HZ} Hz",
            line=FIRST_LINE,
        )
    upper, lower = (
        _markings(path, column, row[column], limits.max_abs_position_m)
        for column in (hs.HIGHD_UPPER_LANE_MARKINGS, hs.HIGHD_LOWER_LANE_MARKINGS)
    )
    if upper[-1] > lower[0]:
        raise NgsimInputError(
            path,
            f"upperLaneMarkings end at image y {upper[-1]:g}, below the first of "
            f"lowerLaneMarkings ({lower[0]:g}): the upper carriageway lies above the lower one",
            line=FIRST_LINE,
        )
    return RecordingMeta(
        recording_id=row[hs.HIGHD_ID],
        location_id=row[hs.HIGHD_LOCATION_ID],
        upper_markings_m=upper,
        lower_markings_m=lower,
    )


def read_tracks_meta(path: Path) -> pl.DataFrame:
    """Per vehicle: VEHICLE_ID, V_CLASS (NGSIM's code), HIGHD_DRIVING_DIRECTION (1 or 2) and
    HIGHD_NUM_FRAMES (its rows in the tracks file).

    Raises for an empty field, a class other than Car or Truck, a direction other than 1 or 2,
    or an id that appears twice.
    """
    frame = read_columns(path, HighdFile.TRACKS_META, hs.HIGHD_TRACKS_META_SCHEMA)
    code = (
        pl.col(hs.HIGHD_CLASS).str.to_lowercase().replace_strict(hs.HIGHD_CLASS_CODES, default=None)
    )
    checked = frame.with_columns(code.cast(pl.Int8).alias(s.V_CLASS))
    problems = (
        (
            pl.any_horizontal(pl.col(hs.HIGHD_TRACKS_META_SCHEMA.names()).is_null()),
            "an empty field",
        ),
        (pl.col(s.V_CLASS).is_null(), "a class other than Car or Truck"),
        (~pl.col(hs.HIGHD_DRIVING_DIRECTION).is_in([1, 2]), "a drivingDirection other than 1 or 2"),
        (pl.col(hs.HIGHD_ID).is_duplicated(), "an id that appears twice"),
        (pl.col(hs.HIGHD_ID) < 1, "an id below 1"),
    )
    for condition, what in problems:
        found = checked.filter(condition.fill_null(True))
        if found.height:
            raise NgsimInputError(path, f"holds {what}", line=int(found[ROW].min()) + FIRST_LINE)
    return checked.select(
        pl.col(hs.HIGHD_ID).alias(s.VEHICLE_ID),
        s.V_CLASS,
        hs.HIGHD_DRIVING_DIRECTION,
        hs.HIGHD_NUM_FRAMES,
    )


def read_tracks(path: Path) -> pl.DataFrame:
    """The parsed HIGHD_TRACKS_SCHEMA columns of a tracks file, with ROW; empty fields null."""
    return read_columns(path, HighdFile.TRACKS, hs.HIGHD_TRACKS_SCHEMA)
