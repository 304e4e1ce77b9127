"""The build layout's writers: a failed write names the file it was writing."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import layout


def test_a_polars_disk_error_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(*_args: object, **_kwargs: object) -> None:
        raise pl.exceptions.ComputeError(
            "parquet: underlying IO error: No space left on device (os error 28)"
        )

    monkeypatch.setattr(pl.DataFrame, "write_parquet", full)
    with pytest.raises(OSError) as caught:
        layout.write_parquet(pl.DataFrame({"a": [1]}), tmp_path / "t" / "x.parquet")
    assert (caught.value.errno, caught.value.filename) == (
        errno.ENOSPC,
        str(tmp_path / "t" / "x.parquet"),
    )


def test_a_numpy_short_write_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def short(*_args: object, **_kwargs: object) -> None:
        raise OSError("100000 requested and 32752 written")

    monkeypatch.setattr(layout.np, "save", short)
    with pytest.raises(OSError) as caught:
        layout.write_arrays(tmp_path, {"a": np.zeros(3)})
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(tmp_path / "a.npy"))


def test_other_polars_errors_are_not_disk_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def bug(*_args: object, **_kwargs: object) -> None:
        raise pl.exceptions.SchemaError("a bug, not a disk")

    monkeypatch.setattr(pl.DataFrame, "write_parquet", bug)
    with pytest.raises(pl.exceptions.SchemaError):
        layout.write_parquet(pl.DataFrame({"a": [1]}), tmp_path / "x.parquet")
