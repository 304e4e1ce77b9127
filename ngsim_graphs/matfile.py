"""MAT-file version 5, as far as CS-LSTM's files need it: a float32 matrix and a cell array.

Written from MathWorks' "MAT-File Format" (version 5, uncompressed, little-endian): a 128-byte
header, then one miMATRIX element per variable. A matrix is stored column by column, so the
writer takes a float32 matrix as blocks of rows and writes each column of each block in turn:
no copy of the whole matrix is ever made (a 7-million-row `traj` is 1.3 GB). `scipy.io.loadmat`,
MATLAB and GNU Octave read the files; tests/test_matfile.py reads them back with scipy.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from typing import BinaryIO

import numpy as np

MI_INT8, MI_INT32, MI_UINT32, MI_SINGLE, MI_DOUBLE, MI_MATRIX = 1, 5, 6, 7, 9, 14
MX_CELL, MX_DOUBLE, MX_SINGLE = 1, 6, 7
MAX_ELEMENT_BYTES = 2**32 - 1  # a tag's byte count is a uint32


def _padding(size: int) -> bytes:
    return b"\0" * (-size % 8)


def _tag(data_type: int, size: int) -> bytes:
    return struct.pack("<II", data_type, size)


def header(description: str) -> bytes:
    """The 128-byte file header: text, no subsystem data, version 0x0100, little-endian."""
    text = description.encode("ascii")[:116].ljust(116, b" ")
    return text + b"\0" * 8 + struct.pack("<H", 0x0100) + b"IM"


def _array_head(class_id: int, rows: int, columns: int, name: str) -> bytes:
    """What every miMATRIX element starts with after its tag: array flags, dimensions, name."""
    encoded = name.encode("ascii")
    return (
        _tag(MI_UINT32, 8)
        + struct.pack("<II", class_id, 0)
        + _tag(MI_INT32, 8)
        + struct.pack("<ii", rows, columns)
        + _tag(MI_INT8, len(encoded))
        + encoded
        + _padding(len(encoded))
    )


def _matrix_tag(name: str, size: int) -> bytes:
    """The miMATRIX tag of an element of `size` bytes after it; over 4 GiB is refused."""
    if size > MAX_ELEMENT_BYTES:
        raise ValueError(f"{name or 'a cell'}: {size:,} bytes, over MAT v5's 4 GiB per variable")
    return _tag(MI_MATRIX, size)


def _matrix_head(class_id: int, rows: int, columns: int, name: str, data_bytes: int) -> bytes:
    """A numeric miMATRIX element up to its data: tag, array head and the data's tag
    (`data_bytes` of single or double values follow, then padding to 8 bytes)."""
    head = _array_head(class_id, rows, columns, name)
    tag = _matrix_tag(name, len(head) + 8 + data_bytes + len(_padding(data_bytes)))
    data_type = MI_SINGLE if class_id == MX_SINGLE else MI_DOUBLE
    return tag + head + _tag(data_type, data_bytes)


def write_single_matrix(
    handle: BinaryIO, name: str, blocks: Sequence[np.ndarray], columns: int
) -> None:
    """A float32 matrix made of `blocks` of rows, (n_i, columns) each, stacked in order."""
    rows = sum(len(block) for block in blocks)
    data_bytes = rows * columns * 4
    handle.write(_matrix_head(MX_SINGLE, rows, columns, name, data_bytes))
    for column in range(columns):
        for block in blocks:
            handle.write(np.ascontiguousarray(block[:, column], dtype="<f4").data)
    handle.write(_padding(data_bytes))


def _cell_element(value: np.ndarray | None) -> bytes:
    """One cell: a float32 matrix, or MATLAB's `[]` (a 0 x 0 double) where `value` is None."""
    if value is None:
        return _matrix_head(MX_DOUBLE, 0, 0, "", 0)
    data = np.asfortranarray(value, dtype="<f4")
    raw = data.tobytes(order="F")
    return _matrix_head(MX_SINGLE, *data.shape, "", len(raw)) + raw + _padding(len(raw))


def write_cell_array(
    handle: BinaryIO, name: str, shape: tuple[int, int], cells: Mapping[tuple[int, int], np.ndarray]
) -> None:
    """A (rows, columns) cell array; `cells` maps 0-based (row, column) to a 2-D float32 matrix,
    every other cell is `[]`."""
    rows, columns = shape
    parts = [
        _cell_element(cells.get((row, column))) for column in range(columns) for row in range(rows)
    ]
    head = _array_head(MX_CELL, rows, columns, name)
    handle.write(_matrix_tag(name, len(head) + sum(len(part) for part in parts)) + head)
    for part in parts:
        handle.write(part)
