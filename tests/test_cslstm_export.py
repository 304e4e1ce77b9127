"""ngsim_graphs.cslstm_export: the three .mat files against the plain-loop reference of the
script (cslstm_reference.reference_files), read back with scipy.io.loadmat as CS-LSTM's
ngsimDataset reads them; the inputs' formats; and what the export refuses."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_row, write_period_csv, write_portal, write_txt
from cslstm_reference import reference_files
from scipy.io import loadmat
from test_cslstm import _recording

from ngsim_graphs.cslstm import DATASET_IDS
from ngsim_graphs.cslstm_export import FILE_NAMES, MARKER, export_cslstm
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS

START_MS = {(r.location, r.period): r.start_epoch_ms for r in OFFICIAL_RECORDINGS}
KEY_OF = {dataset_id: key for key, dataset_id in DATASET_IDS.items()}


def _tables() -> dict[int, np.ndarray]:
    """Six small recordings (cslstm tests' generator) whose ids straddle the split limits."""
    return {dataset_id: _recording(10 + dataset_id, vehicles=16) for dataset_id in range(1, 7)}


def _rows(dataset_id: int, table: np.ndarray) -> list[dict[str, float]]:
    start = START_MS[KEY_OF[dataset_id]]
    return [
        make_row(int(v), int(f), float(x), float(y), start_ms=start, lane_id=int(lane))
        for v, f, x, y, lane in table
    ]


def _write_six(folder: Path, tables: dict[int, np.ndarray]) -> list[Path]:
    return [
        write_txt(folder / f"recording-{d}.txt", _rows(d, table)) for d, table in tables.items()
    ]


def _as_text_values(table: np.ndarray) -> np.ndarray:
    """The table as the text files hold it: 3 decimals, read back as float32."""
    return np.array([[float(f"{v:.3f}") for v in row] for row in table], dtype=np.float32)


def _assert_files_equal_reference(out: Path, tables: dict[int, np.ndarray]) -> None:
    reference = reference_files({d: _as_text_values(t) for d, t in tables.items()})
    for name, (traj, tracks) in reference.items():
        mat = loadmat(out / FILE_NAMES[name])
        assert mat["traj"].dtype == np.float32
        np.testing.assert_array_equal(mat["traj"], traj)
        cells = mat["tracks"]
        width = max(vehicle for _, vehicle in tracks)
        assert cells.dtype == object and cells.shape == (6, width)
        for d in range(1, 7):
            for vehicle in range(1, width + 1):
                cell = cells[d - 1, vehicle - 1]
                if (d, vehicle) in tracks:
                    assert cell.dtype == np.float32
                    np.testing.assert_array_equal(cell, tracks[(d, vehicle)])
                else:
                    assert cell.shape == (0, 0)


def test_export_equals_the_reference_of_the_script(tmp_path: Path) -> None:
    tables = _tables()
    inputs = _write_six(tmp_path / "raw", tables)
    result = export_cslstm(inputs, tmp_path / "out")
    _assert_files_equal_reference(tmp_path / "out", tables)
    assert sum(d.rows for d in result.datasets) == sum(len(t) for t in tables.values())
    assert any(d.short_vehicles > 0 for d in result.datasets)  # the generator makes some
    assert all(n > 0 for n in result.rows.values())
    assert [d.dataset_id for d in result.datasets] == [1, 2, 3, 4, 5, 6]
    marker = json.loads((tmp_path / "out" / MARKER).read_text())
    assert marker["program"] == "ngsim-graphs export-cslstm" and marker["missing_recordings"] == []
    assert {name: f["traj_rows"] for name, f in marker["files"].items()} == {
        FILE_NAMES[name]: n for name, n in result.rows.items()
    }
    for name, record in marker["files"].items():
        assert (
            record["sha256"] == hashlib.sha256((tmp_path / "out" / name).read_bytes()).hexdigest()
        )
    assert not list((tmp_path / "out").glob(".*"))  # no partial files left
    assert not list(tmp_path.glob(".out.*"))  # no lock, no partial folder


def test_a_sample_reads_as_ngsim_dataset_reads_it(tmp_path: Path) -> None:
    """CS-LSTM's loader: the sample's track is tracks[d-1][v-1] transposed, the history is every
    2nd row from 30 rows before the sample's frame, relative to the sample's position."""
    tables = _tables()
    export_cslstm(_write_six(tmp_path / "raw", tables), tmp_path / "out")
    mat = loadmat(tmp_path / "out" / "TrainSet.mat")
    traj, tracks = mat["traj"], mat["tracks"]
    d, v, t = int(traj[0, 0]), int(traj[0, 1]), traj[0, 2]
    track = tracks[d - 1][v - 1].transpose()  # (n, 3): frame, x, y
    now = np.flatnonzero(track[:, 0] == t)[0]
    assert now >= 30 and track[-1, 0] > t + 1  # the edge filter
    history = track[now - 30 : now + 1 : 2, 1:3] - track[now, 1:3]
    assert history.shape == (16, 2) and (history[-1] == 0).all()
    np.testing.assert_array_equal(track[now, 1:3], traj[0, 3:5])


def test_portal_csv_gives_the_same_files(tmp_path: Path) -> None:
    """All six recordings in one portal CSV, vehicles in another order, with the portal's quirks
    and rows of another location: the same files as from the six text files. Recordings of 20
    vehicles: beside a larger one of its location, a group of fewer is stray rows."""
    tables = {dataset_id: _recording(10 + dataset_id, vehicles=20) for dataset_id in range(1, 7)}
    export_cslstm(_write_six(tmp_path / "raw", tables), tmp_path / "txt")
    rows, locations = [], []
    for d, table in tables.items():
        for vehicle in np.unique(table[:, 0])[::-1]:  # the vehicles in reverse, each in order
            own = _rows(d, table[table[:, 0] == vehicle])
            rows += own
            locations += [KEY_OF[d][0]] * len(own)
    rows.append(make_row(1, 5, lane_id=1))
    locations.append("lankershim")
    portal = write_portal(tmp_path / "portal.csv", rows, locations)
    result = export_cslstm([portal], tmp_path / "portal")
    assert result.inputs[0].rows_other_locations == 1
    for name in FILE_NAMES.values():
        ours, theirs = loadmat(tmp_path / "txt" / name), loadmat(tmp_path / "portal" / name)
        np.testing.assert_array_equal(ours["traj"], theirs["traj"])
        assert ours["tracks"].shape == theirs["tracks"].shape


def test_a_missing_recording_is_an_error_unless_allow_partial(tmp_path: Path) -> None:
    tables = _tables()
    inputs = _write_six(tmp_path / "raw", tables)[:-1]  # no i-80 0515-0530
    with pytest.raises(NgsimInputError, match="no rows of i-80/0515-0530.*--allow-partial"):
        export_cslstm(inputs, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    result = export_cslstm(inputs, tmp_path / "out", allow_partial=True)
    assert result.missing == ["i-80/0515-0530"]
    traj = loadmat(tmp_path / "out" / "TrainSet.mat")["traj"]
    assert set(np.unique(traj[:, 0])) == {1, 2, 3, 4, 5}  # dataset ids unchanged
    assert loadmat(tmp_path / "out" / "TrainSet.mat")["tracks"].shape[0] == 6


def test_a_recording_given_twice_is_an_error(tmp_path: Path) -> None:
    tables = _tables()
    inputs = _write_six(tmp_path / "raw", tables)
    again = write_txt(tmp_path / "again.txt", _rows(2, tables[2]))
    with pytest.raises(NgsimInputError, match="again.txt: holds the recording us-101/0805am"):
        export_cslstm([*inputs, again], tmp_path / "out")


def test_a_recording_not_of_the_six_is_an_error(tmp_path: Path) -> None:
    other = write_txt(
        tmp_path / "us-101" / "late.txt",
        [make_row(1, f, start_ms=START_MS[KEY_OF[1]] + 3_600_000) for f in range(40)],
    )
    with pytest.raises(
        NgsimInputError, match="late.txt: holds the recording us-101/0849-0849, none of the six"
    ):
        export_cslstm([other], tmp_path / "out", allow_partial=True)


def test_an_empty_required_field_is_counted_and_its_row_left_out(tmp_path: Path) -> None:
    """A per-period CSV row without Lane_ID: counted with its line; the files are the script's
    on the other rows."""
    tables = _tables()
    inputs = _write_six(tmp_path / "raw", tables)
    rows = _rows(1, tables[1])
    rows[3] = {**rows[3], "lane_id": None}
    inputs[0].unlink()
    inputs[0] = write_period_csv(tmp_path / "raw" / "recording-1.csv", rows)
    result = export_cslstm(inputs, tmp_path / "out")
    report = next(i for i in result.inputs if i.path.endswith("recording-1.csv"))
    assert (report.rows_missing_values, report.first_missing_line) == (1, 5)  # header: line 1
    _assert_files_equal_reference(tmp_path / "out", {**tables, 1: np.delete(tables[1], 3, 0)})


def test_the_output_folder_is_replaced_only_when_ours(tmp_path: Path) -> None:
    inputs = _write_six(tmp_path / "raw", _tables())
    out = tmp_path / "out"
    export_cslstm(inputs, out)
    with pytest.raises(NgsimOutputError, match="holds an export already: --overwrite"):
        export_cslstm(inputs, out)
    export_cslstm(inputs, out, overwrite=True)
    foreign = tmp_path / "theirs"
    foreign.mkdir()
    (foreign / "TestSet.mat").write_bytes(b"someone else's")
    with pytest.raises(
        NgsimOutputError, match="TestSet.mat: was not written by export-cslstm \\(no"
    ):
        export_cslstm(inputs, foreign, overwrite=True)
    assert (foreign / "TestSet.mat").read_bytes() == b"someone else's"
    assert not (foreign / "TrainSet.mat").exists()
