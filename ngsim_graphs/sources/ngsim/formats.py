"""NGSIM's three file formats: finding a build's NGSIM files, telling a file's format from its
first lines (never from its name), and the checks of its header and of its end made before it
is parsed (`files`)."""

from __future__ import annotations

import csv
import difflib
import re
from pathlib import Path

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.archives import archives_in
from ngsim_graphs.sources.inputs import files_in
from ngsim_graphs.sources.ngsim import schema as ns

SNIFF_BYTES = 64 * 1024
CANDIDATE_SUFFIXES = (".csv", ".txt")


class NotNgsimFileError(NgsimInputError):
    """The file is empty or of another kind: a folder search skips it, a named file fails."""


def find_raw_files(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    """Expand files and directories into NGSIM files; returns (files, skipped non-NGSIM files).

    A named file is always taken (reading it reports what is wrong with it). A directory is
    searched recursively for .csv/.txt files whose first line looks like NGSIM data; a file
    there that is not is skipped only when it is plainly something else (`is_plainly_other`),
    and is otherwise an error naming it and the place.
    """
    found: list[Path] = []
    skipped: list[Path] = []
    for path in paths:
        candidates = files_in(path, CANDIDATE_SUFFIXES)
        if candidates is None:  # named: always taken
            found.append(path)
            continue
        inside = []
        for candidate in candidates:
            try:
                sniff_format(candidate)
                inside.append(candidate)
            except NotNgsimFileError:
                if not is_plainly_other(candidate):
                    raise
                skipped.append(candidate)
        if not inside and not archives_in(path):  # an archive's files are searched unpacked
            raise NgsimInputError(
                path, "no NGSIM trajectory files (.csv or .txt) in this directory"
            )
        found.extend(inside)
    unique = list(dict.fromkeys(p.resolve() for p in found))
    return unique, skipped


# A name that says "trajectory file": NGSIM's own (`trajectories-0750am-0805am.txt`, the portal
# export's `..._Vehicle_Trajectories_...csv`) or a period's (`0400-0415`).
_TRAJECTORY_NAME = re.compile(r"trajector|\d{4}(am|pm)?-\d{4}(am|pm)?", re.IGNORECASE)


def _is_numbers_line(line: str) -> bool:
    """Whether a line is two or more numbers, split by whitespace or commas: a row of some table."""
    tokens = [token for token in re.split(r"[\s,]+", line) if token]
    return len(tokens) >= 2 and all(_is_number(token) for token in tokens)


def is_plainly_other(path: Path) -> bool:
    """Whether a file that `sniff_format` does not take is plainly something else (a readme, a
    note): not named like a trajectory file, not empty, and none of its first lines a row of
    numbers. A damaged trajectory file (a column dropped or added, cut inside its first line,
    emptied) is none of these: reading it says what is wrong, and where."""
    if _TRAJECTORY_NAME.search(path.name):
        return False
    lines = _head_lines(path)
    return bool(lines) and not any(_is_numbers_line(line) for line in lines[: SNIFF_LINES + 1])


def _head_lines(path: Path) -> list[str]:
    """The non-blank lines of the file's first SNIFF_BYTES (a byte-order mark dropped; the last
    one may be cut short)."""
    with path.open("rb") as handle:
        head = handle.read(SNIFF_BYTES)
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    return [line for line in text.splitlines() if line.strip()]


def first_line(path: Path) -> str:
    lines = _head_lines(path)
    if not lines:
        raise NotNgsimFileError(path, "empty file: no header and no data")
    return lines[0]


def _has_cr_only_line_ends(path: Path) -> bool:
    with path.open("rb") as handle:
        head = handle.read(SNIFF_BYTES)
    return b"\r" in head.rstrip(b"\r") and b"\n" not in head


def header_names(line: str) -> list[str]:
    """Header fields as spelled in the file, stripped."""
    return [name.strip() for name in next(csv.reader([line]))]


def _is_number(token: str) -> bool:
    try:
        float(token.replace(",", ""))
    except ValueError:
        return False
    return True


def sniff_format(path: Path) -> RawFormat:
    """Tell the format from the first line: a CSV header with Vehicle_ID, or 18 numbers."""
    raw_format = _format_of_first_line(path)
    if _has_cr_only_line_ends(path):
        # Polars splits lines at LF only: the whole file would read as one line.
        raise NgsimInputError(
            path, "lines end in CR alone (classic Mac OS); convert them to LF or CRLF", line=1
        )
    return raw_format


def is_ngsim_file(path: Path) -> bool:
    """Whether `path` is an NGSIM file, told from its content: one that `sniff_format` reads, or
    refuses for a fault of its own (CR line ends: the reader says why)."""
    try:
        sniff_format(path)
    except NotNgsimFileError:
        return False
    except NgsimInputError:
        return True
    return True


# Whether the lines after a first line that is neither a header nor a row look like NGSIM's: a
# file is skipped as "not NGSIM" only when none of these does.
SNIFF_LINES = 20


def _is_txt_row(line: str) -> bool:
    tokens = line.split()
    return len(tokens) == len(ns.TXT_COLUMNS) and all(_is_number(t) for t in tokens)


def _is_csv_row(line: str) -> bool:
    """Whether a line is a row of one of NGSIM's CSV files: as many fields as a header of
    theirs (the portal file's 25, a per-period file's 24 or 18), most of them numbers."""
    fields = next(csv.reader([line]), [])
    numbers = sum(_is_number(f) for f in fields if f.strip())
    widths = (len(ns.TXT_COLUMNS), len(ns.PORTAL_HEADER) - 1, len(ns.PORTAL_HEADER))
    return len(fields) in widths and numbers >= len(ns.TXT_COLUMNS) - 2


def _format_of_first_line(path: Path) -> RawFormat:
    lines = _head_lines(path)
    if not lines:
        raise NotNgsimFileError(path, "empty file: no header and no data")
    line = lines[0]
    if "," in line:
        header = [name.lower() for name in header_names(line)]
        if s.VEHICLE_ID in header or sum(c in header for c in ns.TXT_COLUMNS) >= 9:
            return RawFormat.PORTAL if s.LOCATION in header else RawFormat.CSV
    if _is_txt_row(line):
        return RawFormat.TXT
    # A damaged first line does not make a file of NGSIM rows another kind of file: it is read
    # (its first line is then reported) or refused, never skipped with its recording.
    after = lines[1 : SNIFF_LINES + 1]
    if any(_is_txt_row(other) for other in after):
        return RawFormat.TXT
    if any(_is_csv_row(other) for other in after):
        raise NgsimInputError(
            path,
            "the first line is no header of NGSIM's columns (Vehicle_ID, Frame_ID, ...), yet the "
            "lines after it hold NGSIM rows: is the header damaged or missing?",
            line=1,
        )
    raise NotNgsimFileError(path, f"not an NGSIM trajectory file: {_why_not(path, line)}", line=1)


def _why_not(path: Path, line: str) -> str:
    """What is wrong with a first line that is neither NGSIM's header nor one of its rows (nor
    are the lines after it)."""
    n_columns = len(ns.TXT_COLUMNS)
    if not _is_numbers_line(line) or "," in line:
        return (
            "the first line is neither a CSV header with Vehicle_ID, Frame_ID, ... nor "
            f"{n_columns} whitespace-separated numbers, and neither are the lines after it"
        )
    with path.open("rb") as handle:
        ends = b"\n" in handle.read(SNIFF_BYTES)
    what = "a column missing or added?" if ends else "no line end: is the file cut short?"
    return (
        f"the first line holds {len(line.split())} whitespace-separated numbers where NGSIM's "
        f"rows hold {n_columns} ({what})"
    )


def check_csv_columns(path: Path, header: list[str], raw_format: RawFormat) -> None:
    lowered = [name.lower() for name in header]
    twice = next((name for i, name in enumerate(header) if lowered[i] in lowered[:i]), None)
    if twice is not None:
        raise NgsimInputError(path, f"column {twice} appears twice in the header", line=1)
    required = ns.TXT_COLUMNS + ((s.LOCATION,) if raw_format is RawFormat.PORTAL else ())
    official = {name.lower(): name for name in ns.PORTAL_HEADER}
    present = {name.lower() for name in header}
    # Only a name that matches no known column can be a misspelling of the missing one.
    unknown = {name.lower(): name for name in header if name.lower() not in official}
    for column in required:
        if column not in present:
            close = difflib.get_close_matches(column, list(unknown), n=1, cutoff=0.75)
            hint = f" (found '{unknown[close[0]]}': misspelled?)" if close else ""
            raise NgsimInputError(path, f"missing column {official[column]}{hint}", line=1)


# A file without a final line end may have been cut inside its last field, which then still
# parses ("97.6" of "97.68", "us-10" of "us-101"): its last field is compared with the same field
# of the lines before it, this many of them.
CUT_CHECK_LINES = 20
_TAIL_BYTES = 64 * 1024


def _fields(line: str, raw_format: RawFormat) -> list[str]:
    if raw_format is RawFormat.TXT:
        return line.split()
    return [field.strip() for field in next(csv.reader([line]), [])]


def _decimals(text: str) -> int | None:
    """Digits after the point of a plain decimal number (0 without a point); None otherwise."""
    if not _is_number(text) or any(c in text for c in "eEnN"):
        return None
    return len(text.split(".")[1]) if "." in text else 0


def _looks_cut(last: str, before: list[str]) -> bool:
    """Whether `last` reads as a field of the same column as `before` cut short: empty where
    they are not, fewer decimals than every one of them has, or the start of a name of theirs."""
    if not last:
        return all(before)
    places = {_decimals(value) for value in before}
    if len(places) == 1 and (fixed := places.pop()) is not None:
        written = _decimals(last)
        return written is None or written < fixed or last.endswith(".")
    return last not in before and any(value.startswith(last) for value in before)


def check_not_cut(path: Path, raw_format: RawFormat) -> None:
    """Refuse a file that ends inside its last field (no final line end, and its last field
    cut short against the lines before it, `_looks_cut`): a truncated copy."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        handle.seek(max(0, size - _TAIL_BYTES))
        tail = handle.read()
    if not tail or tail.endswith(b"\n"):
        return
    lines = [line for line in tail.decode("utf-8", errors="replace").splitlines() if line.strip()]
    lines = lines[1:] if size > _TAIL_BYTES else lines  # the first may be a part of a line
    rows = [_fields(line, raw_format) for line in lines[-CUT_CHECK_LINES - 1 :]]
    if len(rows) < 2 or len(rows[-1]) != len(rows[-2]):  # a line cut short: the parser says
        return
    fields = [row[-1] if row else "" for row in rows]
    if not _looks_cut(fields[-1], fields[:-1]):
        return
    with path.open("rb") as handle:
        line = 1 + sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 24), b""))
    raise NgsimInputError(
        path,
        f"the file ends inside its last field ({fields[-1]!r} where the lines before it hold "
        f"values like {fields[-2]!r}) and without a line end: is it truncated?",
        line=line,
    )
