"""Where a build may land: what --overwrite may replace, overlap with the inputs, the swap, and
a failed write reported as one error naming the file, leaving nothing."""

from __future__ import annotations

import errno
import json
import os
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import landing, layout
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.integrity import canonical_sha256

TRACKS = "tracks/us-101_0750am-0805am.parquet"


def files(root: Path) -> dict[str, bytes]:
    """Every file under `root` (relative path -> bytes)."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def siblings(out: Path) -> list[str]:
    """Hidden entries beside `out`: partial and retired directories, the lock file."""
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


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


def _finished(out: Path, names: tuple[str, ...] = (TRACKS,), config: object = None) -> Path:
    """A finished build in `out`: the files `names` and a manifest sealed over them."""
    for name in names:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        if name.endswith(".npy"):
            np.save(out / name, np.arange(3.0))
        else:
            (out / name).write_bytes(b"PAR1 " + name.encode())
    config = {"d_min_m": 25.0} if config is None else config
    body = {"format_version": 1, "config": config, "config_hash": canonical_sha256(config)}
    layout.write_manifest_json(out, body)
    return out


def test_empty_or_missing_target_needs_no_overwrite(tmp_path: Path) -> None:
    landing._check_target(tmp_path / "new", overwrite=False)
    (tmp_path / "empty").mkdir()
    landing._check_target(tmp_path / "empty", overwrite=False)


def test_our_build_is_replaced_only_with_overwrite(tmp_path: Path) -> None:
    out = _finished(tmp_path / "out", (TRACKS, "arrays/us-101_0750am-0805am/node_x_m.npy"))
    assert landing.finished_build_files(out) == {
        "manifest.json",
        "build.log",
        TRACKS,
        "arrays/us-101_0750am-0805am/node_x_m.npy",
    }  # fmt: skip: the build's log is the build's, though it is written after its manifest
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=False)
    assert str(caught.value) == (
        f"{out}: directory is not empty: it holds a build; pass --overwrite to replace it"
    )
    landing._check_target(out, overwrite=True)


def test_a_build_missing_a_file_is_still_ours(tmp_path: Path) -> None:
    out = _finished(tmp_path / "out", (TRACKS, "samples/train.parquet"))
    (out / "samples/train.parquet").unlink()
    landing._check_target(out, overwrite=True)


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["notes.txt", "run1/best.pt"], "notes.txt, run1/"),
        (["samples/my_experiment.parquet"], "samples/my_experiment.parquet"),  # layout's names
        (["_staging/x/y.parquet"], "_staging/"),  # a finished build has none
        (["tracks/old/"], "tracks/old/"),  # an empty folder
    ],
)
def test_files_put_into_a_build_keep_it_from_being_replaced(
    tmp_path: Path, extra: list[str], named: str
) -> None:
    out = _finished(tmp_path / "out", (TRACKS, "samples/train.parquet"))
    for name in extra:
        (out / name.rstrip("/")).parent.mkdir(parents=True, exist_ok=True)
        if name.endswith("/"):
            (out / name).mkdir()
        else:
            (out / name).write_text("mine\n")
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=True)
    assert str(caught.value) == (
        f"{out}: holds a build and also {named}, which are not the build's and "
        "--overwrite would delete with it; move them away first"
    )


@pytest.mark.parametrize(
    ("entries", "named"),
    [
        (["notes.txt"], "notes.txt"),
        (["tracks/us-101_0750am-0805am.parquet"], "tracks/"),  # a build's names, no manifest
        (["arrays/r/x.npy", "_staging/r/0000.parquet", "samples/train.parquet"],
         "_staging/, arrays/, samples/"),  # an unfinished build of an earlier version
        (["src/a.py", "src/b.py", "b", "c", "d"], "b, c, d and 1 more"),
    ],
)  # fmt: skip
def test_anything_but_a_finished_build_is_refused_even_with_overwrite(
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
        "--overwrite replaces only a finished build (move them away or choose another --out)"
    )


def _edit_manifest(out: Path) -> None:
    manifest = json.loads((out / layout.MANIFEST_NAME).read_text())
    manifest["config"]["d_min_m"] = 50.0
    (out / layout.MANIFEST_NAME).write_text(json.dumps(manifest))


@pytest.mark.parametrize(
    "make",
    [
        lambda out: (out / layout.MANIFEST_NAME).write_text('{"format_version": 1}'),
        lambda out: (out / layout.MANIFEST_NAME).write_text("[1, 2]"),
        lambda out: (out / layout.MANIFEST_NAME).write_text("not json"),
        lambda out: (out / layout.MANIFEST_NAME).write_text(  # another tool's, by two keys
            '{"format_version": 3, "config_hash": "x", "tool": "someone else"}'
        ),
        lambda out: _edit_manifest(_finished(out)),  # ours, edited since
    ],
)
def test_directory_with_a_foreign_manifest_is_refused(
    tmp_path: Path, make: Callable[[Path], object]
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    make(out)
    with pytest.raises(NgsimOutputError) as caught:
        landing._check_target(out, overwrite=True)
    assert str(caught.value) == (
        f"{out}: directory is not empty and is not a build: its manifest.json is not one that "
        "ngsim-graphs wrote, or it was edited since; --overwrite replaces only a finished build"
    )


def test_symbolic_links_inside_are_foreign(tmp_path: Path) -> None:
    out = _finished(tmp_path / "out")
    (tmp_path / "precious").mkdir()
    (out / "proximity").symlink_to(tmp_path / "precious")
    with pytest.raises(NgsimOutputError, match="also proximity/, which"):
        landing._check_target(out, overwrite=True)
    elsewhere = _finished(tmp_path / "elsewhere")
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / layout.MANIFEST_NAME).symlink_to(elsewhere / layout.MANIFEST_NAME)
    assert landing.finished_build_files(linked) is None


# --- failures while writing ------------------------------------------------------------------


@pytest.fixture
def previous(tmp_path: Path) -> tuple[Path, dict[str, bytes]]:
    out = _finished(tmp_path / "out")
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


# --- the swap --------------------------------------------------------------------------------


def test_interrupt_while_writing_leaves_out_as_it_was(previous: tuple) -> None:
    out, before = previous
    with pytest.raises(KeyboardInterrupt), landing.build_directory(out, True) as root:
        (root / TRACKS).parent.mkdir(parents=True)
        raise KeyboardInterrupt
    assert files(out) == before
    assert siblings(out) == []


def test_interrupt_while_swapping_lets_the_swap_finish(
    previous: tuple, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C between the two renames would leave no `out` at all, and the new build hidden."""
    out, before = previous
    real = landing._swap_into_place

    def interrupted(partial: Path, target: Path, retired: Path) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        real(partial, target, retired)

    monkeypatch.setattr(landing, "_swap_into_place", interrupted)
    with landing.build_directory(out, overwrite=True) as root:
        (root / "tracks").mkdir()
        (root / TRACKS).write_bytes(b"PAR1 new")
    assert files(out) == {TRACKS: b"PAR1 new"}
    assert siblings(out) == []
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
