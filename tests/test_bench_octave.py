"""bench/compare_octave.py's comparison finds a changed value and a changed cell, and nothing
between two equal exports (Octave itself is not needed)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
from scipy.io import loadmat
from test_cslstm_export import _tables, _write_six

from ngsim_graphs import matfile
from ngsim_graphs.cslstm_export import export_cslstm

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "compare_octave.py"


def _compare_module():  # type: ignore[no-untyped-def]
    sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("compare_octave", SCRIPT)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def _rewrite(path: Path, traj: np.ndarray, tracks: np.ndarray) -> None:
    cells = {index: tracks[index] for index in np.ndindex(tracks.shape) if tracks[index].size}
    with path.open("wb") as handle:
        handle.write(matfile.header("MATLAB 5.0 MAT-file"))
        matfile.write_single_matrix(handle, "traj", [traj], traj.shape[1])
        matfile.write_cell_array(handle, "tracks", tracks.shape, cells)


def test_compare_finds_each_difference(tmp_path: Path) -> None:
    compare = _compare_module().compare
    inputs = _write_six(tmp_path / "raw", _tables())
    export_cslstm(inputs, tmp_path / "a")
    export_cslstm(inputs, tmp_path / "b")
    assert compare(tmp_path / "a", tmp_path / "b") == []
    test = loadmat(tmp_path / "b" / "TestSet.mat")
    traj, tracks = test["traj"].copy(), test["tracks"]
    traj[2, 9] += 1
    first = next(i for i in np.ndindex(tracks.shape) if tracks[i].size)
    tracks[first] = tracks[first] + np.float32(0.5)
    _rewrite(tmp_path / "b" / "TestSet.mat", traj, tracks)
    problems = compare(tmp_path / "a", tmp_path / "b")
    assert len(problems) == 2
    assert problems[0].startswith(
        "TestSet.mat: traj differs in 1 values, first at row 3, column 10"
    )
    assert problems[1] == f"TestSet.mat: tracks cell {tuple(i + 1 for i in first)} differs"
