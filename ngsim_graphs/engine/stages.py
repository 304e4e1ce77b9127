"""The stages of `ngsim-graphs build` over the workers (`pipeline` runs them in order): the
inputs read and staged per recording, the recordings cleaned, then built, and the samples
tables written from what the recordings staged.

Each stage maps its tasks (`tasks`) over `workers.Workers` and returns their results in task
order; what depends on the order of the recordings (track numbers) is decided here, between the
stages, so that any number of jobs gives the same build.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace
from itertools import accumulate
from pathlib import Path

import polars as pl

from ngsim_graphs import edges, layout, storage
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine.staging import staged_unpacked_dir
from ngsim_graphs.engine.tasks import (
    RecordingOutput,
    StagedParts,
    build_recording,
    clean_recording,
    read_file,
)
from ngsim_graphs.engine.workers import Workers
from ngsim_graphs.errors import NgsimError, NgsimInputError
from ngsim_graphs.protocols import PROTOCOLS
from ngsim_graphs.sources import archives
from ngsim_graphs.sources.contract import FileReport, RecordingKey, RecordingReport, Source
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.registry import choose_source
from ngsim_graphs.splits import SPLIT_ORDER
from ngsim_graphs.synth.marker import MARKER_NAME, synthetic_inputs
from ngsim_graphs.windows import SampleProtocol

# (what is being done, steps done, steps in all): the CLI draws it as a progress bar.
BuildProgress = Callable[[str, int, int], None]


def stage_inputs(
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


@dataclass(frozen=True)
class Inputs:
    """What a build read: its source, the files skipped and the reports of those read (both by
    name), their rows staged per recording, and the files (by name) that synth wrote."""

    source: Source
    skipped: list[str]
    reports: list[FileReport]
    staged: dict[RecordingKey, StagedParts]
    synthetic: tuple[str, ...]


def check_grid(source: Source, config: BuildConfig, paths: list[Path]) -> None:
    """The grid must be a whole number of the source's frames: it is kept by frame number."""
    try:
        source.frames_per_step(config.time_step_s)
    except ValueError as err:
        raise NgsimInputError(paths[0], str(err)) from None


def read_inputs(
    raw_paths: list[Path],
    dataset: str | None,
    limits: PhysicalLimits | None,
    config: BuildConfig,
    root: Path,
    progress: BuildProgress,
    strict: bool,
    workers: Workers,
) -> Inputs:
    """The inputs' archives unpacked into `root`'s staging, the source chosen (holding `limits`
    where given) and its files read and staged. An unpacked file is reported
    (and its errors name it) by its archive's name and its own inside it."""
    unpacked = archives.unpack_inputs(
        raw_paths,
        staged_unpacked_dir(root),
        (MARKER_NAME,),
        lambda done, total: progress("unpacking archives", done, total),
    )
    names = unpacked.names
    try:
        source, found, skipped = choose_source(
            archives.searched_paths(raw_paths, unpacked), dataset
        )
        source = source if limits is None else replace(source, limits=limits)
        # The build depends on the set of inputs, not on the order they were named in: the
        # files are read in the order of their names (resolved paths, or an archive's and its
        # member's), which numbers them and lists them in the manifest.
        files = sorted(found, key=lambda path: archives.shown_name(path, names))
        check_grid(source, config, files or raw_paths)
        reports, staged = stage_inputs(source, files, config, root, progress, strict, workers)
    except NgsimError as err:
        raise archives.named_error(err, names) from None
    # Which files synth wrote is told from the files read (an archive's copies and markers).
    synthetic = tuple(
        archives.shown_name(p, names) for p in synthetic_inputs(r.path for r in reports)
    )
    reports = [replace(report, path=archives.shown_name(report.path, names)) for report in reports]
    shown = [archives.shown_name(path, names) for path in skipped] + unpacked.skipped
    return Inputs(source, shown, reports, staged, synthetic)


def stage_of(progress: BuildProgress, what: str, total: int) -> Callable[[int], None]:
    """A stage's progress, started at 0 of `total`: called with the steps done."""
    progress(what, 0, total)
    return lambda done: progress(what, done, total)


def clean_recordings(
    source: Source,
    staged: dict[RecordingKey, StagedParts],
    config: BuildConfig,
    root: Path,
    files: list[FileReport],
    progress: BuildProgress,
    strict: bool,
    workers: Workers,
) -> list[RecordingReport]:
    """Every recording cleaned, in key order, one recording per job at a time."""
    keys = sorted(staged)
    cleaning = [(source, key, staged[key], config, root, files, strict) for key in keys]
    stage = stage_of(progress, "cleaning recordings", len(keys))
    return workers.map(clean_recording, cleaning, stage, staged_sizes(staged))


def build_recordings(
    staged: dict[RecordingKey, StagedParts],
    reports: list[RecordingReport],
    scratch: Path,
    config: BuildConfig,
    root: Path,
    progress: BuildProgress,
    workers: Workers,
) -> list[RecordingOutput]:
    """Every cleaned recording (its tracks staged under `scratch`) built into `root`, in key
    order, one recording per job at a time."""
    keys = sorted(staged)
    first_ids = [0, *accumulate(report.tracks for report in reports)]
    protocol = PROTOCOLS[config.protocol]
    building = [
        (key, i, reports[i], first_ids[i], staged[key], scratch, config, root, protocol)
        for i, key in enumerate(keys)
    ]
    stage = stage_of(progress, "building recordings", len(keys))
    return workers.map(build_recording, building, stage, staged_sizes(staged))


def staged_sizes(staged: dict[RecordingKey, StagedParts]) -> list[int]:
    """The bytes of each recording's staged raw rows, in key order: a guess of its work."""
    return [
        sum(p.stat().st_size for paths in staged[key].values() for p in paths)
        for key in sorted(staged)
    ]


def write_samples(
    root: Path, outputs: list[RecordingOutput], config: BuildConfig
) -> dict[str, dict[str, int]]:
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
    columns = {
        **s.SAMPLE_SCHEMA,
        **dict.fromkeys(edges.count_columns(config.edge_types), s.COUNT_DTYPE),
    }
    for split in SPLIT_ORDER:
        in_split = pl.col(s.SPLIT) == split.value
        windows = pl.concat([pl.scan_parquet(o.windows).filter(in_split) for o in outputs])
        table = windows.with_row_index(s.SAMPLE_ID).select(list(columns))
        storage.sink_parquet(table.cast(columns), layout.samples_path(root, split.value))
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


def check_recordings(
    staged: dict[RecordingKey, StagedParts], files: list[FileReport], protocol: SampleProtocol
) -> None:
    """Every recording must be one the protocol takes (cs-lstm: one of the script's six)."""
    for key in sorted(staged):
        why = protocol.refuses(key)
        if why is not None:
            name = f"{key[0]}/{key[1]}"
            path = next((f.path for f in files if name in f.recordings), files[0].path)
            raise NgsimInputError(path, why)
