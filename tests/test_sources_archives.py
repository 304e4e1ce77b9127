"""Compressed inputs: told by their bytes, unpacked with their names kept, damage named."""

from __future__ import annotations

import gzip
import random
import zipfile
from pathlib import Path

import pytest
from conftest import straight_track, write_txt
from test_cli_ngsim import assert_failed_cleanly, invoke

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources import unpacking
from ngsim_graphs.sources.archives import archive_kind, archives_in, unpack_inputs
from ngsim_graphs.sources.unpacking import ExpansionLimits
from ngsim_graphs.synth.marker import MARKER_NAME


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


def _patched(data: bytes, member: str, at: tuple[int, int], value: bytes) -> bytes:
    """The zip `data` with `value` written into `member`'s local header and central directory
    entry, at offsets `at` (local, central) of each (APPNOTE 4.3.7 and 4.3.12)."""
    patched = bytearray(data)
    for signature, field_at, name_at in zip(
        (b"PK\x03\x04", b"PK\x01\x02"), at, (30, 46), strict=True
    ):
        i = patched.find(signature)
        while i >= 0:
            if patched[i + name_at : i + name_at + len(member)] == member.encode():
                patched[i + field_at : i + field_at + len(value)] = value
            i = patched.find(signature, i + 4)
    return bytes(patched)


FLAGS, METHOD, FILE_SIZE = (6, 8), (8, 10), (22, 24)  # header fields' offsets (local, central)
TXT = "us-101/trajectories-0750am-0805am.txt"


def _zip_of(raw: Path, archive: Path, method: int = zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(archive, "w", method) as zipped:
        for path in sorted(p for p in raw.rglob("*") if p.is_file()):
            zipped.write(path, path.relative_to(raw).as_posix())
    return archive


def test_an_encrypted_member_or_an_unknown_method_is_one_line(
    tmp_path: Path, good_raw: Path
) -> None:
    # main: a traceback (RuntimeError "password required", NotImplementedError).
    (good_raw / MARKER_NAME).write_text("simulated\n")
    archive, out = _zip_of(good_raw, tmp_path / "a.zip"), tmp_path / "out"
    archive.write_bytes(_patched(archive.read_bytes(), TXT, FLAGS, b"\x01\x00"))  # zip -P's bit
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    assert (
        line == f"error: {archive}/{TXT}: encrypted (password-protected): unpack it yourself first"
    )
    archive = _zip_of(good_raw, tmp_path / "b.zip")  # the marker, read apart from the files
    archive.write_bytes(_patched(archive.read_bytes(), MARKER_NAME, METHOD, b"\x63\x00"))
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    assert line == (
        f"error: {archive}/{MARKER_NAME}: compressed with WinZip AES encryption (zip method 99), "
        "which Python's zipfile cannot unpack: unpack it with another tool, or zip it again "
        "with deflate"
    )


def test_a_member_that_declares_too_much_is_refused_unread(tmp_path: Path) -> None:
    # e06's 2 KB of 2.5 GiB of zeros in miniature, at the default limits: 2 MiB from 2 KB.
    archive, out = tmp_path / "zeros.zip", tmp_path / "out"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zipped:
        zipped.writestr(TXT, bytes(2 << 20))
        info = zipped.getinfo(TXT)
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    ratio = (2 << 20) / info.compress_size
    assert line == (
        f"error: {archive}/{TXT}: declares 2,097,152 bytes unpacked from "
        f"{info.compress_size:,} ({ratio:,.0f} times; a member may unpack to 50 times its size "
        "and 1,048,576 bytes more): a decompression bomb?"
    )


def test_a_member_larger_than_the_free_disk_is_refused_unread(
    tmp_path: Path, good_raw: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    archive, out = _zip_of(good_raw, tmp_path / "a.zip"), tmp_path / "out"
    size = (good_raw / TXT).stat().st_size
    monkeypatch.setattr(unpacking, "free_bytes", lambda folder: size - 1)
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    assert line.startswith(
        f"error: {archive}/{TXT}: declares {size:,} bytes unpacked, more than the {size - 1:,} "
        f"bytes free on the disk of the build's staging ({tmp_path}/.out.partial-"
    )


def test_an_archive_unpacks_to_its_bound_at_most(
    tmp_path: Path, good_raw: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What a .gz or a zip's nested archives unpack to is counted as it is written, against the
    size of the archive given: neither declares it (gzip keeps 32 bits of it)."""
    monkeypatch.setattr(unpacking, "LIMITS", ExpansionLimits(max_ratio=3.0, allowance_bytes=0))
    text = (good_raw / TXT).read_bytes()
    packed = tmp_path / "packed" / "trajectories-0750am-0805am.txt.gz"
    packed.parent.mkdir()
    packed.write_bytes(gzip.compress(text))
    assert len(text) > 3 * packed.stat().st_size  # the bound is passed
    out = tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", packed.parent, "--out", out), out, {}, packed)
    size = packed.stat().st_size
    assert line == (
        f"error: {packed}: unpacks to more than {3 * size:,} bytes, the most that it "
        f"({size:,} bytes) may unpack to (3 times its size and 0 bytes more): "
        "a decompression bomb?"
    )
    archive = tmp_path / "nested.zip"  # the .gz stored: as large as it declares, 1 time
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zipped:
        zipped.write(packed, "us-101/t.txt.gz")
    line = assert_failed_cleanly(invoke("build", archive, "--out", out), out, {}, archive)
    assert line.startswith(f"error: {archive}/us-101/t.txt.gz: unpacks to more than ")
    assert f"the most that {archive} ({archive.stat().st_size:,} bytes)" in line


@pytest.mark.parametrize("method", [zipfile.ZIP_STORED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA])
def test_every_method_zipfile_reads_unpacks_whole(tmp_path: Path, method: int) -> None:
    # 2.6 MB of digits: bzip2 (read here, a MB at a time) unpacks in several pieces.
    text = random.Random(0).randbytes(1_300_000).hex().encode()
    archive = tmp_path / "a.zip"
    with zipfile.ZipFile(archive, "w", method) as zipped:
        zipped.writestr("a.txt", text)
    unpacked = unpack_inputs([archive], tmp_path / "scratch")
    [path] = [p for p in unpacked.names if p.is_file()]
    assert path.read_bytes() == text


@pytest.mark.parametrize("method", [zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2])
def test_a_member_that_declares_less_than_it_holds_is_damaged(tmp_path: Path, method: int) -> None:
    """A declared size is no bound to trust: zipfile stops at it and finds the CRC wrong (deflate);
    bzip2, read here, is refused as it passes it."""
    archive = tmp_path / "a.zip"
    with zipfile.ZipFile(archive, "w", method) as zipped:
        zipped.writestr("a.txt", b"1 2 3\n" * 1000)
    archive.write_bytes(
        _patched(archive.read_bytes(), "a.txt", FILE_SIZE, (100).to_bytes(4, "little"))
    )
    with pytest.raises(NgsimInputError) as raised:
        unpack_inputs([archive], tmp_path / "scratch")
    found = (
        "Bad CRC-32 for file 'a.txt'"
        if method == zipfile.ZIP_DEFLATED
        else "more than its declared 100 bytes"
    )
    assert str(raised.value) == f"{archive}/a.txt: damaged compressed data: {found}"
