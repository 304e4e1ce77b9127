"""Compressed inputs: told by their bytes, unpacked with their names kept, damage named."""

from __future__ import annotations

import gzip
import zipfile
from pathlib import Path

import pytest
from conftest import straight_track, write_txt
from test_cli_ngsim import assert_failed_cleanly, invoke

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.archives import archive_kind, archives_in, unpack_inputs


def test_archives_are_told_by_their_bytes(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "a.txt").write_bytes(gzip.compress(b"1 2 3\n"))  # gzip'd under its own name
    (raw / "b.txt").write_text("1 2 3\n")
    with zipfile.ZipFile(raw / "c.zip", "w") as zipped:
        zipped.writestr("x/b.txt", "1 2 3\n")
    assert [archive_kind(raw / n) for n in ("a.txt", "b.txt", "c.zip")] == ["gzip", None, "zip"]
    assert archives_in(raw) == [raw / "a.txt", raw / "c.zip"]


def test_unpacked_files_keep_their_names(tmp_path: Path) -> None:
    archive = tmp_path / "d.zip"
    with zipfile.ZipFile(archive, "w") as zipped:
        zipped.writestr("us-101/t.txt.gz", gzip.compress(b"1 2 3\n"))
        zipped.writestr("us-101/photo.jpg", b"\xff\xd8")
    unpacked = unpack_inputs([archive], tmp_path / "scratch")
    [(path, name)] = [(p, n) for p, n in unpacked.names.items() if p.is_file()]
    assert (path.name, path.read_bytes(), name) == (
        "t.txt",
        b"1 2 3\n",
        f"{archive}/us-101/t.txt.gz",
    )
    assert unpacked.skipped == [f"{archive}/us-101/photo.jpg"]


def test_damaged_archives_are_named(tmp_path: Path) -> None:
    cut = tmp_path / "t.txt.gz"
    cut.write_bytes(gzip.compress(b"1 2 3\n" * 1000)[:-20])
    with pytest.raises(NgsimInputError, match=rf"^{cut}: damaged compressed data"):
        unpack_inputs([cut], tmp_path / "s1")
    escaping = tmp_path / "e.zip"
    with zipfile.ZipFile(escaping, "w") as zipped:
        zipped.writestr("../../x.txt", "1 2 3\n")
    with pytest.raises(NgsimInputError, match="leads out of its zip file"):
        unpack_inputs([escaping], tmp_path / "s2")
    assert not (tmp_path / "x.txt").exists()


@pytest.fixture
def good_raw(tmp_path: Path) -> Path:
    """A folder with one good NGSIM file (us-101 0750am, two vehicles, 30 frames each)."""
    raw = tmp_path / "raw"
    rows = straight_track(1, range(10, 40), x_ft=6.0) + straight_track(2, range(10, 40))
    write_txt(raw / "us-101" / "trajectories-0750am-0805am.txt", rows)
    return raw


HTML_PAGE = b"<html><body>404 Not Found</body></html>\n"  # a download that failed


@pytest.mark.parametrize("name", ["i-80/trajectories-0400-0415.txt.gz", "I-80-Main-Data.zip"])
def test_a_file_named_as_an_archive_that_is_none_is_refused(
    tmp_path: Path, good_raw: Path, name: str
) -> None:
    # Beside good files, main left it out: exit 0, not listed as skipped, its recording lost.
    fake = good_raw / name
    fake.parent.mkdir(parents=True, exist_ok=True)
    text = (good_raw / "us-101" / "trajectories-0750am-0805am.txt").read_bytes()
    content = HTML_PAGE if name.endswith(".zip") else text
    fake.write_bytes(content)
    kind, suffix = ("zip", ".zip") if name.endswith(".zip") else ("gzip", ".gz")
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", good_raw, "--out", out), out, {}, fake)
    assert line == f"error: {fake}: named {suffix} but not {kind} data (it begins {content[:16]!r})"
    # Named on the command line, it is refused alike (main read the text under .txt.gz).
    line = assert_failed_cleanly(invoke("build", fake, "--out", out), out, {}, fake)
    assert line.endswith(f"named {suffix} but not {kind} data (it begins {content[:16]!r})")


def test_a_member_named_as_an_archive_that_is_none_is_refused(tmp_path: Path) -> None:
    archive, out = tmp_path / "NGSIM.zip", tmp_path / "out"
    with zipfile.ZipFile(archive, "w") as zipped:
        zipped.writestr("us-101/download.zip", HTML_PAGE)
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    assert line == (
        f"error: {archive}/us-101/download.zip: named .zip but not zip data "
        f"(it begins {HTML_PAGE[:16]!r})"
    )
