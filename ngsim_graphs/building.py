"""`ngsim-graphs build`: raw NGSIM files to a finished, self-describing output directory.

Memory stays bounded by one input file plus one recording: each file's rows are staged per
recording as Parquet, then each recording is cleaned and written on its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import polars as pl

from ngsim_graphs import __version__, layout
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.ingestion import (
    FileReport,
    RecordingKey,
    RecordingReport,
    build_tracks,
    read_file_recordings,
    recording_rows,
)
from ngsim_graphs.reading import find_raw_files

# (what is being done, steps done, steps in all): the CLI draws it as a progress bar.
ProgressCallback = Callable[[str, int, int], None]


@dataclass(frozen=True)
class BuildResult:
    """What a finished build holds; the same facts as its manifest."""

    out_dir: Path
    files: tuple[FileReport, ...]
    skipped_files: tuple[str, ...]
    recordings: tuple[RecordingReport, ...]
    manifest: dict[str, Any]


def _stage_inputs(
    files: list[Path], config: BuildConfig, root: Path, progress: ProgressCallback
) -> tuple[list[FileReport], dict[RecordingKey, list[Path]]]:
    """Read each file and stage its rows per recording, one recording in memory at a time."""
    reports: list[FileReport] = []
    staged: dict[RecordingKey, list[Path]] = {}
    for file_index, path in enumerate(files):
        progress(f"reading {path.name}", file_index, len(files))
        rows, chosen, report = read_file_recordings(path, config)
        for key, recording_index in sorted(chosen.items()):
            target = layout.staged_raw_path(root, *key, file_index)
            layout.write_staged(recording_rows(rows, recording_index), target)
            staged.setdefault(key, []).append(target)
        del rows
        reports.append(report)
    progress("reading done", len(files), len(files))
    if not staged:
        found = sorted({loc for r in reports for loc in r.locations_found})
        raise NgsimInputError(
            None,
            f"no rows of the chosen locations ({', '.join(config.locations)}) in any input; "
            f"found: {', '.join(found) or 'none'}",
        )
    return reports, staged


def _build_recordings(
    staged: dict[RecordingKey, list[Path]], config: BuildConfig, root: Path, progress: ProgressCallback
) -> list[RecordingReport]:
    """Clean each recording on its own and write its tracks table."""
    reports: list[RecordingReport] = []
    next_track_id = 0
    keys = sorted(staged)
    for index, key in enumerate(keys):
        progress(f"tracks {layout.recording_name(*key)}", index, len(keys))
        tracks, report = build_tracks(pl.read_parquet(staged[key]), key, config, next_track_id)
        layout.write_parquet(tracks, layout.tracks_path(root, *key))
        next_track_id += report.tracks
        reports.append(report)
    progress("tracks done", len(keys), len(keys))
    return reports


def _manifest(
    config: BuildConfig, files: list[FileReport], recordings: list[RecordingReport]
) -> dict[str, Any]:
    config_dict = config.to_dict()
    totals = {
        key: sum(getattr(r, key) for r in recordings)
        for key in ("rows", "exact_duplicates", "conflicting_duplicates", "gaps", "tracks", "grid_rows")
    }
    return {
        "format_version": layout.FORMAT_VERSION,
        "stage": "tracks",
        "software": {"ngsim_graphs": __version__, "polars": pl.__version__},
        "config": config_dict,
        "config_hash": layout.config_hash(config_dict),
        "inputs": [asdict(f) for f in files],
        "recordings": [
            {**asdict(r), "tracks_file": str(layout.tracks_path(Path("."), r.location, r.period))}
            for r in recordings
        ],
        "counts": {
            "rows_read": sum(f.rows_read for f in files),
            "rows_other_locations": sum(f.rows_other_locations for f in files),
            "rows_missing_values": sum(f.rows_missing_values for f in files),
            **totals,
        },
    }


def run_build(
    raw_paths: list[Path],
    out_dir: Path,
    config: BuildConfig,
    overwrite: bool = False,
    progress: ProgressCallback | None = None,
) -> BuildResult:
    """Read every NGSIM file under `raw_paths` and write the finished build into `out_dir`.

    Raises NgsimInputError for unusable input; `out_dir` is then left as it was.
    """
    report_progress = progress or (lambda _what, _done, _total: None)
    files, skipped = find_raw_files(raw_paths)
    with layout.build_directory(out_dir, overwrite) as root:
        file_reports, staged = _stage_inputs(files, config, root, report_progress)
        recording_reports = _build_recordings(staged, config, root, report_progress)
        manifest = _manifest(config, file_reports, recording_reports)
        layout.write_manifest(root, manifest)
    return BuildResult(
        out_dir=out_dir,
        files=tuple(file_reports),
        skipped_files=tuple(str(p) for p in skipped),
        recordings=tuple(recording_reports),
        manifest=manifest,
    )
