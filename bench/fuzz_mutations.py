"""The inputs and the damage of bench/fuzz_inputs.py: small valid NGSIM files of each format,
and seeded mutations of their bytes (truncation, byte flips, field values, column swaps, extra
columns, non-UTF-8 bytes, lines deleted or repeated, CR line ends, other file types).

A mutation is a pure function (rng, input bytes, format) -> (output bytes, what it did); a case
(seed, index, format, kind) always gives the same bytes (`make_input`).
"""

from __future__ import annotations

import csv
import gzip
import io
import itertools
import json
import re
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS

FORMATS = ("portal", "csv", "txt")
FILE_NAMES = {
    "portal": "Next_Generation_Simulation__NGSIM__Vehicle_Trajectories_and_Supporting_Data.csv",
    "csv": "trajectories-0750am-0805am.csv",
    "txt": "trajectories-0750am-0805am.txt",
}
N_VEHICLES, N_FRAMES = 10, 100
OFFICIAL_NAMES = {name.lower(): name for name in ns.PORTAL_HEADER}
INTEGER_COLUMNS = frozenset(c for c in ns.TXT_COLUMNS if ns.RAW_SCHEMA[c] != pl.Float64)

Mutator = Callable[[np.random.Generator, bytes, str], tuple[bytes, str]]


# ---- the unmutated inputs (the writers of tests/conftest.py, as bytes) --------------------------


def base_rows() -> list[dict[str, float]]:
    """Vehicles 1..10 of us-101 0750am, frames 0..99 each, in NGSIM units (feet, ms): each
    spans 50 grid steps, one 8.2 s window, so the build makes 10 samples."""
    frame0_ms = OFFICIAL_RECORDINGS[0].start_epoch_ms - 7_000
    rows = []
    for vehicle in range(1, N_VEHICLES + 1):
        for frame in range(N_FRAMES):
            x_ft, y_ft = 6.0 + 12.0 * (vehicle % 5), 40.0 * (vehicle // 5) + 3.5 * frame
            rows.append(
                {
                    s.VEHICLE_ID: vehicle,
                    s.FRAME_ID: frame,
                    ns.TOTAL_FRAMES: N_FRAMES,
                    s.GLOBAL_TIME: frame0_ms + 100 * frame,
                    ns.LOCAL_X: x_ft,
                    ns.LOCAL_Y: y_ft,
                    ns.GLOBAL_X: 6451000.0 + x_ft,
                    ns.GLOBAL_Y: 1873000.0 + y_ft,
                    ns.V_LENGTH: 15.0,
                    ns.V_WIDTH: 6.0,
                    s.V_CLASS: 2,
                    ns.V_VEL: 35.0,
                    ns.V_ACC: 0.0,
                    s.LANE_ID: 1 + vehicle % 5,
                    s.PRECEDING: 0,
                    s.FOLLOWING: 0,
                    ns.SPACE_HEADWAY: 0.0,
                    ns.TIME_HEADWAY: ns.NO_LEADER_TIME_HEADWAY_S,
                }
            )
    return rows


def _text(value: float | None, thousands: bool) -> str:
    if value is None:
        return ""
    text = f"{value:.3f}".rstrip("0").rstrip(".") if isinstance(value, float) else str(value)
    if thousands and abs(float(value)) >= 1000:
        whole, _, frac = text.partition(".")
        text = f"{int(whole):,}" + (f".{frac}" if frac else "")
    return text


def _csv_bytes(header: list[str], body: list[list[str]], quirks: bool) -> bytes:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\r\n" if quirks else "\n")
    writer.writerow(header)
    writer.writerows(body)
    return (("\ufeff" if quirks else "") + buffer.getvalue()).encode()


@cache
def base_input(fmt: str) -> bytes:
    """The valid input of `fmt`: portal with BOM, CRLF and quoted thousands ("1,156"); a
    per-period CSV spelling `v_Length`; text with padded fields and no final newline."""
    rows = base_rows()
    if fmt == "txt":
        lines = [
            "   " + "  ".join(_text(r[c], False).rjust(6) for c in ns.TXT_COLUMNS) + "  "
            for r in rows
        ]
        return "\n".join(lines).encode()
    if fmt == "portal":
        body = [
            [_text(r.get(c.lower()), True) for c in ns.PORTAL_HEADER[:-1]] + ["us-101"]
            for r in rows
        ]
        return _csv_bytes(list(ns.PORTAL_HEADER), body, quirks=True)
    header = ["v_Length" if name == "v_length" else name for name in ns.PERIOD_CSV_HEADER]
    body = [[_text(r.get(c.lower()), False) for c in header] for r in rows]
    return _csv_bytes(header, body, quirks=False)


# ---- lines and fields of a file ------------------------------------------------------------------


def split_lines(data: bytes) -> tuple[bytes, list[bytes]]:
    """(byte-order mark or b"", physical lines each with its LF; the last may lack one)."""
    bom = b"\xef\xbb\xbf" if data.startswith(b"\xef\xbb\xbf") else b""
    return bom, re.findall(rb"[^\n]*\n|[^\n]+\Z", data[len(bom) :])


def join_lines(bom: bytes, lines: list[bytes], newline: bytes) -> bytes:
    """The file again; a line moved off the end gets `newline`."""
    fixed = [
        line if line.endswith(b"\n") or i == len(lines) - 1 else line + newline
        for i, line in enumerate(lines)
    ]
    return bom + b"".join(fixed)


def _newline(lines: list[bytes]) -> bytes:
    return b"\r\n" if lines and lines[0].endswith(b"\r\n") else b"\n"


def _body(line: bytes) -> bytes:
    """A line without its line end (LF or CRLF)."""
    return line.removesuffix(b"\n").removesuffix(b"\r")


def field_spans(body: bytes, fmt: str) -> list[tuple[int, int]]:
    """(start, end) of each field of a line body: runs of non-space for txt, CSV fields (a
    quoted field with its quotes) otherwise."""
    if fmt == "txt":
        return [m.span() for m in re.finditer(rb"\S+", body)]
    spans, start, quoted = [], 0, False
    for i, byte in enumerate(body):
        if byte == ord('"'):
            quoted = not quoted
        elif byte == ord(",") and not quoted:
            spans.append((start, i))
            start = i + 1
    return [*spans, (start, len(body))]


def replace_spans(line: bytes, spans: list[tuple[int, int]], new: dict[int, bytes]) -> bytes:
    """`line` with field i (a span of its body) replaced by new[i]; the line end is kept."""
    body, out, last = _body(line), [], 0
    for i, (start, end) in enumerate(spans):
        if i in new:
            out += [body[last:start], new[i]]
            last = end
    return b"".join([*out, line[last:]])


def column_names(lines: list[bytes], fmt: str) -> list[str]:
    """Column names as the header spells them (txt: NGSIM's official names)."""
    if fmt == "txt":
        return [OFFICIAL_NAMES[c] for c in ns.TXT_COLUMNS]
    body = _body(lines[0])
    return [body[a:b].decode(errors="replace") for a, b in field_spans(body, fmt)]


def data_line_indices(lines: list[bytes], fmt: str) -> list[int]:
    first = 0 if fmt == "txt" else 1
    return [i for i in range(first, len(lines)) if lines[i].strip()]


def count_data_lines(data: bytes, fmt: str) -> tuple[int, int]:
    """(data lines with a visible character, non-empty data lines) of a file, the CSV header
    excluded, as the reader splits lines: at LF, a CR before it dropped; a gzip'd file's as the
    build reads it, unpacked."""
    if data.startswith(b"\x1f\x8b"):
        data = gzip.decompress(data)
    text = data.decode("utf-8", errors="replace").removeprefix("\ufeff")
    lines = [line.removesuffix("\r") for line in text.split("\n")]
    if fmt != "txt":
        lines = lines[1:]
    return sum(1 for line in lines if line.strip()), sum(1 for line in lines if line)


# ---- mutations: (rng, input bytes, format) -> (output bytes, description) ----------------------


def truncate(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    cut = int(rng.integers(1, len(data)))
    line = data[:cut].count(b"\n") + 1
    return data[:cut], f"truncate to {cut:,} of {len(data):,} bytes (in line {line})"


INTERESTING_BYTES = b'\x00\x1f",\n\r \t\xff.-eE0'


def flip_bytes(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    """Set 1..5 random bytes to other values, half of them ones that mean something to a parser."""
    out = bytearray(data)
    n_flips = min(int(rng.integers(1, 6)), len(data))
    places = sorted(int(p) for p in rng.choice(len(data), size=n_flips, replace=False))
    changes = []
    for place in places:
        new = (
            INTERESTING_BYTES[rng.integers(len(INTERESTING_BYTES))]
            if rng.random() < 0.5
            else int(rng.integers(256))
        )
        new = new if new != out[place] else out[place] ^ 0x40
        line = data[:place].count(b"\n") + 1
        changes.append(f"byte {place:,} (line {line}) {bytes([out[place]])!r}->{bytes([new])!r}")
        out[place] = new
    return bytes(out), "flip " + ", ".join(changes)


def _many_digits(rng: np.random.Generator, old: bytes) -> bytes:
    """A number of 20 to 60 digits, or the old value with a long run of decimals after it."""
    if rng.random() < 0.5:
        return b"1" + bytes(
            rng.integers(ord("0"), ord("9") + 1, size=int(rng.integers(20, 60))).astype(np.uint8)
        )
    quoted = old.startswith(b'"') and old.endswith(b'"') and len(old) > 1
    inner = old[1:-1] if quoted else old
    longer = inner + (b"" if b"." in inner else b".") + b"0" * int(rng.integers(15, 40)) + b"1"
    return b'"' + longer + b'"' if quoted else longer


def replace_field(value: str | None, integer_columns_only: bool = False) -> Mutator:
    """Replace one random field of one random data line with `value` (None: many digits); three
    times in four the field is of one of the 18 columns the reader parses."""

    def mutate(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
        bom, lines = split_lines(data)
        names = column_names(lines, fmt)
        i = int(rng.choice(data_line_indices(lines, fmt)))
        spans = field_spans(_body(lines[i]), fmt)
        fields = range(min(len(spans), len(names)))
        parsed = [j for j in fields if names[j].lower() in ns.TXT_COLUMNS]
        if integer_columns_only:
            usable = [j for j in parsed if names[j].lower() in INTEGER_COLUMNS]
        else:  # mostly a column the reader parses; now and then one it ignores (O_Zone, Location)
            usable = parsed if rng.random() < 0.75 else list(fields)
        j = int(rng.choice(usable))
        old = _body(lines[i])[slice(*spans[j])]
        new = _many_digits(rng, old) if value is None else value.encode()
        lines[i] = replace_spans(lines[i], spans, {j: new})
        what = f"replace field {names[j]} of line {i + 1} ({old.decode()!r}) with {new.decode()!r}"
        return join_lines(bom, lines, _newline(lines)), what

    return mutate


def swap_columns(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    """CSV: swap two header names. Text: swap two columns' values on every line."""
    bom, lines = split_lines(data)
    names = column_names(lines, fmt)
    j, k = sorted(int(c) for c in rng.choice(len(names), size=2, replace=False))
    targets = [0] if fmt != "txt" else range(len(lines))
    for i in targets:
        body = _body(lines[i])
        spans = field_spans(body, fmt)
        if len(spans) > k:
            lines[i] = replace_spans(
                lines[i], spans, {j: body[slice(*spans[k])], k: body[slice(*spans[j])]}
            )
    what = "header names" if fmt != "txt" else "the values of columns"
    return join_lines(bom, lines, _newline(lines)), f"swap {what} {names[j]} and {names[k]}"


def _insert_field(line: bytes, fmt: str, position: int, value: bytes) -> bytes:
    """`line` with `value` as a new field before field `position` (at the end if past it)."""
    body = _body(line)
    spans = field_spans(body, fmt)
    separator = b" " if fmt == "txt" else b","
    if position >= len(spans):
        at, piece = len(body), separator + value
    else:
        at, piece = spans[position][0], value + separator
    return body[:at] + piece + body[at:] + line[len(body) :]


def add_column_everywhere(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    """A new column at a random place: in the header (a new name, or one the file already has)
    and on every line, holding one value throughout."""
    bom, lines = split_lines(data)
    names = column_names(lines, fmt)
    position = int(rng.integers(0, len(names) + 1))
    name = str(rng.choice(["Extra", "Notes", names[int(rng.integers(len(names)))]]))
    value = str(rng.choice(["0", "7", "abc", "1.5"])).encode()
    first = 0 if fmt == "txt" else 1
    if fmt != "txt":
        lines[0] = _insert_field(lines[0], fmt, position, name.encode())
    for i in range(first, len(lines)):
        if lines[i].strip():
            lines[i] = _insert_field(lines[i], fmt, position, value)
    where = f"header name {name!r} and " if fmt != "txt" else ""
    what = f"add a column at {position}: {where}value {value.decode()!r} on every line"
    return join_lines(bom, lines, _newline(lines)), what


def add_field_to_one_line(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    bom, lines = split_lines(data)
    i = int(rng.choice(data_line_indices(lines, fmt)))
    position = int(rng.integers(0, len(field_spans(_body(lines[i]), fmt)) + 1))
    value = str(rng.choice(["0", "", "abc"])).encode()
    lines[i] = _insert_field(lines[i], fmt, position, value)
    what = f"add a field {value.decode()!r} at {position} to line {i + 1} only"
    return join_lines(bom, lines, _newline(lines)), what


NON_UTF8 = (b"\xff\xfe", b"\xff", b"\x80", b"\xc3(", b"\xed\xa0\x80", b"\xfe\xff")


def insert_non_utf8(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    """Bytes that are not UTF-8 inside a field (of the header or a data line) or at a line start."""
    bom, lines = split_lines(data)
    junk = NON_UTF8[int(rng.integers(len(NON_UTF8)))]
    i = 0 if fmt != "txt" and rng.random() < 0.2 else int(rng.choice(data_line_indices(lines, fmt)))
    body = _body(lines[i])
    if rng.random() < 0.25:
        at, where = 0, "at the start"
    else:
        spans = field_spans(body, fmt)
        j = int(rng.integers(len(spans)))
        at = int(rng.integers(spans[j][0], spans[j][1] + 1))
        where = f"in field {j + 1} ({body[slice(*spans[j])].decode()!r})"
    lines[i] = lines[i][:at] + junk + lines[i][at:]
    return join_lines(bom, lines, _newline(lines)), f"insert {junk!r} {where} of line {i + 1}"


def _some_lines(rng: np.random.Generator, lines: list[bytes], fmt: str) -> list[int]:
    """1..5 distinct line indices, the header among them one time in ten (CSV)."""
    pool = data_line_indices(lines, fmt)
    picked = [int(i) for i in rng.choice(pool, size=int(rng.integers(1, 6)), replace=False)]
    if fmt != "txt" and rng.random() < 0.1:
        picked[0] = 0
    return sorted(set(picked))


def delete_lines(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    bom, lines = split_lines(data)
    gone = _some_lines(rng, lines, fmt)
    newline = _newline(lines)
    kept = [line for i, line in enumerate(lines) if i not in gone]
    return join_lines(bom, kept, newline), f"delete lines {', '.join(str(i + 1) for i in gone)}"


def duplicate_lines(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    """Copies of 1..5 lines, each inserted at a random place."""
    bom, lines = split_lines(data)
    newline = _newline(lines)
    copies = [(i, int(rng.integers(1, len(lines) + 1))) for i in _some_lines(rng, lines, fmt)]
    out = list(lines)
    for i, at in sorted(copies, key=lambda c: -c[1]):
        out.insert(at, _body(lines[i]) + newline)
    if out[-1].endswith(b"\n") and not lines[-1].endswith(b"\n"):
        out[-1] = _body(out[-1])  # the file still ends without a line end
    moves = ", ".join(f"line {i + 1} before line {at + 1}" for i, at in copies)
    return join_lines(bom, out, newline), f"duplicate {moves}"


def cr_only(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    return data.replace(b"\r\n", b"\r").replace(b"\n", b"\r"), "line ends CR only"


def _png() -> bytes:
    def chunk(tag: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body))

    header = struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\x00\x00"))
        + chunk(b"IEND", b"")
    )


def other_type(kind: str) -> Mutator:
    """Another kind of file under the input's name: the input itself gzipped, its rows as JSON
    or Parquet, a PNG, an empty file, or random bytes."""

    def mutate(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
        if kind == "png":
            return _png(), "a 1x1 PNG image"
        if kind == "gzip":
            return gzip.compress(data, mtime=0), "the input gzipped (a build reads it unpacked)"
        if kind == "json":
            return json.dumps(base_rows()).encode(), "the rows as one JSON array of objects"
        if kind == "parquet":
            buffer = io.BytesIO()
            pl.DataFrame(base_rows()).rename(OFFICIAL_NAMES, strict=False).write_parquet(buffer)
            return buffer.getvalue(), "the rows as a Parquet file"
        if kind == "empty":
            return b"", "an empty file"
        size = int(rng.integers(1, 5000))
        return rng.bytes(size), f"{size:,} random bytes"

    return mutate


def unchanged(rng: np.random.Generator, data: bytes, fmt: str) -> tuple[bytes, str]:
    return data, "the valid input, unchanged"


# kind -> (family, mutation). Fixed kinds do the same to every seed: one case per format.
MUTATIONS: dict[str, tuple[str, Mutator]] = {
    "none": ("none", unchanged),
    "truncate": ("truncate", truncate),
    "flip_bytes": ("flip", flip_bytes),
    "field_text": ("field", replace_field("abc")),
    "field_NaN": ("field", replace_field("NaN")),
    "field_nan": ("field", replace_field("nan")),
    "field_inf": ("field", replace_field("inf")),
    "field_-inf": ("field", replace_field("-inf")),
    "field_1e308": ("field", replace_field("1e308")),
    "field_-1e308": ("field", replace_field("-1e308")),
    "field_empty": ("field", replace_field("")),
    "field_-5": ("field", replace_field("-5")),
    "field_3.5_in_int": ("field", replace_field("3.5", integer_columns_only=True)),
    "field_many_digits": ("field", replace_field(None)),
    "swap_columns": ("swap", swap_columns),
    "extra_column": ("extra column", add_column_everywhere),
    "extra_field_one_line": ("extra column", add_field_to_one_line),
    "non_utf8": ("non-utf8", insert_non_utf8),
    "delete_lines": ("lines", delete_lines),
    "duplicate_lines": ("lines", duplicate_lines),
    "cr_only": ("cr only", cr_only),
    "png": ("other type", other_type("png")),
    "gzip": ("other type", other_type("gzip")),
    "json": ("other type", other_type("json")),
    "parquet": ("other type", other_type("parquet")),
    "empty": ("other type", other_type("empty")),
    "random_bytes": ("other type", other_type("random")),
}
FIXED_KINDS = ("none", "cr_only", "png", "gzip", "json", "parquet", "empty")
RANDOM_KINDS = tuple(k for k in MUTATIONS if k not in FIXED_KINDS)
DEFAULT_CASES = len(FIXED_KINDS) * len(FORMATS) + 6 * len(RANDOM_KINDS) * len(FORMATS)  # 381


@dataclass(frozen=True)
class Case:
    index: int
    seed: int
    fmt: str
    kind: str


def plan_cases(seed: int, n_cases: int = DEFAULT_CASES) -> list[Case]:
    """The fixed kinds once per format, then rounds of every random kind x format."""
    pairs = [(fmt, kind) for kind in FIXED_KINDS for fmt in FORMATS]
    rounds = itertools.cycle([(fmt, kind) for kind in RANDOM_KINDS for fmt in FORMATS])
    pairs += itertools.islice(rounds, max(0, n_cases - len(pairs)))
    return [Case(i, seed, fmt, kind) for i, (fmt, kind) in enumerate(pairs[:n_cases])]


def make_input(case: Case) -> tuple[bytes, str]:
    """The mutated input of `case` and what was done to it; the same case gives the same bytes."""
    rng = np.random.default_rng([case.seed, case.index])
    return MUTATIONS[case.kind][1](rng, base_input(case.fmt), case.fmt)
