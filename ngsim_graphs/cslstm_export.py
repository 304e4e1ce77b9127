"""CS-LSTM's `TrainSet.mat`, `ValSet.mat` and `TestSet.mat` from the six recordings.

Reads the recordings' raw rows (any of the three NGSIM formats; the script cleans nothing, so
neither does the export), applies the rules of `ngsim_graphs.cslstm` to each recording, splits,
builds each split's `tracks` and applies the edge filter, and writes the three files in the MAT
v5 format that `scipy.io.loadmat` reads (docs/cslstm.md says what each value is).

The output folder is ours to replace only where `cslstm-export.json` says so: it is written
first with `"complete": false`, the three files are renamed into place, and it is rewritten with
`"complete": true` last. A `TrainSet.mat` the marker does not list is never replaced.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import polars as pl

from ngsim_graphs import __version__, matfile
from ngsim_graphs import schema as s
from ngsim_graphs.cslstm import (
    DATASET_IDS,
    RECORDING_OF_DATASET,
    SPLIT_NAMES,
    TRAJ_COLUMNS,
    RecordingRows,
    kept_by_edge_filter,
    ordered_rows,
    split_codes,
    traj_rows,
    vehicle_bounds,
)
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.interrupts import interrupts_held
from ngsim_graphs.sources.ngsim.files import find_raw_files, read_raw_file
from ngsim_graphs.sources.ngsim.recordings import identify_recordings

FILE_NAMES = {"train": "TrainSet.mat", "val": "ValSet.mat", "test": "TestSet.mat"}
MARKER = "cslstm-export.json"
LOCATIONS = ("us-101", "i-80")
# What the script keeps of a row, and Global_Time, which tells the recordings apart.
_NEEDED = (s.VEHICLE_ID, s.FRAME_ID, s.GLOBAL_TIME, s.LOCAL_X, s.LOCAL_Y, s.LANE_ID)
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class InputFile:
    """One input file and what the export took of it."""

    path: str
    raw_format: str
    size_bytes: int
    sha256: str
    rows_read: int
    rows_other_locations: int  # portal CSV: rows of Lankershim and Peachtree
    rows_missing_values: int  # an empty Vehicle_ID, Frame_ID, Global_Time, Local_X/Y or Lane_ID
    first_missing_line: int | None
    rows_stray: int  # a file of several recordings: Global_Time fits none of them
    first_stray_line: int | None
    recordings: tuple[str, ...]  # "location/period"


@dataclass(frozen=True)
class DatasetCounts:
    """One dataset id: its rows, and what the split and the edge filter made of them."""

    dataset_id: int
    recording: str  # "location/period"
    rows: int
    vehicles: int
    kept_rows: dict[str, int]  # per split: rows of `traj`
    vehicles_by_split: dict[str, int]  # per split: vehicles, all in `tracks`
    short_vehicles: int  # under 31 rows: the script would stop; their rows are not in `traj`
    short_vehicle_rows: int


@dataclass(frozen=True)
class SplitTables:
    """One split: `traj` as blocks of rows, (n_i, 47) float32 each, one per dataset in order,
    and `tracks` as {(dataset id - 1, vehicle id - 1): (3, n) float32} of a (6, width) array."""

    traj_blocks: list[np.ndarray]
    cells: dict[tuple[int, int], np.ndarray]

    @property
    def traj_rows(self) -> int:
        return sum(len(block) for block in self.traj_blocks)

    @property
    def width(self) -> int:
        """The largest vehicle id of the split: the second dimension of `tracks`."""
        return max((vehicle + 1 for _, vehicle in self.cells), default=0)


@dataclass(frozen=True)
class ExportResult:
    out: Path
    inputs: list[InputFile]
    skipped_files: list[Path]
    datasets: list[DatasetCounts]
    missing: list[str]  # recordings of the six that no input holds (--allow-partial)
    rows: dict[str, int]  # per split: rows of `traj`
    tracks_width: dict[str, int]  # per split: the second dimension of `tracks`


def _recording_name(key: tuple[str, str]) -> str:
    return f"{key[0]}/{key[1]}"


def _first_line(rows: pl.DataFrame, mask: pl.Series, first_line: int) -> int | None:
    hits = rows.filter(mask)
    return None if hits.height == 0 else int(hits["row"].min()) + first_line


def read_file_rows(path: Path) -> tuple[dict[tuple[str, str], pl.DataFrame], InputFile]:
    """One file's rows per recording key, columns _NEEDED in file order, and what was dropped.

    A file that holds one recording gives it every row with the needed fields (the script reads
    the file whole); in a file of several recordings (the portal CSV) a row whose Global_Time
    fits none of them is a stray, counted and dropped.
    """
    raw = read_raw_file(path, LOCATIONS)
    frame = raw.frame.collect().with_row_index("row")
    complete = frame.select(pl.all_horizontal(pl.col(_NEEDED).is_not_null())).to_series()
    if not complete.any():
        raise NgsimInputError(
            path, "no row has all of Vehicle_ID, Frame_ID, Global_Time, Local_X, Local_Y, Lane_ID"
        )
    index, names = identify_recordings(
        frame.select(s.LOCATION, s.FRAME_ID, s.GLOBAL_TIME, s.VEHICLE_ID), path, complete
    )
    if len(names) == 1:
        index = pl.Series(np.zeros(frame.height, dtype=np.uint16))
    stray = complete & index.is_null()
    for key in names:
        if key not in DATASET_IDS:
            raise NgsimInputError(
                path,
                f"holds the recording {_recording_name(key)}, none of the six that CS-LSTM's "
                "script reads (US-101 0750-0835, I-80 0400-0415 and 0500-0530)",
            )
    rows = {
        key: frame.filter(complete & (index == i)).select(_NEEDED) for i, key in enumerate(names)
    }
    report = InputFile(
        path=str(path),
        raw_format=raw.raw_format.value,
        size_bytes=raw.size_bytes,
        sha256=file_sha256(path),
        rows_read=raw.rows_read,
        rows_other_locations=raw.rows_other_locations,
        rows_missing_values=int((~complete).sum()),
        first_missing_line=_first_line(frame, ~complete, raw.first_line),
        rows_stray=int(stray.sum()),
        first_stray_line=_first_line(frame, stray, raw.first_line),
        recordings=tuple(_recording_name(key) for key in names),
    )
    return rows, report


def read_recordings(
    paths: list[Path], allow_partial: bool, progress: Progress
) -> tuple[dict[int, RecordingRows], list[InputFile], list[Path], list[str]]:
    """(rows per dataset id in the script's order, input reports, skipped files, missing)."""
    files, skipped = find_raw_files(paths)
    found: dict[int, tuple[Path, pl.DataFrame]] = {}
    inputs = []
    for done, path in enumerate(files):
        progress(f"reading {path.name}", done, len(files))
        rows, report = read_file_rows(path)
        inputs.append(report)
        for key, table in rows.items():
            dataset_id = DATASET_IDS[key]
            if dataset_id in found:
                raise NgsimInputError(
                    path,
                    f"holds the recording {_recording_name(key)}, which {found[dataset_id][0]} "
                    "holds too: give each recording once",
                )
            found[dataset_id] = (path, table)
    missing = [
        _recording_name(key) for i, key in sorted(RECORDING_OF_DATASET.items()) if i not in found
    ]
    if missing and not allow_partial:
        raise NgsimInputError(
            None,
            f"the inputs hold no rows of {', '.join(missing)}: CS-LSTM's files are made of all "
            "six recordings (--allow-partial writes those present, dataset ids unchanged)",
        )
    recordings = {}
    for dataset_id in sorted(found):
        table = found[dataset_id][1]
        recordings[dataset_id] = ordered_rows(
            dataset_id, *(table[c].to_numpy() for c in _NEEDED if c != s.GLOBAL_TIME)
        )
    return recordings, inputs, skipped, missing


def split_tables(
    recordings: dict[int, RecordingRows], progress: Progress
) -> tuple[dict[str, SplitTables], list[DatasetCounts]]:
    """Each split's `traj` and `tracks` from the recordings' rows, and what each dataset gave."""
    tables = {name: SplitTables([], {}) for name in SPLIT_NAMES}
    counts = []
    for done, (dataset_id, rows) in enumerate(sorted(recordings.items())):
        progress(f"dataset {dataset_id}: maneuvers and grid", done, len(recordings))
        traj = traj_rows(rows)
        kept, too_short = kept_by_edge_filter(rows)
        code = split_codes(rows)
        starts, ends = vehicle_bounds(rows.vehicle)
        track = np.stack([rows.frame, rows.x_ft, rows.y_ft])  # (3, n) float32
        kept_rows, vehicles = {}, {}
        for number, name in enumerate(SPLIT_NAMES):
            block = traj[kept & (code == number)]
            tables[name].traj_blocks.append(block)
            kept_rows[name] = len(block)
            mine = code[starts] == number
            vehicles[name] = int(mine.sum())
            for a, b in zip(starts[mine], ends[mine], strict=True):
                cell = (dataset_id - 1, int(rows.vehicle[a]) - 1)
                tables[name].cells[cell] = np.ascontiguousarray(track[:, a:b])
        del traj
        counts.append(
            DatasetCounts(
                dataset_id=dataset_id,
                recording=_recording_name(RECORDING_OF_DATASET[dataset_id]),
                rows=len(rows.vehicle),
                vehicles=len(starts),
                kept_rows=kept_rows,
                vehicles_by_split=vehicles,
                short_vehicles=int(too_short[starts].sum()),
                short_vehicle_rows=int(too_short.sum()),
            )
        )
    return tables, counts


def write_mat(path: Path, table: SplitTables, description: str) -> None:
    """`traj` and `tracks` as one MAT v5 file (ngsim_graphs.matfile), synced to disk."""
    with path.open("wb") as handle:
        handle.write(matfile.header(description))
        matfile.write_single_matrix(handle, "traj", table.traj_blocks, TRAJ_COLUMNS)
        matfile.write_cell_array(handle, "tracks", (6, table.width), table.cells)
        handle.flush()
        os.fsync(handle.fileno())


def check_output(out: Path, overwrite: bool) -> None:
    """Refuse an --out whose files are not ours to replace, or ours without --overwrite."""
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "exists and is not a folder")
    present = [name for name in FILE_NAMES.values() if (out / name).exists()]
    marker = out / MARKER
    if not present and not marker.exists():
        return
    listed = _listed_files(marker)
    foreign = [name for name in present if name not in listed]
    if foreign:
        raise NgsimOutputError(
            out / foreign[0],
            f"was not written by export-cslstm (no {MARKER} lists it): not replaced; "
            "choose another --out",
        )
    if not overwrite:
        raise NgsimOutputError(out, "holds an export already: --overwrite replaces it")


def _listed_files(marker: Path) -> set[str]:
    if not marker.exists():
        return set()
    try:
        document = json.loads(marker.read_text())
        files = document["files"]
    except (OSError, ValueError, KeyError, TypeError):
        raise NgsimOutputError(marker, "is not an export-cslstm marker: not replaced") from None
    return {name for name in files if name in FILE_NAMES.values()}


def _write_marker(out: Path, result: ExportResult, complete: bool) -> None:
    document = {
        "program": "ngsim-graphs export-cslstm",
        "version": __version__,
        "complete": complete,
        "files": {FILE_NAMES[name]: {"traj_rows": n} for name, n in result.rows.items()},
        "tracks_width": {FILE_NAMES[name]: n for name, n in result.tracks_width.items()},
        "missing_recordings": result.missing,
        "datasets": [asdict(d) for d in result.datasets],
        "inputs": [asdict(i) for i in result.inputs],
    }
    partial = out / f".{MARKER}.partial"
    partial.write_text(json.dumps(document, indent=2) + "\n")
    partial.replace(out / MARKER)


def export_cslstm(
    paths: list[Path],
    out: Path,
    *,
    allow_partial: bool = False,
    overwrite: bool = False,
    progress: Progress = lambda _what, _done, _total: None,
) -> ExportResult:
    """Write DIR/TrainSet.mat, ValSet.mat and TestSet.mat as CS-LSTM's `preprocess_data.m` makes
    them from the six recordings (docs/cslstm.md), and DIR/cslstm-export.json."""
    check_output(out, overwrite)
    recordings, inputs, skipped, missing = read_recordings(paths, allow_partial, progress)
    tables, datasets = split_tables(recordings, progress)
    del recordings
    result = ExportResult(
        out=out,
        inputs=inputs,
        skipped_files=skipped,
        datasets=datasets,
        missing=missing,
        rows={name: t.traj_rows for name, t in tables.items()},
        tracks_width={name: t.width for name, t in tables.items()},
    )
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    partials = {}
    try:
        for done, name in enumerate(SPLIT_NAMES):
            progress(f"writing {FILE_NAMES[name]}", done, len(SPLIT_NAMES))
            partials[name] = out / f".{FILE_NAMES[name]}.partial"
            description = (
                f"MATLAB 5.0 MAT-file, written by ngsim-graphs {__version__} export-cslstm: "
                f"CS-LSTM's {FILE_NAMES[name]}"
            )
            write_mat(partials[name], tables.pop(name), description)
    except BaseException as err:  # an interrupt too: no partial file is left
        for partial in partials.values():
            partial.unlink(missing_ok=True)
        if created and not any(out.iterdir()):
            out.rmdir()
        if not isinstance(err, (OSError, ValueError)):
            raise
        why = err.strerror if isinstance(err, OSError) and err.strerror else err
        raise NgsimOutputError(out, f"cannot write the export: {why}") from None
    with interrupts_held():  # the three files land together, or (interrupted earlier) none
        _write_marker(out, result, complete=False)
        for name, partial in partials.items():
            partial.replace(out / FILE_NAMES[name])
        _write_marker(out, result, complete=True)
    return result
