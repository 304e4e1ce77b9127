"""The build layout's writers: a failed write names the file it was writing."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import straight_track, write_period_csv
from highd_fixtures import two_directions
from typer.testing import CliRunner

from ngsim_graphs import layout


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


def test_a_full_disk_while_streaming_a_table_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pl.LazyFrame, "sink_parquet", _full_disk)
    path = tmp_path / "samples" / "val.parquet"
    with pytest.raises(OSError) as caught:
        layout.sink_parquet(pl.LazyFrame({"a": [1]}), path)
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

    appender = layout.ArrayAppender(tmp_path, ("start_step",))
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
        layout.write_parquet(pl.DataFrame({"a": [1]}), tmp_path / "x.parquet")


PARTS = [
    np.arange(6, dtype=np.int32).reshape(3, 2),
    np.empty((0, 2), np.int32),
    np.arange(8, 12, dtype=np.int32).reshape(2, 2),
]


def test_arrays_appended_part_by_part_are_what_np_save_writes_of_them_at_once(
    tmp_path: Path,
) -> None:
    with layout.ArrayAppender(tmp_path / "parts", ("rows", "key")) as appender:
        for part in PARTS:
            appender.append({"rows": part, "key": part[:, 0] * 0.5})
    whole = np.concatenate(PARTS)
    np.save(tmp_path / "rows.npy", whole)
    np.save(tmp_path / "key.npy", whole[:, 0] * 0.5)
    for name in ("rows", "key"):
        assert (tmp_path / "parts" / f"{name}.npy").read_bytes() == (
            tmp_path / f"{name}.npy"
        ).read_bytes()
    opened = layout.open_arrays(tmp_path / "parts", ("rows", "key"))
    assert opened["rows"].tolist() == [[0, 1], [2, 3], [4, 5], [8, 9], [10, 11]]
    assert opened["key"].tolist() == [0.0, 1.0, 2.0, 4.0, 5.0]


def test_a_part_of_another_dtype_or_shape_fails_and_leaves_no_file(tmp_path: Path) -> None:
    for wrong in (PARTS[0].astype(np.int64), np.zeros((2, 3), np.int32)):
        with (
            pytest.raises(ValueError, match="a part"),
            layout.ArrayAppender(tmp_path, ("rows",)) as appender,
        ):
            appender.append({"rows": PARTS[0]})
            appender.append({"rows": wrong})
        assert not (tmp_path / "rows.npy").exists()


def test_a_table_appended_part_by_part_is_one_row_group_a_part(tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    schema = pl.Schema({"step": pl.Int32, "distance_m": pl.Float64})
    parts = [
        pl.DataFrame({"step": [0, 0, 1], "distance_m": [1.5, 2.0, 0.25]}, schema=schema),
        pl.DataFrame({"step": [4], "distance_m": [9.0]}, schema=schema),
    ]
    path = tmp_path / "table.parquet"
    with layout.TableAppender(path, schema) as table:
        for part in parts:
            table.append(part)
    read = pl.read_parquet(path)
    assert read.schema == schema
    assert read.rows() == [(0, 1.5), (0, 2.0), (1, 0.25), (4, 9.0)]
    assert pq.ParquetFile(path).metadata.num_row_groups == 2
    with pytest.raises(RuntimeError), layout.TableAppender(path, schema) as table:
        table.append(parts[0])
        raise RuntimeError("a failure while building")
    assert not path.exists()


_SINK_SCRIPT = """
import sys
from pathlib import Path
import polars as pl
from ngsim_graphs import layout
layout.SINK_ROW_GROUP_ROWS = 1_000
root = Path(sys.argv[1])
parts = [pl.scan_parquet(root / f"part-{i}.parquet") for i in range(3)]
layout.sink_parquet(pl.concat(parts).with_row_index("sample_id"), root / sys.argv[2])
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
        layout.write_staged(part, tmp_path / f"part-{i}.parquet")
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


def _not_builds(root: Path, tiny_build: Path, tiny_run: Path) -> dict[str, tuple[Path, str]]:
    """Folders (and a file) a user may give where a build is expected, and what each is said
    to be."""
    ngsim = root / "ngsim-raw"
    write_period_csv(
        ngsim / "us-101" / "trajectories-0750am-0805am.csv", straight_track(1, range(9))
    )
    highd = root / "highd-raw"
    two_directions(highd / "data", frames=range(1, 30))
    multi = root / "multi-run"
    (multi / "h2s").mkdir(parents=True)
    (multi / "horizons.json").write_text('{"horizons_s": [2.0], "members": ["h2s"]}')
    shutil.copyfile(tiny_run / "run.json", multi / "h2s" / "run.json")
    unfinished, other, empty = root / "unfinished", root / "other", root / "empty"
    for folder in (unfinished / layout.STAGING_DIR, unfinished / layout.TRACKS_DIR, other, empty):
        folder.mkdir(parents=True)
    (other / "notes.txt").write_text("not a trajectory\n")
    raw_file = ngsim / "us-101" / "trajectories-0750am-0805am.csv"
    run_says = f"an aigem run, not a build; its build is {tiny_build.resolve()}"
    return {
        "ngsim": (ngsim, f"holds NGSIM/highD trajectory files, not a build: build one with "
                  f"`ngsim-graphs build {ngsim} --out BUILD`"),
        "highd": (highd, f"holds NGSIM/highD trajectory files, not a build: build one with "
                  f"`ngsim-graphs build {highd} --out BUILD`"),
        "raw file": (raw_file, f"an NGSIM/highD trajectory file, not a build: build one with "
                     f"`ngsim-graphs build {raw_file} --out BUILD`"),
        "run": (tiny_run, run_says),
        "multi-horizon run": (multi, run_says),
        "empty": (empty, "an empty folder, not a build"),
        "unfinished": (unfinished, "an unfinished build (interrupted?): no manifest.json"),
        "other": (other, "not a build: no manifest.json"),
    }  # fmt: skip


def test_what_a_folder_is_where_a_build_is_expected(
    tiny_build: Path, tiny_run: Path, tmp_path: Path
) -> None:
    from aigem import runs  # torch loads only for the tests that use it
    from ngsim_cli.aigem import app as aigem_app
    from ngsim_cli.ngsim import app as ngsim_app

    out = tmp_path / "out"
    commands = {
        "stats": (ngsim_app, ["stats", "{}"]),
        "show": (ngsim_app, ["show", "{}", "--out", f"{out}.png"]),
        "export": (ngsim_app, ["export", "{}", "--out", str(out)]),
        "verify": (ngsim_app, ["verify", "{}"]),
        "fit": (aigem_app, ["fit", "{}", "--out", str(out), "--epochs", "1", "--device", "cpu"]),
        "evaluate": (aigem_app, ["evaluate", str(tiny_run), "--data", "{}", "--device", "cpu"]),
    }
    runner = CliRunner(env={"COLUMNS": "200"})
    for kind, (path, says) in _not_builds(tmp_path, tiny_build, tiny_run).items():
        for name, (app, args) in commands.items():
            result = runner.invoke(app, [arg.format(path) for arg in args])
            assert (result.exit_code, result.stderr.strip()) == (1, f"error: {path}: {says}"), (
                kind,
                name,
                result.output,
            )
            assert not out.exists() and not Path(f"{out}.png").exists()
    assert layout.RUN_INFO_NAME == runs.RUN_INFO and layout.RUN_HORIZONS_NAME == runs.HORIZONS
