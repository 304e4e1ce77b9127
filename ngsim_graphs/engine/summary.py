"""What a build's recordings add up to: its manifest (counts, the recordings' entries), its
warnings, and why a build has no samples (`pipeline` writes them; pure functions of the
recordings' outputs and the input files' reports)."""

from __future__ import annotations

import dataclasses
from functools import reduce
from pathlib import Path

import polars as pl

from ngsim_graphs import layout
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine.tasks import RecordingOutput
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.manifest import BuildCounts, Manifest, RecordingEntry, ScriptRows, SourceLine
from ngsim_graphs.protocols import PROTOCOLS
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.contract import FileReport
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.splits import split_warnings
from ngsim_graphs.version import __version__


def _why_no_samples(
    outputs: list[RecordingOutput], config: BuildConfig, frames_per_step: int
) -> str:
    """Why the chosen recordings gave no sample at all, as a user can act on it
    (`frames_per_step`: the source's frames per grid step)."""
    rows = sum(o.report.rows for o in outputs)
    why = PROTOCOLS[config.protocol].why_no_samples(_script_total(outputs), rows, config)
    if why is not None:
        return why
    if sum(o.report.grid_rows for o in outputs) == 0:
        return (
            f"none of the {rows:,} rows kept lies on the {config.time_step_s} s grid, which keeps "
            f"the frames whose Frame_ID is a multiple of {frames_per_step} (are they all odd?)"
        )
    longest = max(o.longest_track_steps for o in outputs)
    if longest < config.window_steps:
        return (
            f"no track spans a whole window of {config.window_steps} grid steps "
            f"({config.window_steps * config.time_step_s:g} s of history and future); the longest "
            f"has {longest} steps"
        )
    return f"every window falls in a gap between the blocks of the {config.split.value} split"


def check_some_samples(
    outputs: list[RecordingOutput], config: BuildConfig, raw_paths: list[Path], frames_per_step: int
) -> None:
    if sum(sum(o.samples.values()) for o in outputs) == 0:
        more = f" (and {len(raw_paths) - 1} more)" if len(raw_paths) > 1 else ""
        raise NgsimInputError(
            f"{raw_paths[0]}{more}",
            f"no samples: {_why_no_samples(outputs, config, frames_per_step)}",
        )


def warnings(
    outputs: list[RecordingOutput], config: BuildConfig, files: list[FileReport]
) -> list[str]:
    """What the reading said of its files' recordings, then of the splits."""
    samples = {f"{o.report.location}/{o.report.period}": o.samples for o in outputs}
    ids = {f"{o.report.location}/{o.report.period}": o.vehicle_ids for o in outputs}
    notes = [f"{file.path}: {note}" for file in files for note in file.notes]
    return notes + split_warnings(samples, ids, config)


def _recording_entry(
    o: RecordingOutput, samples: dict[str, dict[str, int]], files: list[FileReport]
) -> RecordingEntry:
    """The manifest's entry of one recording; its first outlier by input path, not index."""
    name = layout.recording_name(o.report.location, o.report.period)
    first = o.report.first_outlier
    return RecordingEntry(
        report=dataclasses.replace(o.report, first_outlier=None),
        index=o.index,
        name=name,
        first_track_id=o.first_track_id,
        n_steps=o.n_steps,
        proximity_edges=o.proximity_edges,
        samples={split: samples[split].get(name, 0) for split in samples},
        first_outlier=None if first is None else SourceLine(files[first[0]].path, first[1]),
        cslstm_rows=o.script_rows,
    )


def _script_total(outputs: list[RecordingOutput]) -> ScriptRows | None:
    """The cs-lstm protocol's rows over the recordings (None: the aigem protocol)."""
    parts = [o.script_rows for o in outputs if o.script_rows is not None]
    return reduce(ScriptRows.plus, parts) if parts else None


def _counts(
    files: list[FileReport], outputs: list[RecordingOutput], samples: dict[str, dict[str, int]]
) -> BuildCounts:
    """The build's totals over its input files and recordings."""

    def total(key: str) -> int:
        return sum(getattr(o.report, key) for o in outputs)

    # The shared reasons, then those of the source's own that its files' reports count.
    reasons = dict.fromkeys(
        [*(r.value for r in DropReason), *(r for f in files for r in f.rows_dropped)]
    )
    dropped = {reason: sum(f.rows_dropped.get(reason, 0) for f in files) for reason in reasons}
    dropped[DropReason.POSITION_OUTLIER.value] = total("position_outliers")
    return BuildCounts(
        rows_read=sum(f.rows_read for f in files),
        rows_other_locations=sum(f.rows_other_locations for f in files),
        rows_missing_values=sum(f.rows_missing_values for f in files),
        rows_dropped=dropped,
        rows=total("rows"),
        exact_duplicates=total("exact_duplicates"),
        conflicting_duplicates=total("conflicting_duplicates"),
        position_jumps=total("position_jumps"),
        gaps=total("gaps"),
        tracks=total("tracks"),
        grid_rows=total("grid_rows"),
        proximity_edges=sum(o.proximity_edges for o in outputs),
        samples=sum(sum(per.values()) for per in samples.values()),
        cslstm_rows=_script_total(outputs),
    )


def manifest(
    dataset: str,
    config: BuildConfig,
    limits: PhysicalLimits,
    files: list[FileReport],
    outputs: list[RecordingOutput],
    samples: dict[str, dict[str, int]],
    scaler: MinMaxScaler,
    warnings: list[str],
    skipped: list[str],
) -> Manifest:
    """What the build is, to be written last (`layout.write_manifest` adds the file records):
    `limits`, those its source applied, recorded beside the config and in its hash."""
    return Manifest(
        format_version=layout.FORMAT_VERSION,
        software={"ngsim_graphs": __version__, "polars": pl.__version__},
        dataset=dataset,
        config=config,
        config_hash=layout.config_hash(config.to_dict(), limits.to_dict()),
        limits=limits,
        inputs=tuple(files),
        recordings=tuple(_recording_entry(o, samples, files) for o in outputs),
        splits={split: sum(per.values()) for split, per in samples.items()},
        scaler=scaler,
        warnings=tuple(warnings),
        counts=_counts(files, outputs, samples),
        skipped_files=tuple(skipped),
    )
