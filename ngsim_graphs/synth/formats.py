"""Synthetic NGSIM files behind `ngsim-graphs synth`: simulated recordings written in one of the
three raw formats (docs/conventions.md), optionally with the quirks of real exports.

The folder lands whole (`landing.output_directory`): its files are written into a hidden partial
folder beside it, each created exclusively and never through a link, and the finished folder is
swapped in, so that an interrupted or killed run leaves nothing that looks complete (a killed
run's partial folder is removed by the next run into the same folder). The same config always
gives byte-identical files. A folder synth fills carries `SYNTHETIC.md`, which says the data are
simulated and lists synth's files with their sha256: synth replaces a folder only when it is new
or empty or holds exactly the files its marker lists, as synth wrote them.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import BinaryIO

import numpy as np
import polars as pl

from ngsim_graphs import landing, schema, storage
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.landing import entries_beyond, some_names
from ngsim_graphs.partial_files import create_exclusive
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, PACIFIC_DAYLIGHT, Recording
from ngsim_graphs.synth.highd import DECIMALS as HIGHD_DECIMALS
from ngsim_graphs.synth.highd import highd_paths, highd_tables
from ngsim_graphs.synth.marker import MARKER_NAME  # written last into every folder synth fills
from ngsim_graphs.synth.traffic import simulate_recording

PORTAL_FILE_NAME = "Next_Generation_Simulation__NGSIM__Vehicle_Trajectories_and_Supporting_Data.csv"
BOM = b"\xef\xbb\xbf"
# Rows of another location that a portal export carries and the default build must drop.
FOREIGN_RECORDING = Recording(
    "lankershim",
    "0828am-0845am",
    int(datetime(2005, 6, 16, 8, 28, tzinfo=PACIFIC_DAYLIGHT).timestamp() * 1000),
)
FOREIGN_MINUTES = 0.25  # a few thousand rows

GAP_VEHICLE_SHARE = 0.01  # vehicles whose record loses a run of frames
GAP_FRAMES = (3, 20)  # length of the lost run, inclusive
EXACT_DUPLICATE_SHARE = 0.001
CONFLICT_SHARE = 0.0005  # second rows with a larger Local_Y (the reader keeps the smallest)
EMPTY_LOCAL_X_SHARE = 0.0001
CHUNK_ROWS = 500_000  # rows formatted at a time when writing text
# Each official recording's period, which names its files whatever --minutes is (below).
OFFICIAL_PERIOD_MINUTES = 15.0
_DIGEST_LINE = re.compile(r"    ([0-9a-f]{64})  (\S+)")  # a marker's sha256 of one file

# Header spellings of per-period CSVs in the wild: case and `v_Length` vary.
CSV_HEADER_VARIANTS = {"Vehicle_ID": "vehicle_id", "Local_Y": "LOCAL_Y", "v_length": "v_Length"}
# Decimals and field width of each text-file column, in ns.TXT_COLUMNS order.
TXT_DECIMALS = (0, 0, 0, 0, 3, 3, 3, 3, 1, 1, 0, 2, 2, 0, 0, 0, 2, 2)
TXT_WIDTHS = (6, 7, 7, 16, 10, 11, 14, 14, 7, 7, 4, 9, 9, 4, 7, 7, 10, 10)


def write_synthetic(
    out_dir: Path, config: SynthConfig, on_progress: Callable[[str], None] | None = None
) -> list[Path]:
    """Simulate the first `config.recordings` official recordings and write them under out_dir.

    PORTAL: one combined CSV; CSV and TXT: `<location>/trajectories-<period>.<ext>` per recording;
    HIGHD: `NN_tracks.csv`, `NN_tracksMeta.csv`, `NN_recordingMeta.csv` per recording (`synth.highd`).
    `out_dir` must be new, empty, or synth's own (`check_synth_target`): it is then replaced as a
    whole once every file is written, and left as it was on failure or interrupt. Calls
    `on_progress` with a one-line message after each recording. Returns the files written.
    """
    report = on_progress or (lambda message: None)
    paths = synthetic_paths(out_dir, config)
    names = [_relative(path, out_dir) for path in paths]
    with landing.output_directory(out_dir, check_synth_target) as folder:
        _write_files([folder / name for name in names], paths, config, report)
        digests = {name: file_sha256(folder / name) for name in names}
        with create_exclusive(folder / MARKER_NAME) as marker:
            marker.write(_marker_text(config, digests).encode())
    return paths


def synthetic_paths(out_dir: Path, config: SynthConfig) -> list[Path]:
    """The files that `write_synthetic` writes for `config`, in order."""
    if config.raw_format is schema.RawFormat.PORTAL:
        return [out_dir / PORTAL_FILE_NAME]
    if config.raw_format is schema.RawFormat.HIGHD:
        return highd_paths(out_dir, config.recordings)
    return [
        out_dir / recording.location / f"trajectories-{recording.period}.{config.raw_format.value}"
        for recording in OFFICIAL_RECORDINGS[: config.recordings]
    ]


def period_note(config: SynthConfig) -> str | None:
    """What to tell a user whose recordings are not the official periods' 15 minutes (None where
    they are, or for highD's files): each one starts at its period's official start and keeps
    that period's name. A build tells an NGSIM recording by its frame 0's time, which names the
    period whose start is nearest (`sources.ngsim.recordings`), so a file named by its own
    length would be reported by the build under another name than its own."""
    if config.minutes == OFFICIAL_PERIOD_MINUTES or config.raw_format is schema.RawFormat.HIGHD:
        return None
    per_period = config.raw_format is not schema.RawFormat.PORTAL
    named = "its file's name and a build's report" if per_period else "a build's report"
    return (
        f"each recording runs {config.minutes:g} minutes from the start of its official period "
        f"and is named after that 15-minute period (e.g. 0400-0415) in {named}: a build tells "
        "a recording by its start time"
    )


def check_synth_target(out_dir: Path) -> None:
    """Refuse a folder that synth may not replace: one that is neither new nor empty nor exactly
    an earlier run's files as synth wrote them (`earlier_synth_files`)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise NgsimOutputError(out_dir, "exists and is not a directory")
    if not out_dir.is_dir() or not any(out_dir.iterdir()):
        return
    marker = out_dir / MARKER_NAME
    listed = earlier_synth_files(out_dir)
    if listed is None and not os.path.lexists(marker):
        entries = sorted(p.name for p in out_dir.iterdir())
        raise NgsimOutputError(
            out_dir,
            f"folder is not empty and not synth's (no {MARKER_NAME}): it holds "
            f"{some_names(entries)}; "
            "synth writes only into a new or empty folder or one it wrote before",
        )
    if listed is None:
        raise NgsimOutputError(
            marker,
            "is not a marker that synth wrote (or was edited since: it lists no file with its "
            "sha256): the folder is not replaced; move it away or choose another folder",
        )
    beyond = entries_beyond(out_dir, {MARKER_NAME, *listed})
    changed = [
        name
        for name, digest in listed.items()
        if os.path.lexists(out_dir / name) and _digest(out_dir / name) != digest
    ]
    if beyond or changed:
        raise NgsimOutputError(
            out_dir / (beyond + changed)[0],
            f"not written by synth (not listed in {marker}, or changed since); move it away "
            "first: synth replaces only a folder of its own files",
        )


def _digest(path: Path) -> str | None:
    return file_sha256(path) if path.is_file() and not path.is_symlink() else None


def earlier_synth_files(out_dir: Path) -> dict[str, str] | None:
    """The files an earlier run of synth wrote into `out_dir` (relative name -> sha256), as its
    marker lists them; None where `out_dir` holds no marker of synth's (a link, or a file
    listing no file with its sha256)."""
    marker = out_dir / MARKER_NAME
    if marker.is_symlink() or not marker.is_file():
        return None
    try:
        text = marker.read_text(errors="replace")
    except OSError:
        return None
    digests = _listed_digests(text)
    return digests if digests and set(digests) == _listed_files(text) else None


def _relative(path: Path, out_dir: Path) -> str:
    return path.relative_to(out_dir).as_posix()


def _marker_text(config: SynthConfig, digests: dict[str, str]) -> str:
    """What the marker tells a person, and the list of files (with their sha256) that makes
    them synth's."""
    quirks = "on" if config.quirks else "off"
    highd = config.raw_format is schema.RawFormat.HIGHD
    return (
        f"# Synthetic data: NOT real {'highD' if highd else 'NGSIM'} trajectories\n\n"
        "The files listed below were written by `ngsim-graphs synth`: simulated traffic in the\n"
        + ("format of the highD files" if highd else "formats of the NGSIM US-101 / I-80 files")
        + ", not measurements. `ngsim-graphs synth` replaces\n"
        "this folder only while it holds these files and nothing else, each with its sha256 below.\n\n"
        f"Settings: format {config.raw_format.value}, {config.recordings} recordings of "
        f"{config.minutes:g} minutes, seed {config.seed}, quirks {quirks}.\n\n"
        + (f"{note[0].upper()}{note[1:]}.\n\n" if (note := period_note(config)) else "")
        + "Files:\n\n"
        + "".join(f"- {name}\n" for name in digests)
        + "\nsha256 (`sha256sum -c` reads these lines):\n\n"
        + "".join(f"    {digest}  {name}\n" for name, digest in digests.items())
    )


def _possible_names() -> set[str]:
    """Every file name that synth can write (relative to its folder)."""
    everything = SynthConfig(recordings=len(OFFICIAL_RECORDINGS))
    return {
        _relative(path, Path("."))
        for raw_format in schema.RawFormat
        for path in synthetic_paths(Path("."), replace(everything, raw_format=raw_format))
    }


def _listed_files(text: str) -> set[str]:
    """The files a marker lists (its lines `- NAME`) that synth can write: a list edited to name
    anything else makes nothing else synth's."""
    return {line[2:].strip() for line in text.splitlines() if line.startswith("- ")} & (
        _possible_names()
    )


def _listed_digests(text: str) -> dict[str, str]:
    """The sha256 a marker records of each file synth can write (its lines `    HEX  NAME`)."""
    found = (_DIGEST_LINE.fullmatch(line) for line in text.splitlines())
    possible = _possible_names()
    return {m.group(2): m.group(1) for m in found if m and m.group(2) in possible}


def _write_files(
    targets: list[Path], paths: list[Path], config: SynthConfig, report: Callable[[str], None]
) -> None:
    """Write the files of `synthetic_paths` as `targets` (in the partial folder); `paths`, where
    they land, are what the progress messages name."""
    recordings = OFFICIAL_RECORDINGS[: config.recordings]
    if config.raw_format is schema.RawFormat.PORTAL:
        _write_portal(targets[0], recordings, config, report)
        return
    if config.raw_format is schema.RawFormat.HIGHD:
        _write_highd(targets, paths, recordings, config, report)
        return
    for index, (recording, target, path) in enumerate(zip(recordings, targets, paths, strict=True)):
        rows = simulated_rows(recording, index, config)
        with _new_file(target) as handle:
            if config.raw_format is schema.RawFormat.CSV:
                _write_period_csv(handle, rows, config.quirks)
            else:
                _write_txt(handle, rows, config.quirks)
        report(f"{recording.location} {recording.period}: {len(rows):,} rows -> {path}")


def _write_highd(
    targets: list[Path],
    paths: list[Path],
    recordings: tuple[Recording, ...],
    config: SynthConfig,
    report: Callable[[str], None],
) -> None:
    """Each recording's three highD files (in `targets` order: tracks, tracksMeta,
    recordingMeta)."""
    for index, recording in enumerate(recordings):
        rows = simulated_rows(recording, index, config)
        tables = highd_tables(rows, recording, index, config.minutes)
        for table, target in zip(tables.values(), targets[3 * index : 3 * index + 3], strict=True):
            with _new_file(target) as handle:
                table.write_csv(handle, float_precision=HIGHD_DECIMALS)
        report(f"{recording.location} {recording.period}: {len(rows):,} rows -> {paths[3 * index]}")


def simulated_rows(recording: Recording, index: int, config: SynthConfig) -> pl.DataFrame:
    """The raw rows of one recording as every format carries them: with quirks, frame gaps."""
    rows = simulate_recording(recording, config.minutes, config.seed)
    if config.quirks:
        rows = drop_frame_runs(rows, np.random.default_rng([config.seed, index, 1]))
    return rows


def drop_frame_runs(rows: pl.DataFrame, rng: np.random.Generator) -> pl.DataFrame:
    """Remove a run of 3-20 consecutive frames from the middle of ~1% of the vehicles' records.

    Total_Frames keeps the original count, as in NGSIM. At least one vehicle gets a gap when any
    record is long enough (50 frames).
    """
    spans = (
        rows.group_by(schema.VEHICLE_ID)
        .agg(pl.col(schema.FRAME_ID).min().alias("first"), pl.len().alias("n"))
        .filter(pl.col("n") >= 50)
        .sort(schema.VEHICLE_ID)
    )
    if spans.is_empty():
        return rows
    chosen = rng.random(len(spans)) < GAP_VEHICLE_SHARE
    if not chosen.any():
        chosen[rng.integers(len(spans))] = True
    spans = spans.filter(pl.Series(chosen))
    run = rng.integers(GAP_FRAMES[0], GAP_FRAMES[1] + 1, len(spans))
    start = spans["first"].to_numpy() + rng.integers(10, spans["n"].to_numpy() - run - 10 + 1)
    gaps = pl.DataFrame(
        {schema.VEHICLE_ID: spans[schema.VEHICLE_ID], "gap_start": start, "gap_end": start + run}
    )
    frame = pl.col(schema.FRAME_ID)
    in_gap = (frame >= pl.col("gap_start")) & (frame < pl.col("gap_end"))
    return (
        rows.join(gaps, on=schema.VEHICLE_ID, how="left", maintain_order="left")
        .filter(~in_gap.fill_null(False))
        .drop("gap_start", "gap_end")
    )


@contextmanager
def _new_file(path: Path) -> Iterator[BinaryIO]:
    """A new file of the partial folder, its folder made: created exclusively, never through a
    link; a failed write (a full disk, which polars does not name) names it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with storage.writing(path), create_exclusive(path) as handle:
        yield handle


def _header_columns(header: tuple[str, ...]) -> list[pl.Expr]:
    """Expressions giving the columns of `header` in order; unknown NGSIM columns stay empty."""
    known = set(ns.RAW_SCHEMA.names()) | {schema.LOCATION}
    return [
        pl.col(name.lower()) if name.lower() in known else pl.lit(None, pl.String).alias(name)
        for name in header
    ]


def _write_period_csv(handle: BinaryIO, rows: pl.DataFrame, quirks: bool) -> None:
    """A per-period CSV; with quirks, header spelling variants and CRLF line ends."""
    header = ns.PERIOD_CSV_HEADER
    if quirks:
        header = tuple(CSV_HEADER_VARIANTS.get(name, name) for name in header)
    end = "\r\n" if quirks else "\n"
    handle.write((",".join(header) + end).encode())
    table = rows.select(_header_columns(ns.PERIOD_CSV_HEADER))
    table.write_csv(handle, include_header=False, line_terminator=end)


def _fixed(name: str, decimals: int) -> pl.Expr:
    """A numeric column as text with exactly `decimals` decimals (values already rounded)."""
    value = pl.col(name)
    if decimals == 0:
        return value.cast(pl.Int64).cast(pl.String)
    scaled = (value.abs() * 10**decimals).round(0).cast(pl.Int64)
    digits = scaled.cast(pl.String).str.zfill(decimals + 1)
    sign = pl.when((value < 0) & (scaled > 0)).then(pl.lit("-")).otherwise(pl.lit(""))
    return pl.concat_str([sign, digits.str.head(-decimals), pl.lit("."), digits.str.tail(decimals)])


def _write_txt(handle: BinaryIO, rows: pl.DataFrame, quirks: bool) -> None:
    """Fixed-width, space-padded lines with leading and trailing spaces, like the original files."""
    fields = [
        _fixed(name, decimals).str.pad_start(width)
        for name, decimals, width in zip(ns.TXT_COLUMNS, TXT_DECIMALS, TXT_WIDTHS, strict=True)
    ]
    for start in range(0, len(rows), CHUNK_ROWS):  # bounded memory: lines are wide strings
        lines = rows.slice(start, CHUNK_ROWS).select(pl.concat_str([*fields, pl.lit("  ")]))
        lines.write_csv(handle, include_header=False, quote_style="never")
    if quirks and len(rows):
        handle.seek(-1, 2)  # real files may end without a newline
        handle.truncate()


def _write_portal(
    path: Path,
    recordings: tuple[Recording, ...],
    config: SynthConfig,
    report: Callable[[str], None],
) -> Path:
    """The combined portal CSV: plain and streamed per recording, or with every export quirk."""
    if config.quirks:
        with _new_file(path) as handle:
            _write_quirky_portal(handle, recordings, config, report)
        return path
    with _new_file(path) as handle:
        handle.write((",".join(ns.PORTAL_HEADER) + "\n").encode())
        for index, recording in enumerate(recordings):
            rows = simulated_rows(recording, index, config)
            table = rows.with_columns(pl.lit(recording.location).alias(schema.LOCATION))
            table.select(_header_columns(ns.PORTAL_HEADER)).write_csv(handle, include_header=False)
            report(f"{recording.location} {recording.period}: {len(rows):,} rows")
    return path


def _write_quirky_portal(
    handle: BinaryIO,
    recordings: tuple[Recording, ...],
    config: SynthConfig,
    report: Callable[[str], None],
) -> None:
    """All recordings plus duplicates, conflicts, empty fields and a foreign location, sorted by
    Global_Y (which interleaves periods), with a BOM, CRLF and quoted thousands separators."""
    locations = [recording.location for recording in recordings] + [FOREIGN_RECORDING.location]
    parts = []
    for index, recording in enumerate(recordings):
        rows = simulated_rows(recording, index, config)
        extra = _duplicate_rows(rows, np.random.default_rng([config.seed, index, 2]))
        parts.append(pl.concat([rows, extra]).with_columns(pl.lit(index, pl.UInt8).alias("rec")))
        report(f"{recording.location} {recording.period}: {len(rows):,} rows")
    foreign = simulate_recording(FOREIGN_RECORDING, FOREIGN_MINUTES, config.seed)
    parts.append(foreign.with_columns(pl.lit(len(recordings), pl.UInt8).alias("rec")))
    table = pl.concat(parts, rechunk=False)  # a rechunk would briefly hold every row twice
    del parts
    order = table.select(
        pl.arg_sort_by(
            [ns.GLOBAL_Y, "rec", schema.VEHICLE_ID, schema.FRAME_ID], maintain_order=True
        )
    ).to_series()
    handle.write(BOM + (",".join(ns.PORTAL_HEADER) + "\r\n").encode())
    location = pl.col("rec").replace_strict(dict(enumerate(locations)), return_dtype=pl.String)
    for start in range(0, len(order), CHUNK_ROWS):
        chunk = table.select(pl.all().gather(order.slice(start, CHUNK_ROWS)))
        formatted = chunk.select(
            *[_with_thousands(name) for name in ns.RAW_SCHEMA.names()],
            location.alias(schema.LOCATION),
        )
        formatted.select(_header_columns(ns.PORTAL_HEADER)).write_csv(
            handle, include_header=False, quote_style="never", line_terminator="\r\n"
        )


def _duplicate_rows(rows: pl.DataFrame, rng: np.random.Generator) -> pl.DataFrame:
    """Extra rows of one recording: exact copies, copies with a larger Local_Y, copies without
    Local_X. Shares of the recording's rows, at least one of each kind."""

    def pick(share: float) -> pl.DataFrame:
        count = min(len(rows), max(1, round(share * len(rows))))
        return rows[np.sort(rng.choice(len(rows), count, replace=False))]

    exact = pick(EXACT_DUPLICATE_SHARE)
    conflict = pick(CONFLICT_SHARE)
    shift = rng.uniform(0.5, 3.0, len(conflict))
    conflict = conflict.with_columns((pl.col(ns.LOCAL_Y) + shift).round(3))
    empty = pick(EMPTY_LOCAL_X_SHARE).with_columns(pl.lit(None, pl.Float64).alias(ns.LOCAL_X))
    return pl.concat([exact, conflict, empty])


def _with_thousands(name: str) -> pl.Expr:
    """A numeric column as text, values of 1000 and more as `"1,234.5"` (quoted, separated)."""
    value = pl.col(name)
    text = value.abs().cast(pl.String)
    dot = text.str.find(".", literal=True).fill_null(text.str.len_chars())
    grouped = (
        text.str.head(dot)
        .str.reverse()
        .str.replace_all(r"(\d{3})", "$1,")
        .str.strip_chars_end(",")
        .str.reverse()
    )
    sign = pl.when(value < 0).then(pl.lit("-")).otherwise(pl.lit(""))
    quoted = pl.concat_str([pl.lit('"'), sign, grouped, text.str.slice(dot), pl.lit('"')])
    return pl.when(value.abs() >= 1000).then(quoted).otherwise(value.cast(pl.String)).alias(name)
