"""Synthetic NGSIM files behind `ngsim-graphs synth`: simulated recordings written in one of the
three raw formats (docs/conventions.md), optionally with the quirks of real exports, or in
highD's (synth.highd), into a folder that lands whole with its marker (synth.folder). The same
config always gives byte-identical files.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import BinaryIO

import numpy as np
import polars as pl

from ngsim_graphs import landing, schema, storage
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.partial_files import create_exclusive
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, PACIFIC_DAYLIGHT, Recording
from ngsim_graphs.synth.folder import (
    check_synth_target,
    marker_text,
    relative_name,
    synthetic_paths,
)
from ngsim_graphs.synth.highd import DECIMALS as HIGHD_DECIMALS
from ngsim_graphs.synth.highd import highd_tables
from ngsim_graphs.synth.marker import MARKER_NAME  # written last into every folder synth fills
from ngsim_graphs.synth.traffic import simulate_recording

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
    names = [relative_name(path, out_dir) for path in paths]
    with landing.output_directory(out_dir, check_synth_target) as folder:
        _write_files([folder / name for name in names], paths, config, report)
        digests = {name: file_sha256(folder / name) for name in names}
        with create_exclusive(folder / MARKER_NAME) as marker:
            marker.write(marker_text(config, digests).encode())
    return paths


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
