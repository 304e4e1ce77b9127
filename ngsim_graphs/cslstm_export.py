"""CS-LSTM's `TrainSet.mat`, `ValSet.mat` and `TestSet.mat` from the six recordings.

Reads the recordings' raw rows (any of the three NGSIM formats; the script cleans nothing, so
neither does the export), applies the rules of `ngsim_graphs.cslstm` to each recording, splits,
builds each split's `tracks` and applies the edge filter, and writes the three files in the MAT
v5 format that `scipy.io.loadmat` reads (docs/cslstm.md says what each value is).

The output folder lands whole (`landing.output_directory`): the three files and the marker
`cslstm-export.json` are written into a hidden partial folder beside it, each created
exclusively and never through a link, and the finished folder is swapped in, so that an
interrupted or killed export leaves nothing that looks complete. An existing folder is replaced
only when it is empty, or (with --overwrite) an earlier export beyond doubt: the files in it are
exactly its marker and the files the marker lists, each of the sha256 the marker records. A
`TrainSet.mat` the marker does not list, or one changed since, is never replaced.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import polars as pl

from ngsim_graphs import landing, matfile, storage
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
from ngsim_graphs.landing import entries_beyond, some_names
from ngsim_graphs.partial_files import create_exclusive
from ngsim_graphs.sources.archives import archives_in
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.files import read_raw_file
from ngsim_graphs.sources.ngsim.formats import find_raw_files
from ngsim_graphs.sources.ngsim.recordings import identify_recordings
from ngsim_graphs.version import __version__

FILE_NAMES = {"train": "TrainSet.mat", "val": "ValSet.mat", "test": "TestSet.mat"}
MARKER = "cslstm-export.json"
PROGRAM = "ngsim-graphs export-cslstm"
LOCATIONS = ("us-101", "i-80")
# What the script keeps of a row, and Global_Time, which tells the recordings apart.
_NEEDED = (s.VEHICLE_ID, s.FRAME_ID, s.GLOBAL_TIME, ns.LOCAL_X, ns.LOCAL_Y, s.LANE_ID)
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
    packed = [archive for path in paths for archive in archives_in(path)]
    if packed:
        raise NgsimInputError(
            packed[0], "export-cslstm reads no compressed file: unpack it first (build reads it)"
        )
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
    """`traj` and `tracks` as one new MAT v5 file (ngsim_graphs.matfile), synced to disk:
    created exclusively, never through a link."""
    with create_exclusive(path) as handle:
        handle.write(matfile.header(description))
        matfile.write_single_matrix(handle, "traj", table.traj_blocks, TRAJ_COLUMNS)
        matfile.write_cell_array(handle, "tracks", (6, table.width), table.cells)
        handle.flush()
        os.fsync(handle.fileno())


def check_output(out: Path, overwrite: bool) -> None:
    """Refuse an --out that must not be replaced: anything but a new or empty folder or an
    earlier export beyond doubt (its marker's files, each of the sha256 it records, and nothing
    else), and that without `overwrite`."""
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "exists and is not a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return
    listed = _marker_digests(out)
    if listed is None:
        entries = sorted(p.name for p in out.iterdir())
        ours = [name for name in (*FILE_NAMES.values(), MARKER) if name in entries]
        if not ours:
            raise NgsimOutputError(
                out,
                f"folder is not empty and holds no export: it holds {some_names(entries)}; "
                "choose a new or empty --out",
            )
        raise NgsimOutputError(
            out / ours[0],
            f"was not written by export-cslstm (no {MARKER} of it lists its sha256): not "
            "replaced; choose another --out",
        )
    changed = [name for name, digest in listed.items() if _changed(out / name, digest)]
    foreign = changed + entries_beyond(out, {MARKER, *listed})
    if foreign:
        raise NgsimOutputError(
            out / foreign[0],
            f"was not written by export-cslstm (not listed in {out / MARKER}, or changed since): "
            "not replaced; move it away or choose another --out",
        )
    if not overwrite:
        raise NgsimOutputError(out, "holds an export already: --overwrite replaces it")


def _marker_digests(out: Path) -> dict[str, str] | None:
    """What the marker of an earlier export in `out` lists (file name -> sha256), or None where
    `out` holds no such marker: none, a link, another program's, one without sha256s."""
    document = landing.json_object(out / MARKER)
    if document is None or document.get("program") != PROGRAM:
        return None
    files = document.get("files")
    if not isinstance(files, dict) or not files:
        return None
    digests = {name: record.get("sha256") if isinstance(record, dict) else None
               for name, record in files.items()}  # fmt: skip
    if not set(digests) <= set(FILE_NAMES.values()) or not all(map(_is_sha256, digests.values())):
        return None
    return digests


def _changed(path: Path, digest: str) -> bool:
    """Whether a file an earlier export listed is there but not as it wrote it (a link too)."""
    if not os.path.lexists(path):
        return False
    return path.is_symlink() or not path.is_file() or file_sha256(path) != digest


def _is_sha256(value: object) -> bool:
    return isinstance(value, str) and re.fullmatch(r"[0-9a-f]{64}", value) is not None


def _write_marker(folder: Path, result: ExportResult) -> None:
    document = {
        "program": PROGRAM,
        "version": __version__,
        "files": {
            FILE_NAMES[name]: {"traj_rows": n, "sha256": file_sha256(folder / FILE_NAMES[name])}
            for name, n in result.rows.items()
        },
        "tracks_width": {FILE_NAMES[name]: n for name, n in result.tracks_width.items()},
        "missing_recordings": result.missing,
        "datasets": [asdict(d) for d in result.datasets],
        "inputs": [asdict(i) for i in result.inputs],
    }
    with create_exclusive(folder / MARKER) as handle:
        handle.write((json.dumps(document, indent=2) + "\n").encode())


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
    with landing.output_directory(out, lambda target: check_output(target, overwrite)) as folder:
        try:
            for done, name in enumerate(SPLIT_NAMES):
                progress(f"writing {FILE_NAMES[name]}", done, len(SPLIT_NAMES))
                description = (
                    f"MATLAB 5.0 MAT-file, written by ngsim-graphs {__version__} export-cslstm: "
                    f"CS-LSTM's {FILE_NAMES[name]}"
                )
                with storage.writing(folder / FILE_NAMES[name]):  # a full disk names the file
                    write_mat(folder / FILE_NAMES[name], tables.pop(name), description)
        except ValueError as err:  # a table the MAT format cannot hold
            raise NgsimOutputError(out, f"cannot write the export: {err}") from None
        _write_marker(folder, result)
    return result
