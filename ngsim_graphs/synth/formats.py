"""Synthetic NGSIM files behind `ngsim-graphs synth`: simulated recordings written in one of the
three raw formats (SPEC section 1), optionally with the quirks of real exports.

Every file is written under a hidden temporary name in its folder and renamed into place when
complete, so an interrupted run never leaves a complete-looking file. The same config always gives
byte-identical files. A folder synth fills carries `SYNTHETIC.md`, which says the data are
simulated and lists synth's files: synth replaces files only in a new or empty folder or in one of
its own, and only those it listed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import BinaryIO

import numpy as np
import polars as pl

from ngsim_graphs import schema
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.landing import some_names
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, PACIFIC_DAYLIGHT, Recording
from ngsim_graphs.synth.highd import DECIMALS as HIGHD_DECIMALS
from ngsim_graphs.synth.highd import highd_paths, highd_tables
from ngsim_graphs.synth.marker import MARKER_NAME  # written first into every folder synth fills
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

# Header spellings of per-period CSVs in the wild: case and `v_Length` vary.
CSV_HEADER_VARIANTS = {"Vehicle_ID": "vehicle_id", "Local_Y": "LOCAL_Y", "v_length": "v_Length"}
# Decimals and field width of each text-file column, in schema.TXT_COLUMNS order.
TXT_DECIMALS = (0, 0, 0, 0, 3, 3, 3, 3, 1, 1, 0, 2, 2, 0, 0, 0, 2, 2)
TXT_WIDTHS = (6, 7, 7, 16, 10, 11, 14, 14, 7, 7, 4, 9, 9, 4, 7, 7, 10, 10)


def write_synthetic(
    out_dir: Path, config: SynthConfig, on_progress: Callable[[str], None] | None = None
) -> list[Path]:
    """Simulate the first `config.recordings` official recordings and write them under out_dir.

    PORTAL: one combined CSV; CSV and TXT: `<location>/trajectories-<period>.<ext>` per recording;
    HIGHD: `NN_tracks.csv`, `NN_tracksMeta.csv`, `NN_recordingMeta.csv` per recording (`synth.highd`).
    `out_dir` must be new, empty, or synth's own (it carries MARKER_NAME, which lists the files
    synth wrote there): files synth did not write are never replaced, and files of an earlier
    run that this run does not write are removed, so that the folder holds one run's data. On
    failure this run's files are removed again. Calls `on_progress` with a one-line message after
    each recording. Returns the files written.
    """
    report = on_progress or (lambda message: None)
    paths = synthetic_paths(out_dir, config)
    marker = out_dir / MARKER_NAME
    earlier = claim_folder(out_dir, paths)
    created = [p for p in (out_dir, *out_dir.parents) if not p.exists()]
    had_marker = marker.is_file()
    written: list[Path] = []
    try:
        for name in sorted(earlier - {_relative(path, out_dir) for path in paths}):
            _remove_file(out_dir, name)  # listed in the marker: synth's own
        _write_marker(marker, config, paths, complete=False)
        _write_files(paths, config, report, written)
        _write_marker(marker, config, paths, complete=True)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        if not had_marker:  # the folder was new or empty: leave it so
            marker.unlink(missing_ok=True)
            _remove_empty_folders(out_dir, created)
        raise
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


def claim_folder(out_dir: Path, paths: list[Path]) -> set[str]:
    """Refuse a folder whose files synth may not replace; returns the files it wrote there before.

    A new or empty folder is taken; so is one with synth's marker, as long as none of `paths`
    is a file the marker does not list (someone else's, real data perhaps).
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise NgsimOutputError(out_dir, "exists and is not a directory")
    marker = out_dir / MARKER_NAME
    if marker.is_file():
        listed = _listed_files(marker.read_text(errors="replace"))
        foreign = [p for p in paths if p.exists() and _relative(p, out_dir) not in listed]
        if foreign:
            raise NgsimOutputError(
                foreign[0], f"not written by synth (not listed in {marker}); move it away first"
            )
        return listed
    if out_dir.is_dir() and (entries := sorted(p.name for p in out_dir.iterdir())):
        raise NgsimOutputError(
            out_dir,
            f"folder is not empty and not synth's (no {MARKER_NAME}): it holds "
            f"{some_names(entries)}; "
            "synth writes only into a new or empty folder or one it wrote before",
        )
    return set()


def _relative(path: Path, out_dir: Path) -> str:
    return path.relative_to(out_dir).as_posix()


def _marker_text(config: SynthConfig, names: list[str], complete: bool) -> str:
    """What the marker tells a person, and the list of files that makes them synth's."""
    status = "complete" if complete else "INCOMPLETE (being written, or the run failed)"
    quirks = "on" if config.quirks else "off"
    highd = config.raw_format is schema.RawFormat.HIGHD
    return (
        f"# Synthetic data: NOT real {'highD' if highd else 'NGSIM'} trajectories\n\n"
        "The files listed below were written by `ngsim-graphs synth`: simulated traffic in the\n"
        + ("format of the highD files" if highd else "formats of the NGSIM US-101 / I-80 files")
        + ", not measurements. `ngsim-graphs synth` replaces\n"
        "files in this folder only while this file is here, and only the files it lists.\n\n"
        f"Status: {status}.\n"
        f"Settings: format {config.raw_format.value}, {config.recordings} recordings of "
        f"{config.minutes:g} minutes, seed {config.seed}, quirks {quirks}.\n\n"
        "Files:\n\n" + "".join(f"- {name}\n" for name in names)
    )


def _write_marker(marker: Path, config: SynthConfig, paths: list[Path], complete: bool) -> None:
    names = [_relative(path, marker.parent) for path in paths]
    with _atomic_file(marker) as handle:
        handle.write(_marker_text(config, names, complete).encode())


def _listed_files(text: str) -> set[str]:
    """The files a marker lists (its lines `- NAME`) that synth can write: a list edited to name
    anything else makes nothing else synth's."""
    everything = SynthConfig(recordings=len(OFFICIAL_RECORDINGS))
    possible = {
        _relative(path, Path("."))
        for raw_format in schema.RawFormat
        for path in synthetic_paths(Path("."), replace(everything, raw_format=raw_format))
    }
    return {line[2:].strip() for line in text.splitlines() if line.startswith("- ")} & possible


def _remove_file(out_dir: Path, name: str) -> None:
    """Remove a file of an earlier run, and its location folder if that is left empty."""
    path = out_dir / name
    path.unlink(missing_ok=True)
    if path.parent != out_dir and path.parent.is_dir() and not any(path.parent.iterdir()):
        path.parent.rmdir()


def _write_files(
    paths: list[Path], config: SynthConfig, report: Callable[[str], None], written: list[Path]
) -> None:
    """Write the files of `synthetic_paths`, appending each to `written` once it is complete."""
    recordings = OFFICIAL_RECORDINGS[: config.recordings]
    if config.raw_format is schema.RawFormat.PORTAL:
        written.append(_write_portal(paths[0], recordings, config, report))
        return
    if config.raw_format is schema.RawFormat.HIGHD:
        _write_highd(paths, recordings, config, report, written)
        return
    for index, (recording, path) in enumerate(zip(recordings, paths, strict=True)):
        rows = simulated_rows(recording, index, config)
        with _atomic_file(path) as handle:
            if config.raw_format is schema.RawFormat.CSV:
                _write_period_csv(handle, rows, config.quirks)
            else:
                _write_txt(handle, rows, config.quirks)
        written.append(path)
        report(f"{recording.location} {recording.period}: {len(rows):,} rows -> {path}")


def _write_highd(
    paths: list[Path],
    recordings: tuple[Recording, ...],
    config: SynthConfig,
    report: Callable[[str], None],
    written: list[Path],
) -> None:
    """Each recording's three highD files (in `paths` order: tracks, tracksMeta, recordingMeta)."""
    for index, recording in enumerate(recordings):
        rows = simulated_rows(recording, index, config)
        tables = highd_tables(rows, recording, index, config.minutes)
        for table, path in zip(tables.values(), paths[3 * index : 3 * index + 3], strict=True):
            with _atomic_file(path) as handle:
                table.write_csv(handle, float_precision=HIGHD_DECIMALS)
            written.append(path)
        report(f"{recording.location} {recording.period}: {len(rows):,} rows -> {paths[3 * index]}")


def _remove_empty_folders(out_dir: Path, created: list[Path]) -> None:
    """After a failure in a folder that was new or empty: its empty sub-folders, and the
    folders created for it (innermost first)."""
    if out_dir.is_dir():
        for folder in sorted(out_dir.iterdir(), reverse=True):
            if folder.is_dir() and not folder.is_symlink() and not any(folder.iterdir()):
                folder.rmdir()
    for folder in created:
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


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
def _atomic_file(path: Path) -> Iterator[BinaryIO]:
    """A binary file written under a hidden temporary name and renamed to `path` on success."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    try:
        with open(partial, "wb") as handle:
            yield handle
        partial.replace(path)
    except OSError as err:  # a full disk: name the file, not its hidden temporary name
        raise NgsimOutputError(path, f"cannot write: {err.strerror or err}") from None
    finally:
        partial.unlink(missing_ok=True)


def _header_columns(header: tuple[str, ...]) -> list[pl.Expr]:
    """Expressions giving the columns of `header` in order; unknown NGSIM columns stay empty."""
    known = set(schema.RAW_SCHEMA.names()) | {schema.LOCATION}
    return [
        pl.col(name.lower()) if name.lower() in known else pl.lit(None, pl.String).alias(name)
        for name in header
    ]


def _write_period_csv(handle: BinaryIO, rows: pl.DataFrame, quirks: bool) -> None:
    """A per-period CSV; with quirks, header spelling variants and CRLF line ends."""
    header = schema.PERIOD_CSV_HEADER
    if quirks:
        header = tuple(CSV_HEADER_VARIANTS.get(name, name) for name in header)
    end = "\r\n" if quirks else "\n"
    handle.write((",".join(header) + end).encode())
    table = rows.select(_header_columns(schema.PERIOD_CSV_HEADER))
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
        for name, decimals, width in zip(schema.TXT_COLUMNS, TXT_DECIMALS, TXT_WIDTHS, strict=True)
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
        with _atomic_file(path) as handle:
            _write_quirky_portal(handle, recordings, config, report)
        return path
    with _atomic_file(path) as handle:
        handle.write((",".join(schema.PORTAL_HEADER) + "\n").encode())
        for index, recording in enumerate(recordings):
            rows = simulated_rows(recording, index, config)
            table = rows.with_columns(pl.lit(recording.location).alias(schema.LOCATION))
            table.select(_header_columns(schema.PORTAL_HEADER)).write_csv(
                handle, include_header=False
            )
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
            [schema.GLOBAL_Y, "rec", schema.VEHICLE_ID, schema.FRAME_ID], maintain_order=True
        )
    ).to_series()
    handle.write(BOM + (",".join(schema.PORTAL_HEADER) + "\r\n").encode())
    location = pl.col("rec").replace_strict(dict(enumerate(locations)), return_dtype=pl.String)
    for start in range(0, len(order), CHUNK_ROWS):
        chunk = table.select(pl.all().gather(order.slice(start, CHUNK_ROWS)))
        formatted = chunk.select(
            *[_with_thousands(name) for name in schema.RAW_SCHEMA.names()],
            location.alias(schema.LOCATION),
        )
        formatted.select(_header_columns(schema.PORTAL_HEADER)).write_csv(
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
    conflict = conflict.with_columns((pl.col(schema.LOCAL_Y) + shift).round(3))
    empty = pick(EMPTY_LOCAL_X_SHARE).with_columns(pl.lit(None, pl.Float64).alias(schema.LOCAL_X))
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
