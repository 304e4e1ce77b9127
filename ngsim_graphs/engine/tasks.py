"""What one worker of `ngsim-graphs build` does: one input file read and staged, one recording
cleaned, one recording built (`pipeline` runs them over `workers.Workers`).

A task depends only on its arguments and writes only its own files, so that the build is the
same whichever worker runs it and in whatever order they finish. Per recording: frame arrays,
proximity edges, split ego windows, and every sample's counts and its share of the scaler's
ranges (`neighbourhoods`). The graphs themselves are not stored per sample (see
docs/build-format.md: the dataset induces them from the frame arrays).

No task holds a whole file's or recording's rows, so that its memory does not grow with the
size of the recording (NGSIM's largest is twice its smallest):
- a reading task streams its file's parsed rows into a scratch file and stages them a batch at
  a time, per part of the recording's vehicles;
- a cleaning task holds a group of whole vehicles of a part (some 65,536 raw rows), and
  stages the evidence of the recording's checks, which stream it;
- a build task holds its samples' windows and counts and the indexes of its grid rows by step
  and by track (a number or two per row), and a range of steps at a time the rest:
  the grid rows are made of the tracks table and written a range at a time, then mapped back
  from their files a range at a time, and the range's proximity pairs, ten a grid row in a dense
  recording, found, written and used (under cs-lstm it also holds its raw rows' five columns
  until its windows are made).
"""

from __future__ import annotations

import contextlib
import functools
import shutil
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import polars as pl

from ngsim_graphs import budget, edges, layout, storage
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine import staging
from ngsim_graphs.grid import (
    ARRAY_NAMES,
    ROW_ARRAYS,
    RecordingArrays,
    grid_node_rows,
    step_pieces,
    with_pairs,
    write_node_arrays,
)
from ngsim_graphs.manifest import ScriptRows
from ngsim_graphs.neighbourhoods import (
    ego_rows,
    history_rows,
    neighbourhoods_of_rows,
    row_bounds,
    rows_by_y,
    sample_counts,
)
from ngsim_graphs.scaling import MinMaxScaler, train_ranges
from ngsim_graphs.schema import Split
from ngsim_graphs.sources.contract import (
    FileReport,
    FileRows,
    RecordingKey,
    RecordingReport,
    Source,
    TracksPart,
)
from ngsim_graphs.splits import VehicleIds
from ngsim_graphs.threads import in_order
from ngsim_graphs.windows import SampleProtocol

PAIR_ARRAYS = ("pair_rows", "pair_dist", "pair_key")  # RecordingArrays' fields of the pairs
# Called with each range's pair arrays (with_pairs), in step order.
PairSink = Callable[[RecordingArrays], None]
# Maps a recording's ROW_ARRAYS anew (`storage.open_arrays`): what a range of steps read of them
# is let go with the maps, and the grid rows are never all in memory at once.
RowArrays = Callable[[], dict[str, np.ndarray]]


@dataclass(frozen=True)
class RecordingSamples:
    """What one recording's samples contribute to a build, but its pairs (given to a PairSink)."""

    arrays: RecordingArrays  # pair_rows, pair_dist and pair_key empty: they went to the sink
    proximity_edges: int
    windows: pl.DataFrame  # ego windows with s.SPLIT and the count columns (edges.count_columns)
    train_ranges: MinMaxScaler  # what this recording's train samples observed


def recording_samples(
    arrays: RecordingArrays,
    windows: pl.DataFrame,
    config: BuildConfig,
    write_pairs: PairSink,
    row_arrays: RowArrays | None = None,
) -> RecordingSamples:
    """Proximity edges, and the counts and the scaler's ranges of the split ego `windows`
    (`SampleProtocol.recording_windows`), of one recording's frame arrays (`node_arrays`).

    A range of steps at a time (`budget.Budget.piece_rows`; as many at once as the process
    has threads, `threads.in_order`): the neighbourhoods of its ego rows are found with its
    pairs, and what those add to each sample that has history rows in the range is summed up;
    its pairs go to `write_pairs` in the ranges' order; then the range's pairs and
    neighbourhoods are let go. Given `row_arrays`, the ROW_ARRAYS of `arrays` are not used:
    each range maps them anew.
    """
    egos, starts = windows[s.EGO_TRACK_ID].to_numpy(), windows[s.START_STEP].to_numpy()
    history = history_rows(arrays, egos, starts, config)
    rows = ego_rows(history, int(arrays.step_ptr[-1]))
    first_row, last_row = row_bounds(history)
    is_train = (windows[s.SPLIT] == Split.TRAIN.value).to_numpy()
    columns = edges.count_columns(config.edge_types)  # as sample_counts gives them
    counts = np.zeros((len(history), len(columns)), np.int64)
    train = MinMaxScaler.empty()
    pair_ptr, n_pairs = np.zeros_like(arrays.pair_ptr), 0

    def piece_of(
        steps: tuple[int, int],
    ) -> tuple[RecordingArrays, np.ndarray, np.ndarray, MinMaxScaler]:
        first, end = steps
        rec = arrays if row_arrays is None else replace(arrays, **row_arrays())
        lo, hi = int(arrays.step_ptr[first]), int(arrays.step_ptr[end])
        piece = with_pairs(rec, first, end, config.d_min_m)
        mine = rows[np.searchsorted(rows, lo) : np.searchsorted(rows, hi)]
        hood = neighbourhoods_of_rows(piece, mine, rows_by_y(rec, first, end), config)
        touched = np.flatnonzero((last_row >= lo) & (first_row < hi))
        added = sample_counts(hood, history[touched], config)
        ranges = train_ranges(piece, hood, history[touched], is_train[touched])
        return piece, touched, added, ranges

    # A recording without grid rows is one empty piece: its pair files are still written.
    pieces = step_pieces(arrays.step_ptr, budget.BUDGET.piece_rows) or [(0, 0)]
    for piece, touched, added, ranges in in_order(piece_of, pieces):
        write_pairs(piece)  # in the pieces' order
        pair_ptr += piece.pair_ptr
        n_pairs += len(piece.pair_dist)
        counts[touched] += added
        train = train.joined(ranges)
        del piece  # before the next piece is taken
    windows = windows.with_columns(
        pl.Series(name, counts[:, i], dtype=pl.Int32) for i, name in enumerate(columns)
    )
    arrays = replace(arrays, pair_ptr=pair_ptr)
    return RecordingSamples(arrays, n_pairs, windows, train)


@dataclass(frozen=True)
class RecordingOutput:
    """What one recording adds to the manifest and to the samples tables."""

    report: RecordingReport
    index: int
    first_track_id: int
    n_steps: int
    longest_track_steps: int
    vehicle_ids: VehicleIds  # what the vehicle split took of its Vehicle_IDs
    proximity_edges: int
    windows: Path  # staged: its samples, with location, period, s.SPLIT and counts
    samples: dict[str, int]  # its number of samples per split (every split, 0 included)
    script_rows: ScriptRows | None  # the cs-lstm protocol's rows (None: aigem)
    train_ranges: MinMaxScaler  # what its train samples observed


StagedParts = dict[int, list[Path]]  # a recording's staged raw files, by part


def read_file(
    source: Source, path: Path, config: BuildConfig, file_index: int, root: Path, strict: bool
) -> tuple[FileReport, dict[RecordingKey, dict[int, Path]]]:
    """Read one input file and stage its rows per recording and part (a worker's task)."""
    scratch = staging.staged_scratch_dir(root, file_index)
    try:
        read = source.read_file(path, config, source.limits, file_index, strict, scratch)
        return read.report, stage_rows(read, path, root, file_index)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


_PART = "__part"


def stage_rows(
    read: FileRows, path: Path, root: Path, file_index: int
) -> dict[RecordingKey, dict[int, Path]]:
    """Each chosen recording's rows of one file, staged per part of its vehicles; the rows of
    a part in the order they were read. A recording without rows is still staged (part 0,
    empty): it is built, with no sample."""
    keys = {index: key for key, index in read.recordings.items()}
    schema = read.rows.drop(s.RECORDING_INDEX).collect_schema()
    part_of = (pl.col(s.VEHICLE_ID) // budget.BUDGET.vehicles_per_part).alias(_PART)
    staged: dict[RecordingKey, dict[int, Path]] = {key: {} for key in keys.values()}
    with contextlib.ExitStack() as files:
        writers: dict[tuple[int, int], storage.TableAppender] = {}
        batch_rows = budget.BUDGET.batch_rows * max(1, len(keys))
        # One streaming pass over the rows (a slice at a time would scan them from the start).
        for batch in read.rows.collect_batches(chunk_size=batch_rows):
            mine = batch.filter(pl.col(s.RECORDING_INDEX).is_in(list(keys)))
            if mine[s.VEHICLE_ID].null_count():  # the contract says every row has one
                index = mine.filter(pl.col(s.VEHICLE_ID).is_null())[s.RECORDING_INDEX][0]
                raise ValueError(f"{path}: rows of {keys[index]} without a vehicle id")
            groups = mine.with_columns(part_of).partition_by(
                s.RECORDING_INDEX, _PART, as_dict=True, maintain_order=True
            )
            for (index, part), rows in groups.items():
                if (index, part) not in writers:
                    target = staging.staged_raw_path(root, *keys[index], part, file_index)
                    staged[keys[index]][part] = target
                    writers[index, part] = files.enter_context(
                        staging.rows_appender(target, schema)
                    )
                writers[index, part].append(rows.select(schema.names()))
    for key, parts in staged.items():
        if not parts:
            parts[0] = staging.staged_raw_path(root, *key, 0, file_index)
            with staging.rows_appender(parts[0], schema) as empty:
                empty.append(pl.DataFrame(schema=schema))
    return {key: dict(sorted(staged[key].items())) for key in sorted(staged)}


def clean_recording(
    source: Source,
    key: RecordingKey,
    staged: StagedParts,
    config: BuildConfig,
    root: Path,
    files: list[FileReport],
    strict: bool,
) -> RecordingReport:
    """One recording's tracks, numbered from 0, staged a part of its vehicles at a time, and
    cleaned a group of whole vehicles of a part at a time (`vehicle_groups`,
    `budget.Budget.clean_rows`; as many groups at once as the process has threads,
    `threads.in_order`; a worker's task); its report, after the recording's checks.

    A group's tracks are numbered from 0 as they are cleaned, then on from the groups before it
    in order (`Source.vehicle_tracks` numbers a group's tracks alike from any first id). The
    build numbers tracks over all recordings; a recording's first track id is known once
    every recording before it is cleaned, so the numbers are shifted in `build_recording`."""
    groups = [
        (part, group, vehicles)
        for part in sorted(staged)
        for group, vehicles in enumerate(
            vehicle_groups(staging.scan_rows(staged[part]), budget.BUDGET.clean_rows)
        )
    ]

    def clean(item: tuple[int, int, pl.Expr]) -> tuple[int, TracksPart]:
        part, group, vehicles = item
        rows = staging.scan_rows(staged[part]).filter(vehicles).collect()
        cleaned = source.vehicle_tracks(rows, key, config, source.limits, 0)
        evidence = cleaned.evidence
        if evidence.collect_schema().len():  # staged: the checks stream it
            path = staging.staged_evidence_path(root, *key, part, group)
            lazy = isinstance(evidence, pl.LazyFrame)
            staging.write_staged(evidence.collect() if lazy else evidence, path)
            evidence = pl.scan_parquet(path)
        return part, replace(cleaned, evidence=evidence)

    parts, first_track_id = [], 0
    with contextlib.ExitStack() as files_open:
        tracks_of: dict[int, storage.TableAppender] = {}  # every part has a group at least
        for part, cleaned in in_order(clean, groups):
            if part not in tracks_of:
                target = staging.staged_tracks_path(root, *key, part)
                appender = staging.rows_appender(target, s.TRACKS_SCHEMA)
                tracks_of[part] = files_open.enter_context(appender)
            track_id = (pl.col(s.TRACK_ID) + first_track_id).cast(s.TRACKS_SCHEMA[s.TRACK_ID])
            tracks_of[part].append(cleaned.tracks.with_columns(track_id))
            first_track_id += cleaned.report.tracks
            parts.append(replace(cleaned, tracks=cleaned.tracks.clear()))
            del cleaned  # before the next group is cleaned
    return source.recording_report(parts, key, config, source.limits, files, strict)


def vehicle_groups(raw: pl.LazyFrame, most_rows: int) -> list[pl.Expr]:
    """Which rows of `raw` to clean together: consecutive vehicle ids, a group starting at each
    vehicle whose rows before it pass a multiple of `most_rows` (so a group holds at most
    `most_rows` rows and its last vehicle's; every row of a vehicle in one group)."""
    if raw.select(pl.len()).collect().item() <= most_rows:  # Parquet's metadata says
        return [pl.lit(True)]  # one group (also of no rows: the part is cleaned all the same)
    counts = raw.group_by(s.VEHICLE_ID).len().sort(s.VEHICLE_ID).collect(engine="streaming")
    ids, rows = counts[s.VEHICLE_ID].to_numpy(), counts["len"].to_numpy().astype(np.int64)
    group = (np.cumsum(rows) - rows) // max(1, most_rows)
    starts = np.flatnonzero(np.diff(group, prepend=-1))
    bounds = zip(ids[starts], [*ids[starts[1:] - 1], ids[-1]], strict=True)
    return [pl.col(s.VEHICLE_ID).is_between(int(lo), int(hi)) for lo, hi in bounds]


def build_recording(
    key: RecordingKey,
    index: int,
    report: RecordingReport,
    first_track_id: int,
    staged: StagedParts,
    scratch: Path,
    config: BuildConfig,
    root: Path,
    protocol: SampleProtocol,
) -> RecordingOutput:
    """Tracks, proximity edges, frame arrays and split windows of one recording, written into
    the build at `root` (a worker's task): its grid rows streamed from its tracks table
    (windows, largest vehicle ids) and made a range of steps at a time
    (`grid.write_node_arrays`), then read back from their files a range at a time
    (`recording_samples`). Its cleaned tracks are read from the staging of the build at
    `scratch` (`clean_recording`'s root): `root` itself, or the build that builds made
    together share them from; they are only read, never changed."""
    parts = [staging.staged_tracks_path(scratch, *key, part) for part in sorted(staged)]
    # Streamed, never held whole, in row groups of a fixed size: the bytes written do not
    # depend on the parts it was cleaned in. The grid nodes read back what they need of it.
    tracks = staging.scan_rows(parts).with_columns(
        (pl.col(s.TRACK_ID) + first_track_id).cast(s.TRACKS_SCHEMA[s.TRACK_ID])
    )
    storage.sink_parquet(tracks, layout.tracks_path(root, *key))
    tracks = pl.scan_parquet(layout.tracks_path(root, *key))
    nodes = grid_node_rows(tracks, config.time_step_s)  # each use streams them from the file
    # The staged rows before cleaning, scanned: a protocol that reads them takes what it needs.
    raw = staging.scan_rows([path for part in sorted(staged) for path in staged[part]])
    made = protocol.recording_windows(nodes, raw, key, index, config)
    windows, vehicle_ids, script = made.windows, made.vehicle_ids, made.script_rows
    del made, raw  # the windows are all the rest needs of the raw rows
    folder = layout.recording_arrays_dir(root, *key)
    with storage.ArrayAppender(folder, ROW_ARRAYS) as row_files:
        arrays = write_node_arrays(
            tracks, config.time_step_s, budget.BUDGET.grid_rows, row_files.append
        )
    with storage.ArrayAppender(folder, PAIR_ARRAYS) as pair_files:

        def write_pairs(piece: RecordingArrays) -> None:
            pair_files.append({name: getattr(piece, name) for name in PAIR_ARRAYS})

        row_arrays = functools.partial(storage.open_arrays, folder, ROW_ARRAYS)
        samples = recording_samples(arrays, windows, config, write_pairs, row_arrays)
    del arrays, windows  # the samples' own, with the pairs' index and the counts, follow
    arrays = samples.arrays
    written = (*PAIR_ARRAYS, *ROW_ARRAYS)
    storage.write_arrays(
        folder, {name: getattr(arrays, name) for name in ARRAY_NAMES if name not in written}
    )
    # Staged in the samples tables' order, not returned: the build streams the tables from them.
    windows = samples.windows.sort(s.EGO_TRACK_ID, s.START_STEP, maintain_order=True).with_columns(
        pl.lit(key[0]).alias(s.LOCATION),
        pl.lit(key[1]).alias(s.PERIOD),
        pl.lit(index).alias(s.RECORDING_INDEX),
    )
    windows_path = staging.staged_windows_path(root, *key)
    staging.write_staged(windows, windows_path)
    split_of = windows[s.SPLIT]
    per_split = {split.value: int((split_of == split.value).sum()) for split in Split}
    longest = int(np.diff(arrays.track_ptr).max()) if len(arrays.track_ptr) > 1 else 0
    return RecordingOutput(
        report,
        index,
        first_track_id,
        arrays.n_steps,
        longest,
        vehicle_ids,
        samples.proximity_edges,
        windows_path,
        per_split,
        script,
        samples.train_ranges,
    )
