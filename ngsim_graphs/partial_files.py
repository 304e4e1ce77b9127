"""Files written whole or not at all, never through a link.

A file `DIR/NAME` is written to a partial file beside it, `DIR/.NAME.partial-HEX`, whose random
name is new to the folder: it is created exclusively (O_EXCL) and never through a symbolic link
(O_NOFOLLOW), so that a link or a file put at that name is never written into. Once complete and
on disk, the partial file is renamed to NAME, which replaces whatever NAME was (a link included,
never its target). A failure, an interrupt included, removes the partial file. A writer killed
outright (kill -9) leaves it; its name tells it for what it is (`leftover_partials`).
"""

from __future__ import annotations

import errno
import os
import re
import secrets
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

from ngsim_graphs.errors import NgsimOutputError

_PARTIAL = re.compile(r"\.(?P<name>.+)\.partial-[0-9a-f]{16}")
_CREATE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


def partial_path(path: Path) -> Path:
    """A fresh partial name for `path`: `.NAME.partial-` and 16 random hexadecimal digits."""
    return path.with_name(f".{path.name}.partial-{secrets.token_hex(8)}")


def partial_of(name: str) -> str | None:
    """The NAME whose partial file `name` is (`.NAME.partial-HEX`), None for any other name."""
    found = _PARTIAL.fullmatch(name)
    return found.group("name") if found else None


def leftover_partials(folder: Path, names: Iterable[str]) -> list[Path]:
    """The partial files of the given NAMEs in `folder` (left by a writer that was killed)."""
    wanted = set(names)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if partial_of(p.name) in wanted)


def create_exclusive(path: Path) -> BinaryIO:
    """A new file at `path`, open for writing: never an existing file, never through a link."""
    return os.fdopen(os.open(path, _CREATE, 0o666), "wb")


def write_failure(path: Path, err: OSError) -> NgsimOutputError:
    """The one-line error of a failed write of `path`."""
    if err.errno == errno.ELOOP:
        return NgsimOutputError(path, "is a symbolic link: not written through")
    return NgsimOutputError(path, f"cannot write: {err.strerror or err}")


@contextmanager
def atomic_file(path: Path, sync: bool = True) -> Iterator[BinaryIO]:
    """A binary file that becomes `path` once the block ends: written to a fresh partial file
    (`partial_path`), synced to disk (unless not `sync`) and renamed. A failure in the block
    or in the writing removes the partial file; an OSError is an NgsimOutputError naming
    `path`."""
    partial = partial_path(path)
    try:
        with create_exclusive(partial) as handle:
            yield handle
            handle.flush()
            if sync:
                os.fsync(handle.fileno())  # the bytes are on disk before the name points at them
        os.replace(partial, path)
    except OSError as err:
        partial.unlink(missing_ok=True)
        raise write_failure(path, err) from None
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def write_atomic(path: Path, data: bytes) -> None:
    """Write `data` as the file `path` (`atomic_file`)."""
    with atomic_file(path) as handle:
        handle.write(data)
