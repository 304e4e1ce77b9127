"""Compressed inputs: told by their bytes, unpacked with their names kept, damage named."""

from __future__ import annotations

import gzip
import zipfile
from pathlib import Path

import pytest

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
