"""Where a build task stages what it makes for a later one, inside the build's `_staging` folder
(`layout.STAGING_DIR`), removed before the build lands: parsed raw rows by part, the cleaned
tracks of a part, the evidence of a recording's checks, a recording's samples.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs.layout import STAGING_DIR, recording_name
from ngsim_graphs.storage import TableAppender, writing

# The raw rows and cleaned tracks a build stages for itself, a batch at a time: Arrow IPC,
# uncompressed (`storage.TableAppender`), read back at memory speed.
STAGED_ROWS_SUFFIX = "arrow"


def staged_raw_path(root: Path, location: str, period: str, part: int, file_index: int) -> Path:
    """Parsed raw rows of one part of a recording's vehicles from one input file, kept only
    while building."""
    name = f"raw-{part:05d}-{file_index:04d}.{STAGED_ROWS_SUFFIX}"
    return root / STAGING_DIR / recording_name(location, period) / name


def staged_unpacked_dir(root: Path) -> Path:
    """The folder the inputs' archives are unpacked into (`sources.archives`), kept until the
    build lands."""
    return root / STAGING_DIR / "_unpacked"


def staged_scratch_dir(root: Path, file_index: int) -> Path:
    """A folder for what a source writes while reading one input file (its parsed rows), kept
    only until the file's rows are staged."""
    return root / STAGING_DIR / f"_read-{file_index:04d}"


def staged_tracks_path(root: Path, location: str, period: str, part: int) -> Path:
    """The tracks of one part of a recording's vehicles, numbered from 0 in the recording,
    kept only while building."""
    name = f"tracks-{part:05d}.{STAGED_ROWS_SUFFIX}"
    return root / STAGING_DIR / recording_name(location, period) / name


def staged_evidence_path(root: Path, location: str, period: str, part: int, group: int) -> Path:
    """What the source's recording checks need of one group of vehicles of a part of a
    recording (`sources.contract.TracksPart.evidence`), kept only while building."""
    name = f"evidence-{part:05d}-{group:04d}.parquet"
    return root / STAGING_DIR / recording_name(location, period) / name


def staged_windows_path(root: Path, location: str, period: str) -> Path:
    """The samples (ego windows, split and counts) of one recording, kept only while building:
    the samples tables are streamed from them."""
    return root / STAGING_DIR / recording_name(location, period) / "windows.parquet"


def write_staged(frame: pl.DataFrame, path: Path) -> None:
    """Write an intermediate table that lives only while building: fast, lightly compressed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with writing(path):
        frame.write_parquet(path, compression="lz4", statistics=False)


def rows_appender(path: Path, schema: pl.Schema) -> TableAppender:
    """A staged table of raw rows or tracks written a batch at a time (STAGED_ROWS_SUFFIX)."""
    return TableAppender(path, schema)


def scan_rows(paths: Path | list[Path]) -> pl.LazyFrame:
    """Staged raw rows or tracks (`rows_appender`), scanned."""
    return pl.scan_ipc(paths)
