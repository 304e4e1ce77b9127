"""ngsim_graphs.matfile: what it writes, read back with scipy.io.loadmat."""

from __future__ import annotations

import io

import numpy as np
import pytest
from scipy.io import loadmat

from ngsim_graphs import matfile


def _read(data: bytes) -> dict:
    return loadmat(io.BytesIO(data))


def test_a_matrix_of_blocks_and_a_cell_array_read_back_exactly() -> None:
    rng = np.random.default_rng(0)
    blocks = [rng.normal(size=(n, 5)).astype(np.float32) for n in (3, 0, 7, 1)]
    cells = {(0, 0): np.arange(3, dtype=np.float32).reshape(3, 1), (2, 1): blocks[2][:, :3].T}
    handle = io.BytesIO()
    handle.write(matfile.header("MATLAB 5.0 MAT-file, a test"))
    matfile.write_single_matrix(handle, "traj", blocks, 5)
    matfile.write_cell_array(handle, "tracks", (3, 2), cells)
    data = handle.getvalue()
    assert data[:27] == b"MATLAB 5.0 MAT-file, a test" and data[124:128] == b"\x00\x01IM"
    mat = _read(data)
    assert mat["traj"].dtype == np.float32
    np.testing.assert_array_equal(mat["traj"], np.concatenate(blocks))
    tracks = mat["tracks"]
    assert tracks.dtype == object and tracks.shape == (3, 2)
    for row in range(3):
        for column in range(2):
            cell = tracks[row, column]
            if (row, column) in cells:
                assert cell.dtype == np.float32
                np.testing.assert_array_equal(cell, cells[(row, column)])
            else:
                assert cell.shape == (0, 0) and cell.dtype == np.float64  # MATLAB's []


def test_empty_matrix_and_names_of_every_length_mod_8() -> None:
    handle = io.BytesIO()
    handle.write(matfile.header("MATLAB 5.0 MAT-file"))
    names = ["a", "ab_cdefgh", "abcdefgh", "x2345"]
    for name in names:
        matfile.write_single_matrix(handle, name, [np.zeros((0, 47), np.float32)], 47)
    matfile.write_cell_array(handle, "empty", (6, 0), {})
    mat = _read(handle.getvalue())
    for name in names:
        assert mat[name].shape == (0, 47) and mat[name].dtype == np.float32
    assert mat["empty"].shape == (6, 0)
    assert len(handle.getvalue()) % 8 == 0


def test_a_variable_over_4_gib_is_refused() -> None:
    with pytest.raises(ValueError, match="traj: .* over MAT v5's 4 GiB per variable"):
        matfile._matrix_head(matfile.MX_SINGLE, 2**30, 1, "traj", 2**32)
