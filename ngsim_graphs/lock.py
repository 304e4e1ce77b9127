"""The lock of an output directory: one writer at a time, and a killed run's leftovers told
beyond doubt.

While a run writes `NAME`, it holds an flock on `.NAME.lock` beside it. The lock file is created
exclusively and never followed; it holds one line, `ngsim-graphs lock TOKEN PID`, whose random
TOKEN also names the run's partial directory (`.NAME.partial-TOKEN`) and, while it swaps, the
previous `NAME` set aside (`.NAME.old-TOKEN`). The kernel drops an flock when its holder dies, so
a killed run never blocks the next one; its lock file stays, and the next run of the same
directory reads the token from it and removes (or, for a previous directory set aside, restores)
exactly those two directories. Nothing else beside the directory is ever touched, whatever its
name: a lock path that is a link, not a regular file or not such a line is refused, not followed.
"""

from __future__ import annotations

import fcntl
import os
import re
import secrets
import shutil
import signal
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.interrupts import interrupts_held

LOCK_LINE = re.compile(r"ngsim-graphs lock ([0-9a-f]{32}) (\d+)\n")
# A lock file found empty is one whose creator has not flock-ed and written it yet (a moment):
# looked at again this often before it is taken for a foreign file.
_EMPTY_LOCK_TRIES, _EMPTY_LOCK_WAIT_S = 40, 0.05


def lock_path(out: Path) -> Path:
    """The lock file of an output directory: hidden, beside it, so that it survives its swap."""
    return out.parent / f".{out.name}.lock"


def partial_path(out: Path, token: str) -> Path:
    """Where the run holding `token` writes `out` before it swaps it in."""
    return out.parent / f".{out.name}.partial-{token}"


def retired_path(out: Path, token: str) -> Path:
    """Where the run holding `token` sets the previous `out` aside while it swaps."""
    return out.parent / f".{out.name}.old-{token}"


@dataclass(frozen=True)
class Lock:
    """A held output lock: its open file (flock-ed), and the token of the run holding it."""

    path: Path
    fd: int
    token: str


def _refuse_lock(path: Path, out: Path, what: str) -> NgsimOutputError:
    return NgsimOutputError(
        path,
        f"{what}, not a lock of ngsim-graphs: left as it is, and {out} not written (remove it "
        f"if no program is writing {out}, or choose another --out)",
    )


def _open_lock(path: Path, out: Path) -> tuple[int, bool] | None:
    """An open descriptor of the lock file and whether this call created it; None where it
    vanished between two looks. Never follows a link, never opens anything but a regular file."""
    flags = os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK
    try:
        return os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o644), True
    except FileExistsError:
        pass
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(mode):
        raise _refuse_lock(path, out, "is a symbolic link")
    if not stat.S_ISREG(mode):
        raise _refuse_lock(path, out, "is not a regular file")
    try:
        fd = os.open(path, flags)  # a link put there since: refused by O_NOFOLLOW (ELOOP)
    except FileNotFoundError:
        return None
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # something else put there since
        os.close(fd)
        raise _refuse_lock(path, out, "is not a regular file")
    return fd, False


def _same_file(fd: int, path: Path) -> bool:
    """Whether `path` still names the file open as `fd` (a lock holder unlinks it on release)."""
    try:
        named = path.lstat()
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


def _lock_line(fd: int) -> str:
    return os.pread(fd, 256, 0).decode(errors="replace")


def _holder(fd: int) -> str:
    """` (process PID)` from a lock file's line, or nothing if it holds none yet."""
    found = LOCK_LINE.fullmatch(_lock_line(fd))
    return f" (process {found.group(2)})" if found else ""


def _stale_token(fd: int, path: Path, out: Path) -> str | None:
    """The token in the line of a lock file that this process has flock-ed and did not create
    (its run was killed); None for an empty file (its creator is about to flock it)."""
    line = _lock_line(fd)
    if not line:
        return None
    found = LOCK_LINE.fullmatch(line)
    if found is None:
        raise _refuse_lock(path, out, "holds something else")
    return found.group(1)


def _take_lock(path: Path, out: Path) -> tuple[int, str | None]:
    """An open descriptor of `path`, exclusively flock-ed, and the token of the killed run whose
    lock file it is (None for a file this call created); a clear error if another holds it."""
    for _ in range(_EMPTY_LOCK_TRIES):
        opened = _open_lock(path, out)
        if opened is None:
            continue
        fd, created = opened
        try:
            if created:  # ours alone: only another writer's look can hold it, for a moment
                fcntl.flock(fd, fcntl.LOCK_EX)
                return fd, None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise NgsimOutputError(
                    out,
                    f"another process is writing it{_holder(fd)}, holding {path}; wait for it "
                    "to finish or choose another --out",
                ) from None
            if _same_file(fd, path) and (stale := _stale_token(fd, path, out)) is not None:
                return fd, stale
            empty = _same_file(fd, path)
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)  # released and unlinked by its holder, or not yet written by its creator
        if empty:
            time.sleep(_EMPTY_LOCK_WAIT_S)
    raise _refuse_lock(path, out, "is an empty file")


def take_lock(out: Path) -> Lock:
    """Hold `out` for this process until `release_lock`: a second writer of `out` is refused.

    The kernel drops an flock when its holder dies, so a killed run never blocks the next one;
    its lock file stays, naming its token, and its leftovers are cleaned up here (restored, for
    a previous `out` it had set aside) before this run's line replaces it. Ctrl-C and SIGTERM
    are held off while the lock is taken: one that comes meanwhile lets the lock go again (the
    file removed) and is then raised, so that no interrupt leaves a lock file without its line.
    """
    with interrupts_held() as came:
        lock = _hold(out)
        if came:
            release_lock(lock, out)
    for signum in came:
        signal.raise_signal(signum)
    return lock


def _hold(out: Path) -> Lock:
    """take_lock's work, with interrupts held off."""
    path = lock_path(out)
    fd, stale = _take_lock(path, out)
    token = secrets.token_hex(16)
    line = f"ngsim-graphs lock {token} {os.getpid()}\n".encode()
    try:
        if stale is not None:
            _clean_up_after(out, stale)
        os.pwrite(fd, line, 0)
        os.ftruncate(fd, len(line))
    except BaseException:
        if stale is None:  # a file this call created, still without our line: nothing names
            path.unlink(missing_ok=True)
        os.close(fd)
        raise
    return Lock(path, fd, token)


def release_lock(lock: Lock, out: Path) -> None:
    """Let go of `out`: the lock file is removed, unless leftovers of this run remain (a failed
    clean-up), which it names for the next run to remove."""
    try:
        if _same_file(lock.fd, lock.path) and not _leftovers(out, lock.token):
            lock.path.unlink()
    finally:
        os.close(lock.fd)


@contextmanager
def output_lock(out: Path) -> Iterator[str]:
    """Hold `out` for the block (see `take_lock`); yields this run's token."""
    lock = take_lock(out)
    try:
        yield lock.token
    finally:
        release_lock(lock, out)


def _leftovers(out: Path, token: str) -> list[Path]:
    return [p for p in (partial_path(out, token), retired_path(out, token)) if os.path.lexists(p)]


def _is_real_dir(path: Path) -> bool:
    return path.is_dir() and not path.is_symlink()


def _clean_up_after(out: Path, token: str) -> None:
    """Remove what the killed run holding `token` left: its partial directory, and the previous
    `out` it had set aside once the new one was in place; put that back if it was not."""
    partial, retired = partial_path(out, token), retired_path(out, token)
    if _is_real_dir(retired):
        if not os.path.lexists(out):
            os.replace(retired, out)  # killed between its two renames: the previous out is back
        elif _is_real_dir(partial):
            raise NgsimOutputError(
                retired,
                f"holds the previous {out.name}, set aside by a build that was killed, and "
                f"{out} has been made since: move one of them away",
            )
        else:
            shutil.rmtree(retired)  # killed after its swap: out is the new build
    if _is_real_dir(partial):
        shutil.rmtree(partial)
