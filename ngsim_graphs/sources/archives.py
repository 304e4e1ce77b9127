"""Compressed inputs: a .zip or .gz given or found among a build's inputs, told by its first
bytes (a .txt gzip'd under its own name is one), unpacked into the build's staging folder and
read from there; each file unpacked is named by where it came from (`NGSIM.zip/US-101/a.txt`,
`a.txt.gz`). Unpacking streams a member at a time, within bounds (`unpacking`): memory stays
small whatever their size, and an archive unpacks to at most `unpacking.LIMITS` of its size.

A zip may nest folders and inner zips or .gz files (the portal's per-location zips do); of its
members, the .txt and .csv files and the archives are unpacked, and every other member (photos,
CAD drawings, videos, documents) is listed as skipped. A member that cannot be unpacked
(encrypted, a compression method Python does not read, damaged, too large) and a file named .gz
or .zip that is none are refused by name.
"""

from __future__ import annotations

import gzip
import lzma
import shutil
import zipfile
import zlib
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from ngsim_graphs.errors import NgsimError, NgsimInputError
from ngsim_graphs.sources.unpacking import (
    Expansion,
    check_zip_member,
    stream_chunks,
    write_chunks,
    zip_member_chunks,
)

GZIP_MAGIC = b"\x1f\x8b"
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip with members, an empty zip
ARCHIVE_SUFFIXES = (".gz", ".zip")
TEXT_SUFFIXES = (".txt", ".csv")  # the members a source may read
MAX_DEPTH = 4  # archives inside archives, at most


def archive_kind(path: Path) -> str | None:
    """ "gzip" or "zip" for a file whose first bytes say so; None for any other (or unreadable)."""
    try:
        with path.open("rb") as handle:
            head = handle.read(4)
    except OSError:
        return None
    if head.startswith(GZIP_MAGIC):
        return "gzip"
    return "zip" if head in ZIP_MAGICS else None


def archives_in(path: Path) -> list[Path]:
    """The archives among `path` (a named file) or under it (a folder, searched recursively):
    files named .gz or .zip, and .txt or .csv files that are compressed; in path order. Raises
    NgsimInputError for a file named .gz or .zip that is not one (`check_named_right`)."""
    if path.is_file():
        return [path] if _is_archive(path) else []
    if not path.is_dir():
        return []
    suffixes = ARCHIVE_SUFFIXES + TEXT_SUFFIXES
    found = (p for p in sorted(path.rglob("*")) if p.is_file() and p.suffix.lower() in suffixes)
    return [p for p in found if _is_archive(p)]


def _is_archive(path: Path) -> bool:
    check_named_right(path, str(path))
    return archive_kind(path) is not None


def check_named_right(path: Path, name: str) -> None:
    """Raise NgsimInputError naming `name` (the file `path`, or an archive's member unpacked to
    it) where it is named .gz or .zip and is not one: a download that failed (an HTML page), a
    text file renamed. No source reads it, so it would otherwise be lost in silence."""
    suffix = path.suffix.lower()
    expected = {".gz": "gzip", ".zip": "zip"}.get(suffix)
    if expected is None or archive_kind(path) is not None:  # the bytes tell the kind
        return
    with path.open("rb") as handle:
        head = handle.read(16)
    found = f"it begins {head!r}" if head else "it is empty"
    raise NgsimInputError(name, f"named {suffix} but not {expected} data ({found})")


@dataclass
class Unpacked:
    """What unpacking a build's archives gave: in place of each archive, its unpacked copy (a
    zip's folder, a .gz's file) to search; the name each unpacked file and folder is reported
    by; and the members skipped, by name."""

    paths: list[Path] = field(default_factory=list)
    names: dict[Path, str] = field(default_factory=dict)  # resolved unpacked path -> its name
    skipped: list[str] = field(default_factory=list)


def unpack_inputs(
    paths: list[Path],
    scratch: Path,
    markers: tuple[str, ...] = (),
    progress: Callable[[int, int], None] | None = None,
) -> Unpacked:
    """Unpack every archive among or under `paths` into `scratch` (a folder the build removes),
    each under a mirror of its own path, so that its folder names (a location's) still read as
    they would beside it. Files named one of `markers` (synth's) are copied too: a zip's
    members, and those in an archive's folder or the one above it. Raises NgsimInputError naming
    the archive (and member) that cannot be unpacked. `progress` is told (archives unpacked,
    archives) before each and at the end, where there are any."""
    unpacked = Unpacked()
    archives = dict.fromkeys(a.resolve() for path in paths for a in archives_in(path))
    for i, archive in enumerate(archives):
        if progress is not None:
            progress(i, len(archives))
        into = scratch / f"{i:04d}" / archive.relative_to(archive.anchor).parent
        run = _Run(unpacked, markers, Expansion(str(archive), archive.stat().st_size))
        unpacked.paths.append(_unpack(archive, into, str(archive), run, 0))
        for folder, mirror in zip(archive.parents[:2], (into, into.parent), strict=False):
            for marker in markers:
                if (folder / marker).is_file() and not (mirror / marker).exists():
                    shutil.copyfile(folder / marker, mirror / marker)
    if progress is not None and archives:
        progress(len(archives), len(archives))
    return unpacked


@dataclass
class _Run:
    """One input archive being unpacked: what all of them gave, the markers copied, and what
    it may still unpack to."""

    unpacked: Unpacked
    markers: tuple[str, ...]
    expansion: Expansion


def searched_paths(paths: list[Path], unpacked: Unpacked) -> list[Path]:
    """The paths a source searches: `paths` less the archives named among them, and each
    archive's unpacked copy."""
    return [p for p in paths if not (p.is_file() and archive_kind(p))] + unpacked.paths


def _unpack(archive: Path, into: Path, name: str, run: _Run, depth: int) -> Path:
    """Unpack `archive` (reported as `name`) into the folder `into`, and any archive in it;
    returns what it unpacked to: the file of a .gz, the folder of a zip."""
    if depth > MAX_DEPTH:
        raise NgsimInputError(name, f"archives nested more than {MAX_DEPTH} deep")
    into.mkdir(parents=True, exist_ok=True)
    if archive_kind(archive) == "gzip":
        stem = archive.name[:-3] if archive.name.lower().endswith(".gz") else archive.name
        chunks = stream_chunks(lambda: gzip.open(archive, "rb"))  # noqa: SIM115 (opened in a with)
        return _member(chunks, into / stem, name, run, depth)
    folder = into / archive.name
    folder.mkdir(exist_ok=True)
    run.unpacked.names[folder.resolve()] = name
    try:
        with zipfile.ZipFile(archive) as zipped:
            for info in zipped.infolist():
                if not info.is_dir():
                    _zip_member(zipped, archive, info, folder, name, run, depth)
    except (zipfile.BadZipFile, EOFError, zlib.error) as err:
        raise NgsimInputError(name, f"cannot read this zip file: {err}") from None
    return folder


def _zip_member(
    zipped: zipfile.ZipFile,
    archive: Path,
    info: zipfile.ZipInfo,
    folder: Path,
    name: str,
    run: _Run,
    depth: int,
) -> None:
    """Unpack one member of a zip (`archive`, reported as `name`) into its `folder`: a text
    file or an archive; a marker; anything else is listed as skipped."""
    inner = PurePosixPath(info.filename)
    shown = f"{name}/{info.filename}"
    if inner.is_absolute() or ".." in inner.parts:
        raise NgsimInputError(shown, "a member's path leads out of its zip file")
    target = folder.joinpath(*inner.parts)
    is_marker = inner.name in run.markers
    if not is_marker and inner.suffix.lower() not in TEXT_SUFFIXES + ARCHIVE_SUFFIXES:
        run.unpacked.skipped.append(shown)
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    check_zip_member(info, shown, target.parent)
    chunks = zip_member_chunks(zipped, archive, info)
    if is_marker:
        _copy(chunks, target, shown, run)
    else:
        _member(chunks, target, shown, run, depth)


def _member(
    chunks: Generator[bytes, None, None], target: Path, name: str, run: _Run, depth: int
) -> Path:
    """Copy one member (its unpacked `chunks`, reported as `name`) to `target`; an archive in
    turn is unpacked beside it and removed. Returns the file, or that folder."""
    target.parent.mkdir(parents=True, exist_ok=True)
    _copy(chunks, target, name, run)
    check_named_right(target, name)
    if archive_kind(target):
        inner = _unpack(target, target.with_name(f"{target.name}.d"), name, run, depth + 1)
        target.unlink()
        return inner
    run.unpacked.names[target.resolve()] = name
    return target


def _copy(chunks: Generator[bytes, None, None], target: Path, name: str, run: _Run) -> None:
    """Write a member's unpacked `chunks` (reported as `name`) to `target`, within the run's
    bounds (`unpacking.write_chunks`); its damage is named."""
    try:
        write_chunks(chunks, target, name, run.expansion)
    except (gzip.BadGzipFile, zipfile.BadZipFile, EOFError, zlib.error, lzma.LZMAError) as err:
        raise NgsimInputError(name, f"damaged compressed data: {err}") from None
    except (NotImplementedError, RuntimeError) as err:  # what zipfile's open refuses
        raise NgsimInputError(name, f"cannot unpack: {err}") from None
    except FileExistsError:  # a zip may hold two members of one name (appended zips do)
        raise NgsimInputError(name, "the archive holds a member of this name twice") from None


def shown_name(path: Path | str, names: dict[Path, str]) -> str:
    """The name a file is reported by: its archive's for an unpacked one, its own otherwise."""
    return names.get(Path(path).resolve(), str(path))


def named_error(err: NgsimError, names: dict[Path, str]) -> NgsimError:
    """`err` naming the archive (and member) where it names an unpacked file or folder."""
    if err.path is None or Path(err.path).resolve() not in names:
        return err
    return type(err)(shown_name(err.path, names), err.message, err.line)
