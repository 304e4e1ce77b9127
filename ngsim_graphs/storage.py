"""How a build's files are written and read back: Parquet tables (whole or streamed), staged
Arrow IPC tables (a part at a time), .npy arrays (whole or a part at a time, mapped into
memory), and the OS error of a failed write named with its file.

Equal tables and arrays give equal bytes: the options are fixed here (`layout` says where each
file goes).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from ngsim_graphs.errors import NgsimInputError

PARQUET_COMPRESSION = "zstd"

_RUST_OS_ERROR = re.compile(r"os error (\d+)")  # how polars reports an OS error it met


def os_errno(err: BaseException) -> int | None:
    """The OS error number of `err`, also where polars only names it in its message."""
    if isinstance(err, OSError) and err.errno is not None:
        return err.errno
    found = _RUST_OS_ERROR.search(str(err))
    return int(found.group(1)) if found else None


@contextmanager
def writing(path: Path) -> Iterator[None]:
    """Name `path` in the OSError of a failed write (a full disk): polars and numpy do not."""
    try:
        yield
    except (OSError, pl.exceptions.PolarsError) as err:
        if isinstance(err, OSError) and err.filename:
            raise
        code = os_errno(err)
        if code is None and not isinstance(err, OSError):
            raise  # not an OS error: a bug, not a disk
        # numpy's short write ("N requested and M written") carries no number: a full disk
        code = code or errno.ENOSPC
        raise OSError(code, os.strerror(code), str(path)) from err


def write_arrays(folder: Path, arrays: dict[str, np.ndarray]) -> None:
    """One .npy file per array, to be opened memory-mapped."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, array in arrays.items():
        path = folder / f"{name}.npy"
        with writing(path):
            np.save(path, np.ascontiguousarray(array), allow_pickle=False)


class ArrayAppender:
    """.npy files written a part at a time along their first axis: each file holds what
    `np.save` of its parts concatenated writes, byte for byte, without holding them together.

    `append` the parts, then `close`. The header is written first and rewritten by `close` with
    the final length: numpy leaves room in it for the first axis to grow.
    """

    def __init__(self, folder: Path, names: tuple[str, ...]) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self._paths = {name: folder / f"{name}.npy" for name in names}
        self._files: dict[str, Any] = {}
        self._headers: dict[str, dict[str, Any]] = {}
        self._data_at: dict[str, int] = {}

    def append(self, arrays: dict[str, np.ndarray]) -> None:
        for name, array in arrays.items():
            array = np.ascontiguousarray(array)
            with writing(self._paths[name]):
                if name not in self._files:
                    handle = self._files[name] = self._paths[name].open("wb")
                    self._headers[name] = np.lib.format.header_data_from_array_1_0(array[:0])
                    np.lib.format.write_array_header_1_0(handle, self._headers[name])
                    self._data_at[name] = handle.tell()
                header = self._headers[name]
                if array.dtype.str != header["descr"] or array.shape[1:] != header["shape"][1:]:
                    raise ValueError(f"{name}: a part {array.dtype} {array.shape} after {header}")
                header["shape"] = (header["shape"][0] + len(array), *array.shape[1:])
                self._files[name].write(array.data)

    def close(self) -> None:
        """Finish every file with its final header (a name never appended to is not written)."""
        try:
            for name, handle in self._files.items():
                with writing(self._paths[name]):
                    handle.seek(0)
                    np.lib.format.write_array_header_1_0(handle, self._headers[name])
                    if handle.tell() != self._data_at[name]:  # numpy's header format changed
                        raise ValueError(f"{self._paths[name]}: the .npy header changed length")
                    handle.close()
        except BaseException:
            self._abandon()
            raise
        self._files = {}

    def _abandon(self) -> None:
        """Close and delete every file: none is left whose header is not its content."""
        for name, handle in self._files.items():
            with contextlib.suppress(OSError):
                handle.close()
            self._paths[name].unlink(missing_ok=True)
        self._files = {}

    def __enter__(self) -> ArrayAppender:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abandon()


class TableAppender:
    """A table written a part at a time, the parts never held together: an Arrow IPC file, a
    record batch a part, uncompressed (what a build stages for itself, written and read back
    at memory speed). Use as a context manager: after an error, no file is left."""

    def __init__(self, path: Path, schema: pl.Schema) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._path = path
        arrow_schema = pl.DataFrame(schema=schema).to_arrow().schema
        with writing(path):
            self._writer = pa.ipc.new_file(path, arrow_schema)

    def append(self, frame: pl.DataFrame) -> None:
        with writing(self._path):
            self._writer.write_table(frame.to_arrow())

    def __enter__(self) -> TableAppender:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_exc: object) -> None:
        try:
            with writing(self._path):
                self._writer.close()
        except BaseException:
            self._path.unlink(missing_ok=True)
            if exc_type is None:
                raise
        if exc_type is not None:  # the error that stopped the writing is the one raised
            self._path.unlink(missing_ok=True)


def open_arrays(folder: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Memory-map the named .npy files of `folder`: nothing is read until it is used.

    The maps are returned as plain ndarray views: indexing an `np.memmap` object costs
    microseconds of Python per call, which the loader's many small gathers would pay.
    """
    missing = [n for n in names if not (folder / f"{n}.npy").is_file()]
    if missing:
        raise NgsimInputError(folder, f"incomplete build: missing arrays {', '.join(missing)}")
    return {name: _map_array(folder / f"{name}.npy") for name in names}


def _map_array(path: Path) -> np.ndarray:
    try:
        return np.asarray(np.load(path, mmap_mode="r", allow_pickle=False))
    except (ValueError, OSError, EOFError) as err:  # a bad header, or a file shorter than it says
        raise NgsimInputError(path, f"unreadable array: {err}") from None


def write_parquet(frame: pl.DataFrame, path: Path) -> None:
    """Write a table with the project's fixed options (reproducible bytes for equal frames)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with writing(path):
        frame.write_parquet(path, compression=PARQUET_COMPRESSION, statistics=True)


# Rows per row group of a table streamed by `sink_parquet`: fixed, so that the bytes written do
# not depend on how Polars' threads cut the stream.
SINK_ROW_GROUP_ROWS = 131_072


def sink_parquet(table: pl.LazyFrame, path: Path) -> None:
    """Write a lazy table as it streams through, with `write_parquet`'s options: never held
    whole, and the same bytes for the same rows whatever the number of threads."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with writing(path):
        table.sink_parquet(
            path,
            compression=PARQUET_COMPRESSION,
            statistics=True,
            row_group_size=SINK_ROW_GROUP_ROWS,
            maintain_order=True,
        )
