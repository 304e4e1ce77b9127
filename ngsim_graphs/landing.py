"""How an output directory lands: locked, checked, written aside and swapped in whole.

A build (or an export) is written into a hidden sibling directory (`.NAME.partial-PID`) and
renamed into place only when complete. While it writes, it holds an flock on `.NAME.lock` beside
the directory, so that a second writer of the same directory is refused instead of deleting the
first one's work. An existing directory is replaced only if it is empty or recognisably ours (a
build of this project); an output that is, contains or lies inside an input is refused.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.layout import (
    ARRAYS_DIR,
    MANIFEST_NAME,
    PROXIMITY_DIR,
    SAMPLES_DIR,
    STAGING_DIR,
    TRACKS_DIR,
    is_our_manifest,
    manifest_path,
    os_errno,
)

# Where each folder of the build layout keeps its files: levels of sub-folders, file suffix.
BUILD_FOLDERS = {
    TRACKS_DIR: (0, ".parquet"),
    PROXIMITY_DIR: (0, ".parquet"),
    SAMPLES_DIR: (0, ".parquet"),
    ARRAYS_DIR: (1, ".npy"),
    STAGING_DIR: (1, ".parquet"),
}
# Errors only a write can cause: reported as a failed write of the output, even unnamed.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")  # how numpy reports a short write
_NAMES_SHOWN = 3


def lock_path(out: Path) -> Path:
    """The lock file of an output directory: hidden, beside it, so that it survives its swap."""
    return out.parent / f".{out.name}.lock"


def check_outside_inputs(out: Path, inputs: list[Path]) -> None:
    """Refuse an output that is, contains or lies inside an input (a file or a folder).

    Replacing `out` deletes it, and a build inside its input would be read back as input.
    Resolved paths are compared, so a symbolic link or `..` does not hide an overlap.
    """
    target = out.resolve()
    for raw in inputs:
        source = raw.resolve()
        if target == source:
            relation = "is"
        elif target.is_relative_to(source):
            relation = "lies inside"
        elif source.is_relative_to(target):
            relation = "contains"
        else:
            continue
        raise NgsimOutputError(
            out, f"--out {relation} the input {raw}; choose an --out outside the inputs"
        )


def _is_build_entry(parts: tuple[str, ...], is_dir: bool) -> bool:
    """Whether a path under a build (its parts) is one that the build layout writes."""
    if parts == (MANIFEST_NAME,):
        return not is_dir
    if parts[0] not in BUILD_FOLDERS:
        return False
    levels, suffix = BUILD_FOLDERS[parts[0]]
    if is_dir:
        return len(parts) <= levels + 1
    return len(parts) == levels + 2 and parts[-1].endswith(suffix)


def _foreign_entries(folder: Path) -> list[str]:
    """Paths under `folder` that no build writes (a foreign folder is named, not its content)."""
    foreign: list[str] = []
    for here, dirs, files in os.walk(folder):
        base = Path(here).relative_to(folder).parts
        for name in sorted(dirs):
            path = Path(here) / name
            if path.is_symlink() or not _is_build_entry((*base, name), is_dir=True):
                foreign.append(str(Path(*base, name)) + "/")
                dirs.remove(name)  # its content is foreign too: not listed one by one
        foreign += [
            str(Path(*base, name))
            for name in sorted(files)
            if (Path(here) / name).is_symlink() or not _is_build_entry((*base, name), is_dir=False)
        ]
    return sorted(foreign)


def some_names(entries: list[str]) -> str:
    """A few names of a list for a one-line message: `a, b, c and 4 more`."""
    shown = ", ".join(entries[:_NAMES_SHOWN])
    rest = len(entries) - _NAMES_SHOWN
    return f"{shown} and {rest} more" if rest > 0 else shown


def _check_target(out: Path, overwrite: bool) -> None:
    """Refuse an `out` that must not be replaced: a file, another program's directory, or a
    build when `overwrite` is off. An empty directory is always taken.

    A directory is a build of this project when everything in it is a name of the build layout,
    and its manifest, if it has one, is ours (without one: an unfinished build). Nothing else is
    deleted, even with --overwrite: not a folder of another program, and not a file someone put
    into a build (a run trained on it, plots), which replacing the build would delete too.
    """
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "exists and is not a directory")
    if not out.is_dir() or not any(out.iterdir()):
        return
    manifest = manifest_path(out)
    if manifest.is_file() and not is_our_manifest(manifest):
        raise NgsimOutputError(
            out,
            f"directory is not empty and is not a build: its {MANIFEST_NAME} is not one of "
            "ngsim-graphs; --overwrite replaces only a build",
        )
    foreign = _foreign_entries(out)
    if foreign and manifest.is_file():
        raise NgsimOutputError(
            out,
            f"holds a build and also {some_names(foreign)}, which are not the build's and "
            "--overwrite would delete with it; move them away first",
        )
    if foreign:
        raise NgsimOutputError(
            out,
            f"directory is not empty and is not a build: it holds {some_names(foreign)}; "
            "--overwrite replaces only a build (move them away or choose another --out)",
        )
    if not overwrite:
        raise NgsimOutputError(
            out, "directory is not empty: it holds a build; pass --overwrite to replace it"
        )


def _same_file(fd: int, path: Path) -> bool:
    """Whether `path` still names the file open as `fd` (a lock holder unlinks it on release)."""
    try:
        named = path.stat()
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


def _holder(fd: int) -> str:
    """` (process PID)` from a lock file's content, or nothing if it holds no PID yet."""
    text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    return f" (process {text})" if text.isdigit() else ""


def _take_lock(path: Path, out: Path) -> int:
    """An open descriptor of `path`, exclusively flock-ed; a clear error if another holds it."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise NgsimOutputError(
                out,
                f"another process is writing it{holder}, holding {path}; wait for it to finish "
                "or choose another --out",
            ) from None
        except BaseException:
            os.close(fd)
            raise
        if _same_file(fd, path):
            return fd
        os.close(fd)  # its holder released and unlinked it between our open and our lock


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Hold `out` for this process: a second writer of `out` is refused until this one ends.

    The kernel drops an flock when its holder dies, so a killed build never leaves a stale
    lock; the file itself is unlinked on release, before the lock is dropped.
    """
    path = lock_path(out)
    fd = _take_lock(path, out)
    try:
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass  # the PID only improves the message of a refused second writer
        yield
    finally:
        path.unlink(missing_ok=True)
        os.close(fd)


def _recover_interrupted_swap(out: Path) -> None:
    """A build killed between its two renames left the previous build as `.NAME.old-PID`;
    one killed while writing left `.NAME.partial-PID`. Run only while holding the lock."""
    for retired in sorted(out.parent.glob(f".{out.name}.old-*")):
        if not out.exists():
            os.replace(retired, out)  # the previous build comes back, as it was
        else:
            shutil.rmtree(retired, ignore_errors=True)
    for leftover in out.parent.glob(f".{out.name}.partial-*"):
        shutil.rmtree(leftover, ignore_errors=True)  # from a build that was killed


def _swap_into_place(partial: Path, out: Path) -> None:
    """Rename the finished `partial` to `out`; a previous `out` goes only once it is replaced."""
    if not out.exists():
        os.replace(partial, out)
        return
    retired = out.parent / f".{out.name}.old-{os.getpid()}"
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


@contextmanager
def output_directory(out: Path, check: Callable[[Path], None]) -> Iterator[Path]:
    """Yield a fresh hidden partial directory beside `out`; on success it replaces `out`.

    Holds `out`'s lock throughout. Under it, leftovers of killed runs are cleaned up and
    `check(out)` may refuse the target. On failure the partial directory, the lock file and
    the folders created for `out` are removed, `out` is left as it was, and a failed write
    (a full disk) becomes an NgsimOutputError naming the file.
    """
    if out.name in ("", ".."):  # "." or "..": the lock and partial names need a real name
        out = Path(os.path.abspath(out))
    if out.is_symlink():
        out = out.resolve()  # replace the directory it names, not the link
    created = [p for p in (out.parent, *out.parent.parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        with output_lock(out):
            _recover_interrupted_swap(out)
            check(out)
            partial = out.parent / f".{out.name}.partial-{os.getpid()}"
            partial.mkdir()
            try:
                yield partial
                _swap_into_place(partial, out)
            except BaseException as err:
                shutil.rmtree(partial, ignore_errors=True)
                failure = _write_failure(err, partial, out)
                if failure is not None:
                    raise failure from None
                raise
    except BaseException:
        _remove_if_empty(created)
        raise


@contextmanager
def build_directory(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a fresh partial directory; on success it replaces `out`, on failure it is removed.

    `out` may be absent, an empty directory, or (with `overwrite`) a build of this project;
    anything else is refused. The previous content of `out` is removed only after the new build
    is complete, and folders created for `out` are removed again if the build fails.
    """
    with output_directory(out, lambda target: _check_target(target, overwrite)) as partial:
        yield partial
        shutil.rmtree(partial / STAGING_DIR, ignore_errors=True)
