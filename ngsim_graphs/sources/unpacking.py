"""An archive member's bytes, unpacked within bounds (`archives` finds the archives and names
what they hold): which zip members can be read, each one decompressed a bounded piece at a time,
and every byte counted against what its archive may unpack to and the free disk.

A decompression bomb (a few KB of zip or gzip that unpacks to GBs) is refused before it is
unpacked where a zip member declares its size, and while it is unpacked otherwise (a .gz, whose
size field holds only the last 32 bits, or a zip whose declared sizes lie): memory stays tens
of MB at most, and the disk holds at most what the limits allow.
"""

from __future__ import annotations

import bz2
import contextlib
import os
import shutil
import struct
import zipfile
import zlib
from collections.abc import Callable, Generator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from ngsim_graphs.errors import NgsimInputError, NgsimOutputError

_COPY_BYTES = 1 << 20
# The bytes each read of a member asks zipfile for. Its reader decompresses all the compressed
# bytes of a read (4 KiB at least) at once, deflate's excepted: 4 KiB of LZMA unpack to 30 MB
# at most; 4 KiB of bzip2 can unpack to GBs, so bzip2 is decompressed here (`_bzip2_chunks`).
_READ_BYTES = {
    zipfile.ZIP_STORED: _COPY_BYTES,
    zipfile.ZIP_DEFLATED: _COPY_BYTES,
    zipfile.ZIP_BZIP2: _COPY_BYTES,
    zipfile.ZIP_LZMA: 4096,
}
_METHOD_NAMES = {9: "deflate64", 93: "zstandard", 95: "xz", 98: "PPMd", 99: "WinZip AES encryption"}
_ENCRYPTED = 0x1  # a zip member's flag bit: encrypted with a password
_LOCAL_HEADER = struct.Struct("<4s5H3L2H")  # a member's local header, to its name's length


@dataclass(frozen=True)
class ExpansionLimits:
    """How far an archive may expand as it is unpacked. Real NGSIM text deflates 5-8 times
    (synth's NGSIM files 3.5-4.6 times, 8.7 at most with xz; its highD tracks 4.6, 7.7 with xz),
    so 50 times leaves a margin of about 6 over the best of them, and a zip of the same rows
    repeated (84 times) is refused."""

    max_ratio: float = 50.0  # unpacked bytes per byte of the archive (or of a member's)
    allowance_bytes: int = 1 << 20  # and this much more: a small file compresses far more

    def allowed_bytes(self, packed_bytes: int) -> int:
        """The most that `packed_bytes` of archive (or of a member) may unpack to, in bytes."""
        return int(self.max_ratio * packed_bytes) + self.allowance_bytes

    def bound_in_words(self) -> str:
        """The bound as an error message says it."""
        return f"{self.max_ratio:g} times its size and {self.allowance_bytes:,} bytes more"


LIMITS = ExpansionLimits()  # read at call time, so that a test may replace it


def free_bytes(folder: Path) -> int:
    """The bytes free on the disk of `folder`."""
    return shutil.disk_usage(folder).free


@dataclass
class Expansion:
    """One input archive as it is unpacked (the archives it holds included): its name and size,
    and the bytes written of it so far, which may not pass LIMITS of its size."""

    archive: str
    packed_bytes: int
    written_bytes: int = 0

    def add(self, n_bytes: int, name: str) -> None:
        """Count `n_bytes` more written of member `name`; raise NgsimInputError past the bound."""
        self.written_bytes += n_bytes
        allowed = LIMITS.allowed_bytes(self.packed_bytes)
        if self.written_bytes > allowed:
            archive = "it" if name == self.archive else self.archive
            raise NgsimInputError(
                name,
                f"unpacks to more than {allowed:,} bytes, the most that {archive} "
                f"({self.packed_bytes:,} bytes) may unpack to ({LIMITS.bound_in_words()}): "
                "a decompression bomb?",
            )


def check_zip_member(info: zipfile.ZipInfo, name: str, folder: Path) -> None:
    """Raise for a zip member (reported as `name`) that cannot or must not be unpacked into
    `folder`: encrypted, compressed with a method Python's zipfile does not read, declaring more
    bytes than LIMITS allow for its compressed size (NgsimInputError), or than `folder`'s disk
    has free (NgsimOutputError)."""
    method = info.compress_type
    if info.flag_bits & _ENCRYPTED:
        raise NgsimInputError(name, "encrypted (password-protected): unpack it yourself first")
    if method not in _READ_BYTES:
        what = _METHOD_NAMES.get(method, "an unknown method")
        raise NgsimInputError(
            name,
            f"compressed with {what} (zip method {method}), which Python's zipfile cannot "
            "unpack: unpack it with another tool, or zip it again with deflate",
        )
    if info.file_size > LIMITS.allowed_bytes(info.compress_size):
        ratio = info.file_size / max(1, info.compress_size)
        raise NgsimInputError(
            name,
            f"declares {info.file_size:,} bytes unpacked from {info.compress_size:,} "
            f"({ratio:,.0f} times; a member may unpack to {LIMITS.bound_in_words()}): "
            "a decompression bomb?",
        )
    free = free_bytes(folder)
    if info.file_size > free:
        raise NgsimOutputError(
            name,
            f"declares {info.file_size:,} bytes unpacked, more than the {free:,} bytes free "
            f"on the disk of the build's staging ({folder})",
        )


def zip_member_chunks(
    zipped: zipfile.ZipFile, archive: Path, info: zipfile.ZipInfo
) -> Generator[bytes, None, None]:
    """A member's unpacked bytes (of `zipped`, opened from `archive`), a MB at a time (LZMA's
    up to 30 MB); `check_zip_member` passed it."""
    if info.compress_type == zipfile.ZIP_BZIP2:
        return _bzip2_chunks(archive, info)
    return stream_chunks(lambda: zipped.open(info), _READ_BYTES[info.compress_type])


def stream_chunks(
    opener: Callable[[], IO[bytes]], read_bytes: int = _COPY_BYTES
) -> Generator[bytes, None, None]:
    """`opener()`'s stream read `read_bytes` at a time (opened at the first, closed after the last)."""
    with opener() as stream:
        while chunk := stream.read(read_bytes):
            yield chunk


def _bzip2_chunks(archive: Path, info: zipfile.ZipInfo) -> Generator[bytes, None, None]:
    """A bzip2 member decompressed a MB at most at a time, from its bytes in `archive`; raises
    zipfile.BadZipFile, as zipfile does, where it unpacks to other bytes than its CRC's or more
    than its declared size, EOFError where it is cut short."""
    decompressor, crc, size = bz2.BZ2Decompressor(), 0, 0
    with contextlib.closing(_packed_bytes(archive, info)) as packed:
        while not decompressor.eof:
            data = next(packed, b"") if decompressor.needs_input else b""
            if decompressor.needs_input and not data:
                raise EOFError("compressed data ended early")
            try:
                chunk = decompressor.decompress(data, _COPY_BYTES)
            except OSError as err:  # bz2's "Invalid data stream"
                raise zipfile.BadZipFile(f"bzip2: {err}") from None
            crc, size = zlib.crc32(chunk, crc), size + len(chunk)
            if size > info.file_size:
                raise zipfile.BadZipFile(f"more than its declared {info.file_size:,} bytes")
            yield chunk
    if (crc, size) != (info.CRC, info.file_size):
        raise zipfile.BadZipFile(f"Bad CRC-32 for file {info.filename!r}")


def _packed_bytes(archive: Path, info: zipfile.ZipInfo) -> Generator[bytes, None, None]:
    """A member's compressed bytes as they lie in `archive`, a MB at most at a time."""
    with archive.open("rb") as handle:
        handle.seek(info.header_offset)
        header = handle.read(_LOCAL_HEADER.size)
        if len(header) < _LOCAL_HEADER.size or not header.startswith(b"PK\x03\x04"):
            raise zipfile.BadZipFile("Bad magic number for file header")
        *_, name_length, extra_length = _LOCAL_HEADER.unpack(header)
        handle.seek(name_length + extra_length, os.SEEK_CUR)
        left = info.compress_size
        while left > 0:
            data = handle.read(min(left, _COPY_BYTES))
            if not data:
                raise EOFError("the zip file ends inside this member")
            left -= len(data)
            yield data


def write_chunks(
    chunks: Generator[bytes, None, None], target: Path, name: str, expansion: Expansion
) -> None:
    """Write a member's unpacked bytes (reported as `name`) to `target`, a new file, each
    counted against `expansion` and the disk's free bytes as the copy starts (NgsimOutputError
    past them: the disk would fill)."""
    free, written = free_bytes(target.parent), 0
    with contextlib.closing(chunks), target.open("xb") as copy:
        for chunk in chunks:
            expansion.add(len(chunk), name)
            written += len(chunk)
            if written > free:
                raise NgsimOutputError(
                    name,
                    f"unpacks to more than the {free:,} bytes free on the disk of the build's "
                    f"staging ({target.parent})",
                )
            copy.write(chunk)
