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
from ngsim_graphs.ingestion import FileReport, RecordingKey, RecordingReport, build_tracks, read_file_recordings
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
    reports: list[FileReport] = []
    staged: dict[RecordingKey, list[Path]] = {}
    for index, path in enumerate(files):
        progress(f"reading {path.name}", index, len(files))
        by_key, report = read_file_recordings(path, config)
        for (location, period), frame in by_key.items():
            target = layout.staged_raw_path(root, location, period, index)
            layout.write_parquet(frame, target)
            staged.setdefault((location, period), []).append(target)
        reports.append(report)
    progress("reading done", len(files), len(files))
    return reports, staged


def _build_recordings(
    staged: dict[RecordingKey, list[Path]], config: BuildConfig, root: Path, progress: ProgressCallback
) -> list[RecordingReport]:
    reports: list[RecordingReport] = []
    next_track_id = 0
    keys = sorted(staged)
    for index, (location, period) in enumerate(keys):
        progress(f"tracks {layout.recording_name(location, period)}", index, len(keys))
        raw = pl.read_parquet(staged[(location, period)])
        tracks, report = build_tracks(raw, config, next_track_id)
        del raw
        layout.write_parquet(tracks, layout.tracks_path(root, location, period))
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
