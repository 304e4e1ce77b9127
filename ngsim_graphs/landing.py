"""How an output directory lands: locked, checked, written aside and swapped in whole.

A build (or an export) is written into a hidden sibling directory and renamed into place only
when complete, while the run holds the directory's lock (`lock`: one writer at a time, a killed
run's leftovers and nothing else cleaned up). An existing directory is replaced only if it is
empty or a finished build of this project beyond doubt; an output that is, contains or lies
inside an input is refused.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path, PurePosixPath

from ngsim_graphs import integrity
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.interrupts import interrupts_held
from ngsim_graphs.layout import BUILD_LOG, MANIFEST_NAME, STAGING_DIR, manifest_path
from ngsim_graphs.lock import partial_path, release_lock, retired_path, take_lock
from ngsim_graphs.storage import os_errno

# Errors only a write can cause: reported as a failed write of the output, even unnamed.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")  # how numpy reports a short write
_NAMES_SHOWN = 3


def _overlap(target: Path, other: Path) -> str | None:
    """How the resolved path `target` overlaps the resolved `other`, or None where apart."""
    if target == other:
        return "is"
    if target.is_relative_to(other):
        return "lies inside"
    if other.is_relative_to(target):
        return "contains"
    return None


def check_outside_inputs(out: Path, inputs: list[Path]) -> None:
    """Refuse an output that is, contains or lies inside an input (a file or a folder).

    Replacing `out` deletes it, and a build inside its input would be read back as input.
    Resolved paths are compared, so a symbolic link or `..` does not hide an overlap.
    """
    target = out.resolve()
    for raw in inputs:
        relation = _overlap(target, raw.resolve())
        if relation is not None:
            raise NgsimOutputError(
                out, f"--out {relation} the input {raw}; choose an --out outside the inputs"
            )


def check_apart(outs: list[Path]) -> None:
    """Refuse outputs of builds made together where one is, contains or lies inside another:
    each is replaced whole, and one inside another would be deleted with it or read as its
    stray files. Resolved paths are compared, as `check_outside_inputs` does."""
    resolved = [out.resolve() for out in outs]
    for i, out in enumerate(outs):
        for other, target in zip(outs[:i], resolved[:i], strict=True):
            relation = _overlap(resolved[i], target)
            if relation is not None:
                raise NgsimOutputError(
                    out,
                    f"--out {relation} the --out {other} of another build made with it; "
                    "each build needs a folder of its own, apart from the others",
                )


def some_names(entries: list[str]) -> str:
    """A few names of a list for a one-line message: `a, b, c and 4 more`."""
    shown = ", ".join(entries[:_NAMES_SHOWN])
    rest = len(entries) - _NAMES_SHOWN
    return f"{shown} and {rest} more" if rest > 0 else shown


# --- what --overwrite may replace ------------------------------------------------------------


def json_object(path: Path) -> dict | None:
    """The JSON object in the file at `path`, or None where there is none: no file, a link, a
    file that cannot be read or is not JSON, JSON that is not an object. How a marker of ours
    is told from anything else, before its content is checked."""
    if path.is_symlink() or not path.is_file():
        return None
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return document if isinstance(document, dict) else None


def finished_build_files(out: Path) -> set[str] | None:
    """The files of the finished build in `out` (POSIX paths relative to it, its manifest and its
    log included), or None where `out` holds none: no manifest, or one that is not JSON or does
    not match its own checksum and config hash (so not written by a build, or edited since)."""
    path = manifest_path(out)
    manifest = json_object(path)
    if manifest is None or not isinstance(manifest.get(integrity.FILES_KEY), dict):
        return None
    try:
        integrity.check_manifest(manifest, path)
    except (ValueError, TypeError):  # NgsimInputError is a ValueError
        return None
    return {MANIFEST_NAME, BUILD_LOG, *manifest[integrity.FILES_KEY]}


def entries_beyond(out: Path, listed: set[str]) -> list[str]:
    """Paths under `out` (POSIX, relative) that are not among the `listed` files or the folders
    that hold them: a folder is named once (`name/`), not its content; a link is never listed."""
    folders = {str(parent) for name in listed for parent in PurePosixPath(name).parents}
    beyond: list[str] = []
    for here, dirs, files in os.walk(out):
        base = PurePosixPath(Path(here).relative_to(out).as_posix())
        for name in sorted(dirs):
            if (Path(here) / name).is_symlink() or str(base / name) not in folders:
                beyond.append(f"{base / name}/")
                dirs.remove(name)  # its content is not looked at one by one
        beyond += [
            str(base / name)
            for name in sorted(files)
            if (Path(here) / name).is_symlink() or str(base / name) not in listed
        ]
    return sorted(beyond)


def _check_target(out: Path, overwrite: bool) -> None:
    """Refuse an `out` that must not be replaced: a file, anything but a finished build of this
    project, or a build when `overwrite` is off. An empty directory is always taken.

    A finished build is told beyond doubt: its manifest matches its own checksum, and the files
    under `out` are the files it lists, nothing more (a finished build has no `_staging`). Nothing
    else is deleted, even with --overwrite: not a folder of another program, not a folder that
    only looks like a build, and not a file someone put into a build (a run, plots), which
    replacing the build would delete too.
    """
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "exists and is not a directory")
    if not out.is_dir() or not any(out.iterdir()):
        return
    listed = finished_build_files(out)
    if listed is None and manifest_path(out).exists():
        raise NgsimOutputError(
            out,
            f"directory is not empty and is not a build: its {MANIFEST_NAME} is not one that "
            "ngsim-graphs wrote, or it was edited since; --overwrite replaces only a finished "
            "build",
        )
    beyond = entries_beyond(out, listed or set())
    if beyond and listed is not None:
        raise NgsimOutputError(
            out,
            f"holds a build and also {some_names(beyond)}, which are not the build's and "
            "--overwrite would delete with it; move them away first",
        )
    if beyond:
        raise NgsimOutputError(
            out,
            f"directory is not empty and is not a build: it holds {some_names(beyond)}; "
            "--overwrite replaces only a finished build (move them away or choose another --out)",
        )
    if not overwrite:
        raise NgsimOutputError(
            out, "directory is not empty: it holds a build; pass --overwrite to replace it"
        )


# --- landing ---------------------------------------------------------------------------------


def _swap_into_place(partial: Path, out: Path, retired: Path) -> None:
    """Rename the finished `partial` to `out`; a previous `out` goes only once it is replaced."""
    if not os.path.lexists(out):
        os.replace(partial, out)
        return
    os.replace(out, retired)
    os.replace(partial, out)
    shutil.rmtree(retired)


def _write_failure(err: BaseException, partial: Path, out: Path) -> NgsimOutputError | None:
    """The one-line error of a failed write into `partial`, naming the file as it would be in
    `out`; None for an error that is not such a write (it then goes on as it came)."""
    filename = getattr(err, "filename", None)
    if isinstance(err, OSError) and filename and Path(filename).is_relative_to(partial):
        target = out / Path(filename).relative_to(partial)
        target = target.with_name(target.name.removesuffix(".partial"))  # the file it was to be
        return NgsimOutputError(target, f"cannot write: {err.strerror or err}")
    code = os_errno(err)
    if code in WRITE_ERRNOS:  # polars and numpy do not say which file
        return NgsimOutputError(out, f"cannot write: {os.strerror(code)}")
    if isinstance(err, OSError) and _SHORT_WRITE.search(str(err)):
        return NgsimOutputError(out, f"cannot write (is the disk full?): {err}")
    return None


def _remove_if_empty(folders: list[Path]) -> None:
    """Remove the folders (innermost first) that are empty: those a failed run created."""
    for folder in folders:
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def _target(out: Path) -> Path:
    """The directory `out` names: a real name for "." and "..", a link's target for a link."""
    if out.name in ("", ".."):  # the lock and partial names need a real name
        out = Path(os.path.abspath(out))
    return out.resolve() if out.is_symlink() else out  # replace the directory, not the link


@contextmanager
def output_directory(out: Path, check: Callable[[Path], None]) -> Iterator[Path]:
    """Yield a fresh hidden partial directory beside `out`; on success it replaces `out`.

    Holds `out`'s lock throughout (`lock.take_lock`: leftovers of a killed run of `out` are
    cleaned up), and `check(out)` may refuse the target. On failure, an interrupt included, the
    partial directory, the lock file and the folders created for `out` are removed, `out` is
    left as it was, and a failed write (a full disk) becomes an NgsimOutputError naming the
    file. Once the block has ended, the swap and the release run to their end: an interrupt
    meanwhile is let pass, since the new `out` is then in place.
    """
    out = _target(out)
    created = [p for p in (out.parent, *out.parent.parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        lock = take_lock(out)
        partial = None
        try:  # from the first call after the lock is held: an interrupt there lets it go
            partial = partial_path(out, lock.token)
            check(out)
            partial.mkdir()
            try:
                yield partial
            except BaseException as err:
                failure = _write_failure(err, partial, out)
                if failure is not None:
                    raise failure from None
                raise
        except BaseException:
            if partial is not None:
                shutil.rmtree(partial, ignore_errors=True)
            release_lock(lock, out)
            raise
        with interrupts_held():
            try:
                _swap_into_place(partial, out, retired_path(out, lock.token))
            finally:
                release_lock(lock, out)
    except BaseException:
        _remove_if_empty(created)
        raise


@contextmanager
def build_directory(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a fresh partial directory; on success it replaces `out`, on failure it is removed.

    `out` may be absent, an empty directory, or (with `overwrite`) a finished build of this
    project; anything else is refused. The previous content of `out` is removed only after the
    new build is complete, and folders created for `out` are removed again if the build fails.
    """
    with output_directory(out, lambda target: _check_target(target, overwrite)) as partial:
        yield partial
        shutil.rmtree(partial / STAGING_DIR, ignore_errors=True)
