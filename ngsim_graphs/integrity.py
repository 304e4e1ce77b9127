"""What a build's manifest records of itself and of its files, and the checks against it.

The manifest lists every file of the build with its size, sha256 and sampled digest, and every
array's dtype and shape; it carries the sha256 of its own content, and the sha256 of its settings
(its config and the physical limits its source applied: `build_settings`).
Opening a build checks, every time: the manifest's own checksum and config hash, that every file
is there with its recorded size, that every array's header gives its recorded dtype and shape,
and every file's sampled digest (the whole file up to WHOLE_FILE_BYTES; beyond, SAMPLE_BLOCKS
blocks spread over it: an edit of a small file, or one spread over a large file, is found on
opening). `verify` also reads every byte, compares the checksums, and names the files the
manifest does not list and every symbolic link. A damaged or edited build then fails with one
line naming the file, instead of giving wrong numbers.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from ngsim_graphs.budget import available_cores
from ngsim_graphs.errors import NgsimInputError

CHECKSUM_KEY = "manifest_sha256"  # sha256 of the manifest's canonical JSON without this key
FILES_KEY = "files"  # relative path -> {"bytes", "sha256", "sampled_sha256"[, "dtype", "shape"]}
SAMPLED_KEY = "sampled_sha256"  # a file record's digest that every open checks
# A file up to this size is read whole by every open (its sampled digest is its sha256): the
# sample arrays, the samples tables and most arrays of a recording of a few minutes.
WHOLE_FILE_BYTES = 8 << 20
# A larger one gives SAMPLE_BLOCKS blocks of SAMPLE_BLOCK_BYTES (1 MiB in all), spread evenly
# from its first byte (an array's header) to its last (a Parquet footer).
SAMPLE_BLOCKS = 256
SAMPLE_BLOCK_BYTES = 4096
SAFE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]*$")  # a file or folder name of a build
# The physical limits a build's source applied: beside its config in the manifest (an older
# manifest holds them inside its config, under the same key)
LIMITS_KEY = "limits"


def file_sha256(path: Path) -> str:
    """sha256 of a file's bytes, read in 16 MiB chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(1 << 24):
            digest.update(chunk)
    return digest.hexdigest()


def sample_offsets(size: int) -> list[int]:
    """Where the blocks of a file of `size` bytes that its sampled digest reads begin: [0] (the
    whole file) up to WHOLE_FILE_BYTES, else SAMPLE_BLOCKS offsets from 0 to size - block."""
    if size <= WHOLE_FILE_BYTES:
        return [0]
    last = size - SAMPLE_BLOCK_BYTES
    return [i * last // (SAMPLE_BLOCKS - 1) for i in range(SAMPLE_BLOCKS)]


def sampled_sha256(path: Path) -> str:
    """sha256 of the blocks of a file at `sample_offsets`: its plain sha256 up to
    WHOLE_FILE_BYTES, of 1 MiB of it spread evenly beyond."""
    size = path.stat().st_size
    if size <= WHOLE_FILE_BYTES:
        return file_sha256(path)
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for offset in sample_offsets(size):
            digest.update(os.pread(handle.fileno(), SAMPLE_BLOCK_BYTES, offset))
    return digest.hexdigest()


def canonical_sha256(value: Any) -> str:
    """sha256 of a JSON value written canonically (sorted keys, no spaces)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def build_settings(config: Any, limits: Any = None) -> Any:
    """What a build's config hash covers, as JSON: its config with, under LIMITS_KEY, the
    physical limits its source applied. A manifest records the limits beside its config; an
    older one inside it (`limits` None), so that its settings, and their hash, are its config:
    a build of NGSIM's default limits hashes as it did when its config held them."""
    if limits is None or not isinstance(config, dict):
        return config
    return {**config, LIMITS_KEY: limits}


def settings_sha256(config: Any, limits: Any = None) -> str:
    """A build's config hash: sha256 of `build_settings` written canonically."""
    return canonical_sha256(build_settings(config, limits))


def npy_header(path: Path) -> tuple[str, tuple[int, ...]]:
    """(dtype as numpy spells it, shape) from a .npy file's header, without reading its data."""
    with path.open("rb") as handle:
        version = np.lib.format.read_magic(handle)
        if version == (1, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_1_0(handle)
        elif version == (2, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_2_0(handle)
        else:
            raise ValueError(f"unknown .npy format version {version}")
    return dtype.str, tuple(int(n) for n in shape)


def _both_digests(path: Path) -> tuple[str, str]:
    """(sha256, sampled digest) of a file; a small file is read once (they are equal)."""
    digest = file_sha256(path)
    small = path.stat().st_size <= WHOLE_FILE_BYTES
    return digest, digest if small else sampled_sha256(path)


def file_records(root: Path, skip: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Every file under `root` but those under the top-level names in `skip`: its path relative
    to `root` (POSIX), size, sha256, sampled digest, and for a .npy array its dtype and shape."""
    records: dict[str, dict[str, Any]] = {}
    paths = [
        p
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.relative_to(root).parts[0] not in skip
    ]
    # hashlib lets go of the GIL while it hashes: the files are read and hashed on every core.
    with ThreadPoolExecutor(available_cores()) as threads:
        digests = list(threads.map(_both_digests, paths))
    for path, (digest, sampled) in zip(paths, digests, strict=True):
        relative = path.relative_to(root)
        record: dict[str, Any] = {"bytes": path.stat().st_size, "sha256": digest}
        record[SAMPLED_KEY] = sampled
        if path.suffix == ".npy":
            dtype, shape = npy_header(path)
            record |= {"dtype": dtype, "shape": list(shape)}
        records[relative.as_posix()] = record
    return records


def with_checksum(manifest: dict[str, Any]) -> dict[str, Any]:
    """The manifest with CHECKSUM_KEY set to the checksum of the rest of it."""
    body = {k: v for k, v in manifest.items() if k != CHECKSUM_KEY}
    return {**body, CHECKSUM_KEY: canonical_sha256(body)}


def check_manifest(manifest: dict[str, Any], path: Path) -> None:
    """Raise unless the manifest matches its own checksum and its config its config hash."""
    body = {k: v for k, v in manifest.items() if k != CHECKSUM_KEY}
    if manifest.get(CHECKSUM_KEY) != canonical_sha256(body):
        raise NgsimInputError(
            path,
            "its content does not match its checksum: edited or damaged (a build is never edited "
            "by hand; build it again)",
        )
    settings = settings_sha256(manifest.get("config"), manifest.get(LIMITS_KEY))
    if manifest.get("config_hash") != settings:
        raise NgsimInputError(path, "its config does not match its config_hash: edited or damaged")


def inside(root: Path, relative: str, path: Path) -> Path:
    """`root / relative` for a relative POSIX path of safe names; any other path (absolute, with
    `..`, odd names) is refused, so that a manifest never leads reads outside its build."""
    parts = PurePosixPath(relative).parts
    if not parts or not all(SAFE_NAME.match(part) for part in parts):
        raise NgsimInputError(
            path, f"names a file outside the build or of an odd name: {relative!r}"
        )
    return root.joinpath(*parts)


def check_sizes(root: Path, records: dict[str, dict[str, Any]], manifest: Path) -> None:
    """Raise for the first recorded file that is missing or not of its recorded size."""
    for relative, record in records.items():
        path = inside(root, relative, manifest)
        if not path.is_file():
            raise NgsimInputError(path, "missing: the build is incomplete (deleted or moved?)")
        size = path.stat().st_size
        if size != record["bytes"]:
            raise NgsimInputError(
                path,
                f"{size:,} bytes where the manifest records {record['bytes']:,} (truncated or replaced?)",
            )


NOT_LISTED = (
    "not listed in the manifest: not part of this build (a manifest re-sealed without it?); "
    "build it again"
)


def listed_record(root: Path, path: Path, records: Mapping[str, Any]) -> Any:
    """The manifest's record of the build's file `path` (under `root`); raise for a file the
    manifest does not list, whose checks an open would otherwise skip."""
    record = records.get(path.relative_to(root).as_posix())
    if record is None:
        raise NgsimInputError(path, NOT_LISTED)
    return record


def check_listed(root: Path, paths: list[Path], records: Mapping[str, Any]) -> None:
    """Raise for the first of `paths` (files of the build under `root`) not in `records`."""
    for path in paths:
        listed_record(root, path, records)


def check_array(path: Path, array: np.ndarray, record: dict[str, Any] | None) -> None:
    """Raise unless an opened array has the dtype and shape its record gives."""
    if record is None:
        raise NgsimInputError(path, NOT_LISTED)
    if array.dtype.str != record["dtype"] or list(array.shape) != record["shape"]:
        raise NgsimInputError(
            path,
            f"{array.dtype.str} {tuple(array.shape)} where the manifest records {record['dtype']} "
            f"{tuple(record['shape'])} (replaced or damaged?)",
        )


def check_array_header(path: Path, record: dict[str, Any]) -> None:
    """Raise unless a recorded array's .npy header gives its recorded dtype and shape."""
    try:
        dtype, shape = npy_header(path)
    except (ValueError, OSError, EOFError) as err:
        raise NgsimInputError(path, f"unreadable array header (damaged?): {err}") from None
    if dtype != record["dtype"] or list(shape) != record["shape"]:
        raise NgsimInputError(
            path,
            f"{dtype} {shape} where the manifest records {record['dtype']} "
            f"{tuple(record['shape'])} (replaced or damaged?)",
        )


def check_files(root: Path, records: dict[str, dict[str, Any]], manifest: Path) -> None:
    """What every open checks: raise for the first recorded file that is missing or not of its
    recorded size, an array whose header is not its recorded dtype and shape, then a file whose
    sampled digest is not its record's (same-size edits: shifted, rescaled, replaced values)."""
    check_sizes(root, records, manifest)
    paths = {relative: inside(root, relative, manifest) for relative in records}
    for relative, record in records.items():
        if "dtype" in record:
            check_array_header(paths[relative], record)
    # hashlib lets go of the GIL while it hashes: the files are checked on every core.
    with ThreadPoolExecutor(available_cores()) as threads:
        digests = list(threads.map(sampled_sha256, paths.values()))
    for (relative, record), digest in zip(records.items(), digests, strict=True):
        if digest != record[SAMPLED_KEY]:
            raise NgsimInputError(
                paths[relative],
                "its bytes do not match the manifest's digest: edited or damaged (build it "
                "again; `ngsim-graphs verify` names every damaged file)",
            )


def stray_entries(
    root: Path, records: dict[str, dict[str, Any]], own: tuple[str, ...]
) -> list[str]:
    """One line per symbolic link under `root` (where it leads, and whether it leaves the build)
    and per file that is neither in `records` nor one of the top-level names in `own` (the
    manifest): `verify` names what a build should not hold. A linked folder is not entered."""
    problems = []
    inner = root.resolve()
    for here, dirs, files in os.walk(root):  # never follows a link into a folder
        dirs.sort()
        for name in sorted([*dirs, *files]):
            path = Path(here) / name
            relative = path.relative_to(root).as_posix()
            if path.is_symlink():
                leaves = not path.resolve().is_relative_to(inner)
                where = "outside the build" if leaves else "inside the build"
                problems.append(
                    f"{path}: a symbolic link to {os.readlink(path)}, {where}; a build holds "
                    "only its own files (copy them in, or build it again)"
                )
            elif name in files and relative not in records and relative not in own:
                problems.append(f"{path}: not listed in the manifest: not part of this build")
    return problems


def verify_files(
    root: Path,
    records: dict[str, dict[str, Any]],
    manifest: Path,
    progress: Callable[[str, int, int], None] | None = None,
) -> list[str]:
    """Read every recorded file and compare its checksum; returns one line per damaged file."""
    problems = []
    for done, (relative, record) in enumerate(records.items()):
        if progress:
            progress(f"checking {relative}", done, len(records))
        path = inside(root, relative, manifest)
        try:
            check_sizes(root, {relative: record}, manifest)
        except NgsimInputError as err:
            problems.append(str(err))
            continue
        if file_sha256(path) != record["sha256"]:
            problems.append(
                f"{path}: its bytes do not match the manifest's sha256 (damaged or edited)"
            )
    return problems
