"""`ngsim-graphs build`: raw files to a finished, self-describing dataset directory.

A data source (`sources`) reads each input file and stages its rows per recording and part of
its vehicles as Parquet; each recording is then cleaned into its tracks table, a part at a time,
and built: frame arrays, ego windows, splits, and every sample's counts and its share of the
scaler's ranges (`tasks`). The files and then the recordings go to `--jobs` worker processes
(`workers`); what depends on the order of the recordings (track numbers, the samples tables,
the manifest) is decided here, between the stages, so that any number of jobs gives the same
build.

Memory stays bounded per job, whatever the size of a file or recording: a task holds a batch of
a file's rows, a group of a recording's vehicles, or a range of a recording's grid rows and
proximity pairs, and of a whole recording only its samples and an index or two per grid row
(`tasks`; cs-lstm: also its raw rows' five columns). A recording's samples are staged by its
task; this process writes the samples tables from them a recording at a time, and keeps of each
recording only its counts and scaler ranges.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace
from functools import reduce
from itertools import accumulate
from pathlib import Path

import polars as pl

from ngsim_graphs import __version__, landing, layout, storage
from ngsim_graphs import schema as s
from ngsim_graphs.budget import available_cores
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine.tasks import (
    RecordingOutput,
    StagedParts,
    build_recording,
    clean_recording,
    read_file,
)
from ngsim_graphs.engine.workers import Workers, one_malloc_arena
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.manifest import BuildCounts, Manifest, RecordingEntry, ScriptRows, SourceLine
from ngsim_graphs.protocols import PROTOCOLS
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.contract import FileReport, RecordingKey, RecordingReport, Source
from ngsim_graphs.sources.registry import check_locations, choose_source
from ngsim_graphs.splits import SPLIT_ORDER, split_warnings
from ngsim_graphs.synth.marker import mixed_inputs_warning, synthetic_inputs
from ngsim_graphs.windows import SampleProtocol

# (what is being done, steps done, steps in all): the CLI draws it as a progress bar.
BuildProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class BuildResult:
    """What a finished build holds; the same facts as its manifest."""

    out_dir: Path
    files: tuple[FileReport, ...]
    skipped_files: tuple[str, ...]
    recordings: tuple[RecordingReport, ...]
    manifest: Manifest
    warnings: tuple[str, ...] = ()  # also in the manifest: splits that are empty or tiny


def _stage_inputs(
    source: Source,
    files: list[Path],
    config: BuildConfig,
    root: Path,
    progress: BuildProgress,
    strict: bool,
    workers: Workers,
) -> tuple[list[FileReport], dict[RecordingKey, StagedParts]]:
    """Read each file and stage its rows per recording, one file per job at a time."""

    def reading(done: int) -> None:  # one job reads the files in order, several at once
        what = files[min(done, len(files) - 1)].name if workers.jobs == 1 else "input files"
        progress(f"reading {what}", done, len(files))

    reading(0)
    tasks = [(source, path, config, i, root, strict) for i, path in enumerate(files)]
    sizes = [path.stat().st_size for path in files]
    read = workers.map(read_file, tasks, reading, sizes)
    reports = [report for report, _ in read]
    staged: dict[RecordingKey, StagedParts] = {}
    for _, paths in read:  # in file order: a part's files in the order they were read
        for key, parts in paths.items():
            for part, path in parts.items():
                staged.setdefault(key, {}).setdefault(part, []).append(path)
    if not staged:
        found = sorted({loc for r in reports for loc in r.locations_found})
        more = f" (and {len(files) - 1} more)" if len(files) > 1 else ""
        raise NgsimInputError(
            f"{files[0]}{more}",
            f"no rows of the chosen locations ({', '.join(config.locations)}) in any input; "
            f"found: {', '.join(found) or 'none'}",
        )
    return reports, staged


def _build_recordings(
    source: Source,
    staged: dict[RecordingKey, StagedParts],
    config: BuildConfig,
    root: Path,
    files: list[FileReport],
    progress: BuildProgress,
    strict: bool,
    workers: Workers,
) -> list[RecordingOutput]:
    """Every recording cleaned, then built, in key order, one recording per job at a time."""
    keys = sorted(staged)

    def stage(what: str) -> Callable[[int], None]:
        progress(what, 0, len(keys))
        return lambda done: progress(what, done, len(keys))

    cleaning = [(source, key, staged[key], config, root, files, strict) for key in keys]
    sizes = [
        sum(path.stat().st_size for paths in staged[key].values() for path in paths) for key in keys
    ]
    reports = workers.map(clean_recording, cleaning, stage("cleaning recordings"), sizes)
    first_ids = [0, *accumulate(report.tracks for report in reports)]
    protocol = PROTOCOLS[config.protocol]
    building = [
        (key, i, reports[i], first_ids[i], staged[key], config, root, protocol)
        for i, key in enumerate(keys)
    ]
    progress_of = stage("building recordings")
    return workers.map(build_recording, building, progress_of, sizes)


def _write_samples(root: Path, outputs: list[RecordingOutput]) -> dict[str, dict[str, int]]:
    """Samples tables and arrays of each split; returns the sample count per split and recording.

    A split's samples are numbered in (location, period, ego track, start step) order. The
    recordings come in key order, which is (location, period)'s, and each staged its samples
    sorted by (ego track, start step): the tables are streamed from the staged files, and this
    process never holds a whole table (under cs-lstm, five million samples)."""
    counts = {
        split.value: {
            layout.recording_name(o.report.location, o.report.period): o.samples[split.value]
            for o in outputs
            if o.samples[split.value]
        }
        for split in SPLIT_ORDER
    }
    for split in SPLIT_ORDER:
        in_split = pl.col(s.SPLIT) == split.value
        windows = pl.concat([pl.scan_parquet(o.windows).filter(in_split) for o in outputs])
        table = windows.with_row_index(s.SAMPLE_ID).select(s.SAMPLES_TABLE_SCHEMA.names())
        storage.sink_parquet(
            table.cast(dict(s.SAMPLES_TABLE_SCHEMA)), layout.samples_path(root, split.value)
        )
    with ExitStack() as stack:
        arrays = {
            split: stack.enter_context(
                storage.ArrayAppender(
                    layout.sample_arrays_dir(root, split.value), layout.SAMPLE_ARRAYS
                )
            )
            for split in SPLIT_ORDER
        }
        for output in outputs:  # each read once; every split's files written, even empty
            windows = pl.read_parquet(
                output.windows, columns=[s.SPLIT, s.RECORDING_INDEX, s.EGO_TRACK_ID, s.START_STEP]
            )
            for split, appender in arrays.items():
                part = windows.filter(pl.col(s.SPLIT) == split.value)
                appender.append(
                    {
                        "recording_index": part[s.RECORDING_INDEX].cast(pl.Int16).to_numpy(),
                        "ego_track_id": part[s.EGO_TRACK_ID].to_numpy(),
                        "start_step": part[s.START_STEP].to_numpy(),
                    }
                )
    return counts


def _why_no_samples(outputs: list[RecordingOutput], config: BuildConfig) -> str:
    """Why the chosen recordings gave no sample at all, as a user can act on it."""
    rows = sum(o.report.rows for o in outputs)
    why = PROTOCOLS[config.protocol].why_no_samples(_script_total(outputs), rows, config)
    if why is not None:
        return why
    if sum(o.report.grid_rows for o in outputs) == 0:
        return (
            f"none of the {rows:,} rows kept lies on the {config.time_step_s} s grid, which keeps "
            f"the frames whose Frame_ID is a multiple of {config.frames_per_step} (are they all odd?)"
        )
    longest = max(o.longest_track_steps for o in outputs)
    if longest < config.window_steps:
        return (
            f"no track spans a whole window of {config.window_steps} grid steps "
            f"({config.window_steps * config.time_step_s:g} s of history and future); the longest "
            f"has {longest} steps"
        )
    return f"every window falls in a gap between the blocks of the {config.split.value} split"


def _check_some_samples(
    outputs: list[RecordingOutput], config: BuildConfig, raw_paths: list[Path]
) -> None:
    if sum(sum(o.samples.values()) for o in outputs) == 0:
        more = f" (and {len(raw_paths) - 1} more)" if len(raw_paths) > 1 else ""
        raise NgsimInputError(
            f"{raw_paths[0]}{more}", f"no samples: {_why_no_samples(outputs, config)}"
        )


def _warnings(
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
        report=replace(o.report, first_outlier=None),
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


def _check_recordings(
    staged: dict[RecordingKey, StagedParts], files: list[FileReport], protocol: SampleProtocol
) -> None:
    """Every recording must be one the protocol takes (cs-lstm: one of the script's six)."""
    for key in sorted(staged):
        why = protocol.refuses(key)
        if why is not None:
            name = f"{key[0]}/{key[1]}"
            path = next((f.path for f in files if name in f.recordings), files[0].path)
            raise NgsimInputError(path, why)


def _counts(
    files: list[FileReport], outputs: list[RecordingOutput], samples: dict[str, dict[str, int]]
) -> BuildCounts:
    """The build's totals over its input files and recordings."""

    def total(key: str) -> int:
        return sum(getattr(o.report, key) for o in outputs)

    dropped = {
        reason.value: sum(f.rows_dropped.get(reason.value, 0) for f in files)
        for reason in DropReason
    }
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


def _manifest(
    dataset: str,
    config: BuildConfig,
    files: list[FileReport],
    outputs: list[RecordingOutput],
    samples: dict[str, dict[str, int]],
    scaler: MinMaxScaler,
    warnings: list[str],
    skipped: list[Path],
) -> Manifest:
    """What the build is, to be written last (`layout.write_manifest` adds the file records)."""
    return Manifest(
        format_version=layout.FORMAT_VERSION,
        software={"ngsim_graphs": __version__, "polars": pl.__version__},
        dataset=dataset,
        config=config,
        config_hash=layout.config_hash(config.to_dict()),
        inputs=tuple(files),
        recordings=tuple(_recording_entry(o, samples, files) for o in outputs),
        splits={split: sum(per.values()) for split, per in samples.items()},
        scaler=scaler,
        warnings=tuple(warnings),
        counts=_counts(files, outputs, samples),
        skipped_files=tuple(str(path) for path in skipped),
    )


def run_build(
    raw_paths: list[Path],
    out_dir: Path,
    config: BuildConfig,
    overwrite: bool = False,
    progress: BuildProgress | None = None,
    strict: bool = False,
    dataset: str | None = None,
    jobs: int | None = 1,
) -> BuildResult:
    """Read every raw file under `raw_paths` and write the finished build into `out_dir`.

    `dataset` names the source (`sources.registry.SOURCES`); by default it is told from the files.
    The same files named in any order, or found in folders, give the same build, byte for byte.
    `jobs` > 1 reads the files and builds the recordings in that many worker processes (None:
    one per core this process may use); the output is the same for any number. The processes
    that run the tasks keep to one malloc arena (`workers.worker_environment`). With one job,
    and for a stage of a single task, the tasks run in this process; with one job it asks for
    one arena for the rest of its life (`workers.one_malloc_arena`: only threads started after
    keep to it). The workers are started with multiprocessing's "spawn": a script that builds
    with jobs > 1 must do so under `if __name__ == "__main__":`.
    Raises ValueError for a location no source knows, NgsimInputError for unusable input and
    NgsimOutputError for an `out_dir` that must
    not be written (an input, another program's folder, another build's) or cannot be (a full
    disk); `out_dir` is then left as it was.
    """
    check_locations(config.locations)
    landing.check_outside_inputs(out_dir, raw_paths)  # before anything is read or written
    workers = Workers(available_cores() if jobs is None else jobs)  # checks jobs >= 1
    if workers.jobs == 1:  # the tasks run in this process
        one_malloc_arena()
    report_progress = progress or (lambda _what, _done, _total: None)
    source, found, skipped = choose_source(raw_paths, dataset)
    # The build depends on the set of inputs, not on the order they were named in: the files
    # (resolved paths) are read in path order, which numbers them and lists them in the manifest.
    files = sorted(found)
    with landing.build_directory(out_dir, overwrite) as root:
        with workers:  # the workers end here: what they held goes back before the writing
            file_reports, staged = _stage_inputs(
                source, files, config, root, report_progress, strict, workers
            )
            _check_recordings(staged, file_reports, PROTOCOLS[config.protocol])
            outputs = _build_recordings(
                source, staged, config, root, file_reports, report_progress, strict, workers
            )
        scaler = reduce(MinMaxScaler.joined, [o.train_ranges for o in outputs])
        _check_some_samples(outputs, config, raw_paths)
        report_progress("writing samples", len(staged), len(staged))
        samples = _write_samples(root, outputs)
        synthetic = synthetic_inputs(file.path for file in file_reports)  # told now: files move
        mixed = mixed_inputs_warning([file.path for file in file_reports], synthetic)
        warnings = _warnings(outputs, config, file_reports) + ([mixed] if mixed else [])
        manifest = _manifest(
            source.name, config, file_reports, outputs, samples, scaler, warnings, skipped
        )
        manifest = replace(
            manifest,
            synthetic=len(synthetic) == len(file_reports),
            synthetic_inputs=synthetic,
        )
        manifest = layout.write_manifest(root, manifest)
    return BuildResult(
        out_dir=out_dir,
        files=tuple(file_reports),
        skipped_files=tuple(str(p) for p in skipped),
        recordings=tuple(o.report for o in outputs),
        manifest=manifest,
        warnings=tuple(warnings),
    )
