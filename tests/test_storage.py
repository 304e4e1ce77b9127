"""How a build's files are written: a failed write names the file it was writing; tables and
arrays written by parts are what writing them whole gives."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import storage
from ngsim_graphs.engine import staging


def _full_disk(*_args: object, **_kwargs: object) -> None:
    """What Polars raises when the disk fills while it writes a Parquet file."""
    raise pl.exceptions.ComputeError(
        "parquet: underlying IO error: No space left on device (os error 28)"
    )


def test_a_polars_disk_error_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pl.DataFrame, "write_parquet", _full_disk)
    with pytest.raises(OSError) as caught:
        storage.write_parquet(pl.DataFrame({"a": [1]}), tmp_path / "t" / "x.parquet")
    assert (caught.value.errno, caught.value.filename) == (
        errno.ENOSPC,
        str(tmp_path / "t" / "x.parquet"),
    )


def test_a_numpy_short_write_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def short(*_args: object, **_kwargs: object) -> None:
        raise OSError("100000 requested and 32752 written")

    monkeypatch.setattr(storage.np, "save", short)
    with pytest.raises(OSError) as caught:
        storage.write_arrays(tmp_path, {"a": np.zeros(3)})
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(tmp_path / "a.npy"))


def test_a_full_disk_while_streaming_a_table_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pl.LazyFrame, "sink_parquet", _full_disk)
    path = tmp_path / "samples" / "val.parquet"
    with pytest.raises(OSError) as caught:
        storage.sink_parquet(pl.LazyFrame({"a": [1]}), path)
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(path))


def test_a_short_write_of_an_appended_array_names_the_file_and_leaves_none(
    tmp_path: Path,
) -> None:
    class FullDisk:  # the file after its first part: the disk is full
        def __init__(self, real: object) -> None:
            self.real = real

        def write(self, data: object) -> int:
            raise OSError("100000 requested and 32752 written")

        def __getattr__(self, name: str) -> object:
            return getattr(self.real, name)

    appender = storage.ArrayAppender(tmp_path, ("start_step",))
    appender.append({"start_step": np.arange(3, dtype=np.int32)})
    appender._files["start_step"] = FullDisk(appender._files["start_step"])
    with pytest.raises(OSError) as caught, appender:
        appender.append({"start_step": np.arange(5, dtype=np.int32)})
    path = tmp_path / "start_step.npy"
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(path))
    assert not path.exists()


def test_other_polars_errors_are_not_disk_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def bug(*_args: object, **_kwargs: object) -> None:
        raise pl.exceptions.SchemaError("a bug, not a disk")

    monkeypatch.setattr(pl.DataFrame, "write_parquet", bug)
    with pytest.raises(pl.exceptions.SchemaError):
        storage.write_parquet(pl.DataFrame({"a": [1]}), tmp_path / "x.parquet")


PARTS = [
    np.arange(6, dtype=np.int32).reshape(3, 2),
    np.empty((0, 2), np.int32),
    np.arange(8, 12, dtype=np.int32).reshape(2, 2),
]


def test_arrays_appended_part_by_part_are_what_np_save_writes_of_them_at_once(
    tmp_path: Path,
) -> None:
    with storage.ArrayAppender(tmp_path / "parts", ("rows", "key")) as appender:
        for part in PARTS:
            appender.append({"rows": part, "key": part[:, 0] * 0.5})
    whole = np.concatenate(PARTS)
    np.save(tmp_path / "rows.npy", whole)
    np.save(tmp_path / "key.npy", whole[:, 0] * 0.5)
    for name in ("rows", "key"):
        assert (tmp_path / "parts" / f"{name}.npy").read_bytes() == (
            tmp_path / f"{name}.npy"
        ).read_bytes()
    opened = storage.open_arrays(tmp_path / "parts", ("rows", "key"))
    assert opened["rows"].tolist() == [[0, 1], [2, 3], [4, 5], [8, 9], [10, 11]]
    assert opened["key"].tolist() == [0.0, 1.0, 2.0, 4.0, 5.0]


def test_a_part_of_another_dtype_or_shape_fails_and_leaves_no_file(tmp_path: Path) -> None:
    for wrong in (PARTS[0].astype(np.int64), np.zeros((2, 3), np.int32)):
        with (
            pytest.raises(ValueError, match="a part"),
            storage.ArrayAppender(tmp_path, ("rows",)) as appender,
        ):
            appender.append({"rows": PARTS[0]})
            appender.append({"rows": wrong})
        assert not (tmp_path / "rows.npy").exists()


def test_a_table_appended_part_by_part_is_one_record_batch_a_part(tmp_path: Path) -> None:
    import pyarrow as pa

    schema = pl.Schema({"step": pl.Int32, "distance_m": pl.Float64})
    parts = [
        pl.DataFrame({"step": [0, 0, 1], "distance_m": [1.5, 2.0, 0.25]}, schema=schema),
        pl.DataFrame({"step": [4], "distance_m": [9.0]}, schema=schema),
    ]
    path = tmp_path / "table.arrow"
    with storage.TableAppender(path, schema) as table:
        for part in parts:
            table.append(part)
    read = pl.read_ipc(path)
    assert read.schema == schema
    assert read.rows() == [(0, 1.5), (0, 2.0), (1, 0.25), (4, 9.0)]
    assert pa.ipc.open_file(path).num_record_batches == 2
    with pytest.raises(RuntimeError), storage.TableAppender(path, schema) as table:
        table.append(parts[0])
        raise RuntimeError("a failure while building")
    assert not path.exists()


_SINK_SCRIPT = """
import sys
from pathlib import Path
import polars as pl
from ngsim_graphs import storage
storage.SINK_ROW_GROUP_ROWS = 1_000
root = Path(sys.argv[1])
parts = [pl.scan_parquet(root / f"part-{i}.parquet") for i in range(3)]
storage.sink_parquet(pl.concat(parts).with_row_index("sample_id"), root / sys.argv[2])
"""


def test_a_sunk_table_is_the_same_bytes_whatever_the_threads(tmp_path: Path) -> None:
    """Three staged parts streamed into one table by Polars with 1 and with 4 threads (a
    process each: Polars reads its number of threads once): row groups of SINK_ROW_GROUP_ROWS
    rows, not of the stream's chunks, so the same bytes; the rows are the parts' in order."""
    import subprocess
    import sys

    import pyarrow.parquet as pq

    rng = np.random.default_rng(3)
    parts = [
        pl.DataFrame({"track": rng.integers(0, 50, n, dtype=np.int32), "y_m": rng.random(n)})
        for n in (1_700, 0, 2_600)
    ]
    for i, part in enumerate(parts):
        staging.write_staged(part, tmp_path / f"part-{i}.parquet")
    for threads in (1, 4):
        env = {**os.environ, "POLARS_MAX_THREADS": str(threads)}
        subprocess.run(
            [sys.executable, "-c", _SINK_SCRIPT, str(tmp_path), f"sunk-{threads}.parquet"],
            env=env,
            check=True,
        )
    one, four = (
        (tmp_path / "sunk-1.parquet").read_bytes(),
        (tmp_path / "sunk-4.parquet").read_bytes(),
    )
    assert one == four
    metadata = pq.ParquetFile(tmp_path / "sunk-1.parquet").metadata
    groups = [metadata.row_group(i).num_rows for i in range(metadata.num_row_groups)]
    assert groups == [1_000, 1_000, 1_000, 1_000, 300]
    expected = pl.concat(parts).with_row_index("sample_id")
    assert pl.read_parquet(tmp_path / "sunk-1.parquet").equals(expected)
