"""The output directory: every path in it and the manifest (written last, read with checks).

The manifest's values are `manifest.Manifest`; this module alone reads and writes its file.

A build is written into a hidden sibling directory (`.NAME.partial-PID`) and renamed into place
only when complete, with the manifest written last. A directory without a complete manifest is
therefore never a finished build, and an interrupted build leaves nothing that looks finished.
How the directory lands (lock, checks, the swap) is `landing`'s.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ngsim_graphs import integrity
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.manifest import Manifest
from ngsim_graphs.storage import writing

# 2: the manifest lists every file with its checksum, and its own checksum; 3: and every file's
# sampled digest, which every open checks; 4: the proximity pairs written once, in the
# recordings' arrays, not also as tables.
FORMAT_VERSION = 4
# The formats this version opens. A build of format 3 holds its pairs a second time, as
# proximity/<recording>.parquet (`proximity_path`): listed in its manifest and checked with
# its other files, and read by nothing.
READ_FORMAT_VERSIONS = (3, 4)
MANIFEST_NAME = "manifest.json"
TRACKS_DIR = "tracks"
PROXIMITY_DIR = "proximity"  # format 3's tables: a folder of a build, ours to replace
SAMPLES_DIR = "samples"
ARRAYS_DIR = "arrays"
STAGING_DIR = "_staging"
# `ngsim-graphs build`'s log: its stderr lines, each after its time, appended once the build has
# landed (so not in the manifest, which is written before; a build that fails leaves none).
# The build's own file all the same: `verify` does not name it, and --overwrite replaces it.
BUILD_LOG = "build.log"
SAMPLE_ARRAYS = ("recording_index", "ego_track_id", "start_step")


def recording_name(location: str, period: str) -> str:
    """The file-name stem of one recording: `us-101_0750am-0805am`."""
    return f"{location}_{period}"


def tracks_path(root: Path, location: str, period: str) -> Path:
    """The tracks table of one recording (one row per track and 0.2 s grid step)."""
    return root / TRACKS_DIR / f"{recording_name(location, period)}.parquet"


def proximity_path(root: Path, location: str, period: str) -> Path:
    """A build of format 3's table of one recording's proximity pairs (step, track_a, track_b,
    distance_m): the pair arrays' pairs again. Later formats have none."""
    return root / PROXIMITY_DIR / f"{recording_name(location, period)}.parquet"


def has_proximity_tables(format_version: int) -> bool:
    """Whether a build of this format holds `proximity_path` tables."""
    return format_version <= 3


def samples_path(root: Path, split: str) -> Path:
    """The samples (ego windows) of one split."""
    return root / SAMPLES_DIR / f"{split}.parquet"


def recording_arrays_dir(root: Path, location: str, period: str) -> Path:
    return root / ARRAYS_DIR / recording_name(location, period)


def sample_arrays_dir(root: Path, split: str) -> Path:
    return root / ARRAYS_DIR / f"samples-{split}"


def manifest_path(root: Path) -> Path:
    return root / MANIFEST_NAME


def build_log_path(root: Path) -> Path:
    """The build's log (BUILD_LOG), beside its manifest."""
    return root / BUILD_LOG


def config_hash(config: dict[str, Any], limits: dict[str, Any] | None = None) -> str:
    """sha256 of the config and the limits its source applied (`integrity.build_settings`) as
    canonical JSON: two builds with equal hashes were made alike."""
    return integrity.settings_sha256(config, limits)


def write_manifest(root: Path, manifest: Manifest) -> Manifest:
    """Write the manifest atomically, the last file of a build: with the records (size, sha256,
    array dtype and shape) of every other file of the build and its own checksum. Returns it so
    sealed (what `read_manifest` gives back)."""
    body = manifest.to_dict()
    for key in (integrity.FILES_KEY, integrity.CHECKSUM_KEY):  # a sealed one is sealed anew
        body.pop(key, None)
    written = write_manifest_json(root, body)
    return manifest.sealed(written[integrity.FILES_KEY], written[integrity.CHECKSUM_KEY])


def write_manifest_json(root: Path, body: dict[str, Any]) -> dict[str, Any]:
    """Write a manifest's JSON value (sorted keys, indented) with the file records and its
    checksum added; returns what was written. `write_manifest` writes a build's; tests seal
    hand-edited ones with it."""
    target = manifest_path(root)
    partial = target.with_suffix(".json.partial")
    _check_finite(target, body)
    records = integrity.file_records(root, skip=(STAGING_DIR, MANIFEST_NAME, partial.name))
    written = integrity.with_checksum({**body, integrity.FILES_KEY: records})
    text = json.dumps(written, indent=2, sort_keys=True, allow_nan=False) + "\n"
    with writing(partial):
        partial.write_text(text)
    os.replace(partial, target)
    return written


def _check_finite(path: Path, body: Any, where: str = "") -> None:
    """A last guard: a manifest is strict JSON, which has no NaN or infinity (Python would write
    a bare NaN that strict readers refuse). The configs refuse such settings before any work,
    and a measured NaN is written as null; one that slips through is an error naming its key."""
    if isinstance(body, float) and not math.isfinite(body):
        raise NgsimOutputError(
            path,
            f"{where or 'a value'} is {body}, which JSON cannot hold: the build is not written",
        )
    if isinstance(body, dict):
        children = body.items()
    elif isinstance(body, list | tuple):
        children = enumerate(body)
    else:
        return
    for key, value in children:
        _check_finite(path, value, f"{where}.{key}" if where else str(key))


def is_our_manifest(path: Path) -> bool:
    """Whether the file `path` is a manifest that a build of this project wrote (any format
    version): a JSON object with a format version and a config hash."""
    try:
        content = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(content, dict) and {"format_version", "config_hash"} <= content.keys()


def read_manifest(root: Path) -> Manifest:
    """The manifest of a finished build; a clear error for anything else: no build, not JSON,
    another format version, edited or damaged (`integrity`), or of another form."""
    manifest = _read_manifest_json(root)
    try:
        return Manifest.from_dict(manifest)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise NgsimInputError(manifest_path(root), f"unreadable build manifest: {err!r}") from None


def _read_manifest_json(root: Path) -> dict[str, Any]:
    """The JSON value of a finished build's manifest, of this format version and checked
    against its checksum and config hash."""
    path = manifest_path(root)
    if not root.exists():
        raise NgsimInputError(root, "no such build directory")
    if not root.is_dir():
        raise NgsimInputError(root, _what_file_is(root))
    if not path.is_file():
        raise NgsimInputError(root, what_folder_is(root))
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise NgsimInputError(path, f"unreadable manifest: {err.msg}", line=err.lineno) from None
    except UnicodeDecodeError:
        raise NgsimInputError(path, "unreadable manifest: not UTF-8 text") from None
    if not isinstance(manifest, dict):
        raise NgsimInputError(path, "unreadable manifest: not a JSON object")
    version = manifest.get("format_version")
    if version not in READ_FORMAT_VERSIONS:
        older = (
            " (made by an older ngsim-graphs: build it again)"
            if isinstance(version, int) and version < min(READ_FORMAT_VERSIONS)
            else ""
        )
        expected = " or ".join(str(v) for v in sorted(READ_FORMAT_VERSIONS, reverse=True))
        raise NgsimInputError(path, f"format version {version!r}; expected {expected}{older}")
    integrity.check_manifest(manifest, path)
    return manifest


# What marks a run directory of aigem (`aigem.runs.records`: RUN_INFO, HORIZONS), and the key of its
# run.json that names its build: named here because ngsim_graphs never imports aigem.
RUN_INFO_NAME, RUN_HORIZONS_NAME, RUN_BUILD_KEY = "run.json", "horizons.json", "build_dir"
# What a build holds before its manifest is written (a folder of only these: an unfinished build)
_UNFINISHED_NAMES = {TRACKS_DIR, PROXIMITY_DIR, SAMPLES_DIR, ARRAYS_DIR, STAGING_DIR}
_LOOKED_AT = 1_000  # entries looked at for trajectory files, at most (not a whole home folder)


def what_folder_is(root: Path) -> str:
    """Why the folder `root`, which holds no manifest, is not a build, as a user can act on it:
    empty, an aigem run (and its build), a folder of builds (named), an unfinished build, a
    folder of trajectory files."""
    try:
        names = {entry.name for entry in root.iterdir()}
        if not names:
            return "an empty folder, not a build"
        if names & {RUN_INFO_NAME, RUN_HORIZONS_NAME}:
            build = _run_build(root)
            return "an aigem run, not a build" + (f"; its build is {build}" if build else "")
        builds = sorted(root / name for name in names if (root / name / MANIFEST_NAME).is_file())
        if builds:  # before its trajectory files: the README's demo/ holds raw/ and build/
            which = builds[0] if len(builds) == 1 else "one of " + ", ".join(map(str, builds))
            return (
                f"not a build, but it holds {'one' if len(builds) == 1 else 'builds'}: give {which}"
            )
        if names <= {*_UNFINISHED_NAMES, f"{MANIFEST_NAME}.partial"}:
            return f"an unfinished build (interrupted?): no {MANIFEST_NAME}"
        if _holds_trajectory_files(root):
            return (
                "holds NGSIM/highD trajectory files, not a build: build one with "
                f"`ngsim-graphs build {root} --out BUILD`"
            )
    except OSError:  # a folder it may not list: said as plainly as the rest
        pass
    return f"not a build: no {MANIFEST_NAME}"


def _what_file_is(path: Path) -> str:
    """Why the file `path` is not a build: a trajectory file, or another file."""
    if _is_trajectory_file(path):
        return (
            "an NGSIM/highD trajectory file, not a build: build one with "
            f"`ngsim-graphs build {path} --out BUILD`"
        )
    return "not a directory"


def _json_of(path: Path) -> Any:
    """The JSON value of a file; None if it cannot be read as JSON."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        return None


def _run_build(run: Path) -> str | None:
    """The build an aigem run names in its run.json (a multi-horizon run: in its first
    member's); None where that cannot be read."""
    info = _json_of(run / RUN_INFO_NAME)
    if info is None:
        horizons = _json_of(run / RUN_HORIZONS_NAME)
        members = horizons.get("members") if isinstance(horizons, dict) else None
        if isinstance(members, list) and members and integrity.SAFE_NAME.match(str(members[0])):
            info = _json_of(run / str(members[0]) / RUN_INFO_NAME)
    build = info.get(RUN_BUILD_KEY) if isinstance(info, dict) else None
    return build if isinstance(build, str) else None


def _holds_trajectory_files(root: Path) -> bool:
    """Whether `root` or a folder in it holds a file that a source reads (of the first
    _LOOKED_AT entries)."""

    def entries() -> Iterator[Path]:
        yield from root.iterdir()
        for folder in root.iterdir():
            if folder.is_dir() and not folder.is_symlink():
                yield from folder.iterdir()

    return any(_is_trajectory_file(path) for path in itertools.islice(entries(), _LOOKED_AT))


def _is_trajectory_file(path: Path) -> bool:
    """Whether `path` is a file that a source reads (NGSIM, highD), told from its content."""
    # Imported here: only this error path needs the sources' sniffers.
    from ngsim_graphs.sources.registry import is_source_file

    return path.is_file() and is_source_file(path)
