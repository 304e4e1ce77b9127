"""What `build`, `synth` and `export` may write, through the CLI: never over what is not theirs,
never into or over an input, one build of a directory at a time, and a full disk reported as one
line naming the file, with the output as it was before and nothing left beside it."""

from __future__ import annotations

import errno
import fcntl
import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import polars as pl
import pytest
from conftest import straight_track, write_txt
from typer.testing import CliRunner, Result

from ngsim_cli.ngsim import app
from ngsim_graphs import lock, storage
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.export import EXPORT_MARKER, export_tables
from ngsim_graphs.layout import BUILD_LOG
from ngsim_graphs.synth import formats as synthesis
from ngsim_graphs.synth.folder import PORTAL_FILE_NAME
from ngsim_graphs.synth.formats import write_synthetic
from ngsim_graphs.synth.marker import MARKER_NAME

NGSIM_FILE = "trajectories-0750am-0805am.txt"
EXPORT_FILES = sorted([EXPORT_MARKER, *(f"{name}.parquet" for name in export_tables())])


def invoke(*args: object) -> Result:
    return CliRunner(env={"COLUMNS": "60"}).invoke(app, [str(a) for a in args])


def files(root: Path) -> dict[str, bytes]:
    """Every file under `root` (relative path -> bytes); empty when `root` does not exist."""
    if not root.exists():
        return {}
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def error_line(result: Result) -> str:
    """The one line of a handled failure: status 1, nothing on stdout, no traceback."""
    assert result.exit_code == 1, result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.stdout == ""
    assert len(result.stderr.splitlines()) == 1, result.stderr
    return result.stderr.strip()


@pytest.fixture
def raw(tmp_path: Path) -> Path:
    """A folder holding one tiny NGSIM text file (two vehicles, 11 s: a window each)."""
    rows = straight_track(1, range(10, 120), x_ft=6.0) + straight_track(
        2, range(10, 120), x_ft=18.0
    )
    write_txt(tmp_path / "raw" / NGSIM_FILE, rows)
    return tmp_path / "raw"


# --- build: what --out may be ----------------------------------------------------------------


def test_overwrite_keeps_a_folder_that_is_not_a_build(tmp_path: Path, raw: Path) -> None:
    out = tmp_path / "mine"
    (out / "sub").mkdir(parents=True)
    (out / "notes.txt").write_text("mine\n")
    (out / "sub" / "x.bin").write_bytes(b"\x00")
    before = files(out)
    line = error_line(invoke("build", raw, "--out", out, "--overwrite"))
    assert line == (
        f"error: {out}: directory is not empty and is not a build: it holds notes.txt, sub/; "
        "--overwrite replaces only a finished build (move them away or choose another --out)"
    )
    assert files(out) == before and siblings(out) == []


@pytest.mark.parametrize(
    ("out", "relation"), [("raw", "is"), (".", "contains"), ("raw/build", "lies inside")]
)
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_out_overlapping_the_input_is_refused(
    tmp_path: Path, raw: Path, out: str, relation: str, overwrite: list[str]
) -> None:
    before = files(tmp_path)
    line = error_line(invoke("build", raw, "--out", tmp_path / out, *overwrite))
    assert line == (
        f"error: {tmp_path / out}: --out {relation} the input {raw}; "
        "choose an --out outside the inputs"
    )
    assert files(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw"]


def test_building_twice_with_overwrite_replaces_the_build(tmp_path: Path, raw: Path) -> None:
    """README's first command, run twice."""
    out = tmp_path / "demo" / "build"
    assert invoke("build", raw, "--out", out, "--overwrite").exit_code == 0
    first = files(out)
    result = invoke("build", raw, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    again = files(out)
    assert again.pop(BUILD_LOG) and first.pop(BUILD_LOG)  # each build's own log (its times)
    assert again == first and "manifest.json" in first
    assert siblings(out) == []


def test_overwrite_keeps_an_unfinished_build_of_an_earlier_version(
    tmp_path: Path, raw: Path
) -> None:
    """Folders named as a build's, no manifest: not ours beyond doubt (builds land whole now)."""
    out = tmp_path / "out"
    (out / "tracks").mkdir(parents=True)
    (out / "tracks" / "us-101_0750am-0805am.parquet").write_bytes(b"PAR1 cut short")
    (out / "arrays" / "samples-train").mkdir(parents=True)
    before = files(out)
    line = error_line(invoke("build", raw, "--out", out, "--overwrite"))
    assert line == (
        f"error: {out}: directory is not empty and is not a build: it holds arrays/, tracks/; "
        "--overwrite replaces only a finished build (move them away or choose another --out)"
    )
    assert files(out) == before and siblings(out) == []


# --- build: nothing that is not its own -----------------------------------------------------


@pytest.fixture
def built(tmp_path: Path, raw: Path) -> Path:
    out = tmp_path / "b"
    assert invoke("build", raw, "--out", out).exit_code == 0
    return out


def _folder(path: Path, content: str = "precious\n") -> dict[str, bytes]:
    path.mkdir(parents=True, exist_ok=True)
    (path / "keep.txt").write_text(content)
    return files(path)


@pytest.mark.parametrize("name", [".b.old-backup", ".b.partial-notes", ".b.partial-123"])
def test_folders_named_like_a_builds_leftovers_are_not_touched(
    tmp_path: Path, raw: Path, built: Path, name: str
) -> None:
    mine = _folder(tmp_path / name)
    result = invoke("build", raw, "--out", built, "--overwrite")
    assert result.exit_code == 0, result.output
    assert files(tmp_path / name) == mine
    assert siblings(built) == [name]


def test_a_hidden_old_folder_is_not_taken_for_a_missing_out(tmp_path: Path, raw: Path) -> None:
    mine = _folder(tmp_path / ".c.old-2024")
    result = invoke("build", raw, "--out", tmp_path / "c")
    assert result.exit_code == 0, result.output
    assert files(tmp_path / ".c.old-2024") == mine
    assert (tmp_path / "c" / "manifest.json").is_file() and not (tmp_path / "c/keep.txt").exists()


def test_a_lock_path_that_is_a_link_is_refused_not_followed(tmp_path: Path, raw: Path) -> None:
    out, victim = tmp_path / "e", tmp_path / "victim.txt"
    victim.write_text("precious-content")
    lock.lock_path(out).symlink_to(victim)
    line = error_line(invoke("build", raw, "--out", out))
    assert line == (
        f"error: {lock.lock_path(out)}: is a symbolic link, not a lock of ngsim-graphs: left as "
        f"it is, and {out} not written (remove it if no program is writing {out}, or choose "
        "another --out)"
    )
    assert victim.read_text() == "precious-content" and not out.exists()


@pytest.mark.parametrize(
    ("name", "named"),
    [("samples/my_experiment.parquet", "samples/my_experiment.parquet"),
     ("_staging/x/y.parquet", "_staging/"),
     ("arrays/run1/weights.npy", "arrays/run1/")],
)  # fmt: skip
def test_overwrite_keeps_a_users_file_of_the_layouts_names(
    tmp_path: Path, raw: Path, built: Path, name: str, named: str
) -> None:
    (built / name).parent.mkdir(parents=True, exist_ok=True)
    (built / name).write_bytes((built / "samples" / "train.parquet").read_bytes())
    before = files(built)
    line = error_line(invoke("build", raw, "--out", built, "--overwrite"))
    assert line == (
        f"error: {built}: holds a build and also {named}, which are not the build's and "
        "--overwrite would delete with it; move them away first"
    )
    assert files(built) == before


def test_overwrite_keeps_a_folder_whose_manifest_only_looks_like_ours(
    tmp_path: Path, raw: Path
) -> None:
    out = tmp_path / "g"
    (out / "arrays" / "run1").mkdir(parents=True)
    (out / "manifest.json").write_text(
        '{"format_version": 3, "config_hash": "x", "tool": "someone else"}'
    )
    (out / "arrays" / "run1" / "weights.npy").write_text("data")
    before = files(out)
    line = error_line(invoke("build", raw, "--out", out, "--overwrite"))
    assert line == (
        f"error: {out}: directory is not empty and is not a build: its manifest.json is not one "
        "that ngsim-graphs wrote, or it was edited since; --overwrite replaces only a finished "
        "build"
    )
    assert files(out) == before


def test_a_killed_builds_leftovers_are_cleaned_up_by_the_next(
    tmp_path: Path, raw: Path, built: Path
) -> None:
    token = "5" * 32
    lock.lock_path(built).write_text(f"ngsim-graphs lock {token} 4242\n")  # no flock: killed
    _folder(lock.partial_path(built, token), "half a build")
    result = invoke("build", raw, "--out", built, "--overwrite")
    assert result.exit_code == 0, result.output
    assert siblings(built) == []


# --- build: one at a time --------------------------------------------------------------------


def test_second_build_of_a_locked_directory_is_refused(tmp_path: Path, raw: Path) -> None:
    out = tmp_path / "out"
    assert invoke("build", raw, "--out", out).exit_code == 0
    before = files(out)
    token = "4" * 32
    first = lock.partial_path(out, token)  # the running build's work
    (first / "tracks").mkdir(parents=True)
    (first / "tracks" / "half.parquet").write_bytes(b"PAR1")
    path = lock.lock_path(out)
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(fd, f"ngsim-graphs lock {token} 4242\n".encode())
        line = error_line(invoke("build", raw, "--out", out, "--overwrite"))
    finally:
        os.close(fd)
    assert line == (
        f"error: {out}: another process is writing it (process 4242), holding {path}; "
        "wait for it to finish or choose another --out"
    )
    assert files(out) == before
    assert files(first) == {"tracks/half.parquet": b"PAR1"}  # not taken for a killed build's


def test_lock_is_released_after_a_build_and_after_a_failure(tmp_path: Path, raw: Path) -> None:
    out, bad = tmp_path / "out", tmp_path / "bad.txt"
    bad.write_text((raw / NGSIM_FILE).read_text()[:-30])  # the last line cut short
    assert invoke("build", raw, "--out", out).exit_code == 0
    assert "bad.txt, line 220" in error_line(invoke("build", bad, "--out", tmp_path / "other"))
    assert siblings(out) == [] and siblings(tmp_path / "other") == []
    assert invoke("build", raw, "--out", out, "--overwrite").exit_code == 0


# --- build: a full disk ----------------------------------------------------------------------


def _enospc(filename: object = None) -> OSError:
    return OSError(
        errno.ENOSPC, "No space left on device", None if filename is None else str(filename)
    )


def _fail_parquet(
    monkeypatch: pytest.MonkeyPatch, stem: str, error: Callable[[Path], Exception]
) -> None:
    """Tables written whole (`write_parquet`) and streamed (`sink_parquet`: the samples)."""
    for name in ("write_parquet", "sink_parquet"):
        real = getattr(storage, name)

        def write(table: pl.DataFrame | pl.LazyFrame, path: Path, real: Callable = real) -> None:
            real(table, path)
            if stem in str(path):  # half the file, as a full disk leaves it
                path.write_bytes(path.read_bytes()[:20])
                raise error(path)

        monkeypatch.setattr(storage, name, write)


def _save_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = np.save

    def save(file: object, array: np.ndarray, allow_pickle: bool = True) -> None:
        if "track_rows" in str(file):
            raise OSError("100000 requested and 32752 written")  # what np.save says
        real(file, array, allow_pickle=allow_pickle)

    monkeypatch.setattr(storage.np, "save", save)


def _manifest_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = Path.write_text

    def write_text(self: Path, text: str, *args: Any, **kwargs: Any) -> int:
        if self.name == "manifest.json.partial":
            real(self, text[:10])
            raise _enospc(self)
        return real(self, text, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)


@pytest.mark.parametrize(
    ("fail", "named", "message"),
    [
        (lambda mp: _fail_parquet(mp, "tracks", _enospc), "tracks/us-101_0750am-0805am.parquet",
         "cannot write: No space left on device"),
        (lambda mp: _fail_parquet(mp, "samples/val", lambda path: pl.exceptions.ComputeError(
            "parquet: underlying IO error: No space left on device (os error 28)")), "",
         "cannot write: No space left on device"),
        # layout's writers name the file numpy's short write was in
        (_save_fails, "arrays/us-101_0750am-0805am/track_rows.npy", "cannot write: No space left on device"),
        (_manifest_fails, "manifest.json", "cannot write: No space left on device"),
    ],
)  # fmt: skip
@pytest.mark.parametrize("existing", [False, True])
def test_full_disk_is_one_line_and_leaves_out_as_it_was(
    tmp_path: Path, raw: Path, monkeypatch: pytest.MonkeyPatch,
    fail: Callable[[pytest.MonkeyPatch], None], named: str, message: str,
    existing: bool,
) -> None:  # fmt: skip
    out = tmp_path / "new" / "out"
    if existing:
        assert invoke("build", raw, "--out", out).exit_code == 0
    before = files(out)
    fail(monkeypatch)
    line = error_line(invoke("build", raw, "--out", out, "--overwrite"))
    assert line == f"error: {out / named if named else out}: {message}"
    assert files(out) == before
    assert siblings(out) == []  # no partial directory, no lock file
    assert (tmp_path / "new").exists() == existing


# --- synth -----------------------------------------------------------------------------------

SYNTH = ("--recordings", "1", "--minutes", "0.05", "--format", "portal")


def test_synth_keeps_a_folder_of_real_data(tmp_path: Path) -> None:
    folder = tmp_path / "ngsim"
    folder.mkdir()
    (folder / PORTAL_FILE_NAME).write_text("real data\n")
    line = error_line(invoke("synth", folder, *SYNTH))
    assert line == (
        f"error: {folder}: folder is not empty and not synth's (no {MARKER_NAME}): it holds "
        f"{PORTAL_FILE_NAME}; synth writes only into a new or empty folder or one it wrote before"
    )
    assert files(folder) == {PORTAL_FILE_NAME: b"real data\n"}


def test_synth_twice_replaces_its_own_files(tmp_path: Path) -> None:
    """README's first command, run twice; the marker says what the folder holds."""
    folder = tmp_path / "demo" / "raw"
    assert invoke("synth", folder, *SYNTH).exit_code == 0
    first = files(folder)
    result = invoke("synth", folder, *SYNTH)
    assert result.exit_code == 0, result.output
    assert files(folder) == first and sorted(first) == [PORTAL_FILE_NAME, MARKER_NAME]
    marker = (folder / MARKER_NAME).read_text()
    assert "NOT real NGSIM" in marker and f"\n- {PORTAL_FILE_NAME}\n" in marker
    digest = hashlib.sha256(first[PORTAL_FILE_NAME]).hexdigest()
    assert f"\n    {digest}  {PORTAL_FILE_NAME}\n" in marker  # as sha256sum -c reads it
    assert siblings(folder) == []  # no lock file, no partial folder


def test_synth_keeps_a_file_its_marker_does_not_list(tmp_path: Path) -> None:
    folder = tmp_path / "raw"
    assert invoke("synth", folder, *SYNTH).exit_code == 0
    real = folder / "us-101" / NGSIM_FILE
    real.parent.mkdir()
    real.write_text("real data\n")
    before = files(folder)
    line = error_line(invoke("synth", folder, "--recordings", "1", "--minutes", "0.05"))
    assert line == (
        f"error: {real.parent}: not written by synth (not listed in {folder / MARKER_NAME}, or "
        "changed since); move it away first: synth replaces only a folder of its own files"
    )
    assert files(folder) == before and siblings(folder) == []


def test_synth_in_another_format_replaces_its_earlier_files(tmp_path: Path) -> None:
    folder = tmp_path / "raw"
    assert invoke("synth", folder, *SYNTH[:-2], "--format", "csv").exit_code == 0
    assert invoke("synth", folder, *SYNTH).exit_code == 0
    # one copy of the data, not two, and no empty us-101/
    assert sorted(files(folder)) == [PORTAL_FILE_NAME, MARKER_NAME]
    assert sorted(p.name for p in folder.iterdir()) == sorted(files(folder))


def test_synth_full_disk_is_one_line_naming_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(handle: BinaryIO, rows: pl.DataFrame, quirks: bool) -> None:
        handle.write(b"half a line")
        raise OSError("No space left on device (os error 28)")  # what polars' write_csv says

    monkeypatch.setattr(synthesis, "_write_txt", full)
    folder = tmp_path / "raw"
    line = error_line(invoke("synth", folder, "--recordings", "1", "--minutes", "0.05"))
    path = folder / "us-101" / NGSIM_FILE
    assert line == f"error: {path}: cannot write: No space left on device"
    assert not folder.exists() and siblings(folder) == []


# --- export ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("export")
    write_synthetic(root / "raw", SynthConfig(recordings=1, minutes=0.5, seed=3))
    assert invoke("build", root / "raw", "--out", root / "build", "--stride-s", "2").exit_code == 0
    return root / "build"


def _export(build: Path, out: Path, *options: str) -> Result:
    return invoke("export", build, "--out", out, "--split", "train", "--samples", "0:3", *options)


@pytest.mark.parametrize(
    ("mine", "named"),
    [
        ({"nodes.parquet": b"someone else's", "notes.txt": b"mine\n"}, "nodes.parquet, notes.txt"),
        ({"nodes.parquet": b"someone else's"}, "nodes.parquet"),  # only an export's name
    ],
)
def test_export_keeps_a_folder_of_other_files(
    build: Path, tmp_path: Path, mine: dict[str, bytes], named: str
) -> None:
    out = tmp_path / "t"
    out.mkdir()
    for name, content in mine.items():
        (out / name).write_bytes(content)
    line = error_line(_export(build, out, "--overwrite"))
    assert line == (
        f"error: {out}: folder is not empty: it holds {named}, which export did not write; "
        "choose a new or empty folder"
    )
    assert files(out) == mine


def test_export_keeps_a_table_changed_since_it_was_exported(build: Path, tmp_path: Path) -> None:
    out = tmp_path / "t"
    assert _export(build, out).exit_code == 0
    (out / "nodes.parquet").write_bytes(b"my own edit of it")
    before = files(out)
    line = error_line(_export(build, out, "--overwrite"))
    assert line.startswith(f"error: {out}: folder is not empty: it holds {EXPORT_MARKER}, ")
    assert files(out) == before


def test_export_replaces_an_earlier_export_only_with_overwrite(build: Path, tmp_path: Path) -> None:
    out = tmp_path / "t"
    assert _export(build, out).exit_code == 0
    assert sorted(files(out)) == EXPORT_FILES
    first = files(out)
    line = error_line(_export(build, out))
    assert line == f"error: {out}: holds an export already; pass --overwrite to replace it"
    result = _export(build, out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert files(out) == first and siblings(out) == []


def test_failed_export_leaves_no_tables(
    build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _fail_parquet(monkeypatch, "targets", _enospc)
    out = tmp_path / "t"
    line = error_line(_export(build, out))
    assert line == f"error: {out / 'targets.parquet'}: cannot write: No space left on device"
    assert not out.exists() and siblings(out) == []


def test_out_given_as_dot(tmp_path: Path, raw: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    result = invoke("build", raw, "--out", ".")
    assert result.exit_code == 0, result.output
    assert (here / "manifest.json").is_file()
    assert (
        sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    )  # no lock left
