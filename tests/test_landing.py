"""Where a build may land: the output lock, what --overwrite may replace, overlap with the
inputs, and a failed write reported as one error naming the file, leaving nothing."""

from __future__ import annotations

import errno
import fcntl
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import polars as pl
import pytest

from ngsim_graphs import landing, layout
from ngsim_graphs.errors import NgsimOutputError


def files(root: Path) -> dict[str, bytes]:
    """Every file under `root` (relative path -> bytes)."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def siblings(out: Path) -> list[str]:
    """Hidden entries beside `out`: partial and retired directories, the lock file."""
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


@pytest.fixture
def held(tmp_path: Path) -> Iterator[Path]:
    """`tmp_path/out`, locked by this test as another build would hold it, with PID 4242."""
    out = tmp_path / "out"
    fd = os.open(landing.lock_path(out), os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, b"4242\n")
    yield out
    os.close(fd)


# --- an output apart from the inputs ---------------------------------------------------------


@pytest.mark.parametrize(
    ("out", "relation"),
    [("raw", "is"), ("raw/build", "lies inside"), (".", "contains"), ("raw/a.txt", "is")],
)
def test_out_overlapping_an_input_is_refused(tmp_path: Path, out: str, relation: str) -> None:
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "a.txt").write_text("1 2 3\n")
    inputs = [tmp_path / "other.txt", raw / "a.txt"] if out == "raw/a.txt" else [raw]
    with pytest.raises(NgsimOutputError) as caught:
        landing.check_outside_inputs(tmp_path / out, inputs)
    assert str(caught.value) == (
        f"{tmp_path / out}: --out {relation} the input {inputs[-1]}; "
        "choose an --out outside the inputs"
    )


def test_overlap_is_found_through_a_link_and_dots(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    raw.mkdir()
    (tmp_path / "link").symlink_to(raw)
    with pytest.raises(NgsimOutputError, match="lies inside the input"):
        landing.check_outside_inputs(tmp_path / "link" / "build", [raw])
    with pytest.raises(NgsimOutputError, match="--out is the input"):
        landing.check_outside_inputs(tmp_path / "x" / ".." / "raw", [raw])


def test_sibling_and_missing_paths_are_apart(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    landing.check_outside_inputs(tmp_path / "raw-build", [raw, tmp_path / "raw.txt"])


# --- which directories may be replaced -------------------------------------------------------


def _finished(out: Path, manifest: object) -> Path:
    (out / layout.TRACKS_DIR).mkdir(parents=True)
    (out / layout.TRACKS_DIR / "us-101_0750am-0805am.parquet").write_bytes(b"PAR1")
    (out / layout.MANIFEST_NAME).write_text(json.dumps(manifest))
    return out


def test_empty_or_missing_target_needs_no_overwrite(tmp_path: Path) -> None:
    landing._check_target(tmp_path / "new", overwrite=False)
    (tmp_path / "empty").mkdir()
    landing._check_target(tmp_path / "empty", overwrite=False)


def test_our_build_is_replaced_only_with_overwrite(tmp_path: Path) -> None:
    out = _finished(tmp_path / "out", {"format_version": 0, "config_hash": "ab", "x": 1})
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=False)
    assert str(caught.value) == (
        f"{out}: directory is not empty: it holds a build; pass --overwrite to replace it"
    )
    landing._check_target(out, overwrite=True)


def test_files_put_into_a_build_keep_it_from_being_replaced(tmp_path: Path) -> None:
    out = _finished(tmp_path / "out", {"format_version": 2, "config_hash": "ab"})
    (out / "notes.txt").write_text("mine\n")
    (out / "run1").mkdir()
    (out / "run1" / "best.pt").write_bytes(b"a model trained on this build")
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=True)
    assert str(caught.value) == (
        f"{out}: holds a build and also notes.txt, run1/, which are not the build's and "
        "--overwrite would delete with it; move them away first"
    )


def test_unfinished_build_of_layout_names_is_ours(tmp_path: Path) -> None:
    out = tmp_path / "out"
    for name in ("arrays/us-101_0750am-0805am/node_x_m.npy", "_staging/r/0000.parquet",
                 "samples/train.parquet", "proximity/p.parquet"):  # fmt: skip
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(b"x")
    (out / "tracks").mkdir()
    landing._check_target(out, overwrite=True)


@pytest.mark.parametrize(
    ("entries", "named"),
    [
        (["notes.txt"], "notes.txt"),
        (["tracks/notes.txt"], "tracks/notes.txt"),
        (["arrays/x.npy"], "arrays/x.npy"),  # .npy belong one folder deeper
        (["src/a.py", "src/b.py", "b", "c", "d"], "b, c, d and 1 more"),
    ],
)
def test_foreign_directory_is_refused_even_with_overwrite(
    tmp_path: Path, entries: list[str], named: str
) -> None:
    out = tmp_path / "out"
    for name in entries:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text("mine\n")
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=True)
    assert str(caught.value) == (
        f"{out}: directory is not empty and is not a build: it holds {named}; "
        "--overwrite replaces only a build (move them away or choose another --out)"
    )


@pytest.mark.parametrize("manifest", ['{"format_version": 1}', "[1, 2]", "not json"])
def test_directory_with_a_foreign_manifest_is_refused(tmp_path: Path, manifest: str) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / layout.MANIFEST_NAME).write_text(manifest)
    with pytest.raises(NgsimOutputError, match="its manifest.json is not one of ngsim-graphs"):
        landing._check_target(out, overwrite=True)


def test_symbolic_link_inside_is_foreign(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "precious").mkdir()
    (out / "tracks").symlink_to(tmp_path / "precious")
    with pytest.raises(NgsimOutputError, match="it holds tracks/;"):
        landing._check_target(out, overwrite=True)


# --- one writer at a time --------------------------------------------------------------------


def test_second_writer_is_refused_naming_the_holder(held: Path) -> None:
    with pytest.raises(NgsimOutputError) as caught, landing.output_lock(held):
        pass
    assert str(caught.value) == (
        f"{held}: another process is writing it (process 4242), holding "
        f"{landing.lock_path(held)}; wait for it to finish or choose another --out"
    )


def test_lock_records_the_pid_and_is_removed_on_release(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with landing.output_lock(out):
        assert landing.lock_path(out).read_text() == f"{os.getpid()}\n"
    assert siblings(out) == []


def test_lock_file_of_a_killed_build_does_not_block(tmp_path: Path) -> None:
    out = tmp_path / "out"
    landing.lock_path(out).write_text("999999\n")  # present, but nobody holds an flock on it
    with landing.output_lock(out):
        assert landing.lock_path(out).read_text() == f"{os.getpid()}\n"


def test_lock_unlinked_by_its_holder_before_ours_is_taken_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A holder releasing between our open() and our flock() unlinks the file we opened: a lock
    on it would hold nothing, since the next writer creates a new file."""
    out = tmp_path / "out"
    path = landing.lock_path(out)
    real_flock, calls = fcntl.flock, []

    def flock_after_a_release(fd: int, operation: int) -> None:
        calls.append(os.fstat(fd).st_ino)
        if len(calls) == 1:
            path.unlink()  # the holder's release
            path.write_text("")  # and a new writer's file
        real_flock(fd, operation)

    monkeypatch.setattr(landing.fcntl, "flock", flock_after_a_release)
    with landing.output_lock(out):
        assert len(calls) == 2 and calls[1] == path.stat().st_ino
        assert path.read_text() == f"{os.getpid()}\n"


# --- failures while writing ------------------------------------------------------------------


@pytest.fixture
def previous(tmp_path: Path) -> tuple[Path, dict[str, bytes]]:
    out = _finished(tmp_path / "out", {"format_version": 1, "config_hash": "ab"})
    return out, files(out)


def _fail_inside(out: Path, make_error: Callable[[Path], Exception]) -> NgsimOutputError:
    with pytest.raises(NgsimOutputError) as caught, landing.build_directory(out, True) as root:
        (root / layout.TRACKS_DIR).mkdir()
        (root / layout.TRACKS_DIR / "half.parquet").write_bytes(b"PAR1 half")
        raise make_error(root)
    return caught.value


def test_full_disk_names_the_file_as_it_would_be_in_out(previous: tuple) -> None:
    out, before = previous
    error = _fail_inside(
        out,
        lambda root: OSError(
            errno.ENOSPC, "No space left on device", str(root / "tracks/a.parquet")
        ),
    )
    assert str(error) == f"{out / 'tracks/a.parquet'}: cannot write: No space left on device"
    assert files(out) == before
    assert siblings(out) == []


@pytest.mark.parametrize(
    ("make_error", "message"),
    [
        (  # what polars 2 raises
            lambda root: pl.exceptions.ComputeError(
                "parquet: File out of specification: underlying IO error: "
                "No space left on device (os error 28)"
            ),
            "cannot write: No space left on device",
        ),
        (  # what np.save raises
            lambda root: OSError("100000 requested and 32752 written"),
            "cannot write (is the disk full?): 100000 requested and 32752 written",
        ),
    ],
)
def test_full_disk_without_a_file_name_names_out(
    previous: tuple, make_error: Callable[[Path], Exception], message: str
) -> None:
    out, before = previous
    assert str(_fail_inside(out, make_error)) == f"{out}: {message}"
    assert files(out) == before
    assert siblings(out) == []


def test_other_errors_go_on_as_they_came(tmp_path: Path) -> None:
    out = tmp_path / "deep" / "out"
    with pytest.raises(KeyError), landing.build_directory(out, False):
        raise KeyError("x")
    assert not (tmp_path / "deep").exists()  # the folders made for it are gone too
